"""Plain-data helpers for the state a node saves across restarts (pure).

The core's ``state()`` methods return msgpack-able data; packed values can exceed 64 bits, so
they are kept as big-endian bytes.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any

from bridge.core.events import Delivery
from bridge.core.outputs import Outbox

log = logging.getLogger("zab.core")

STATE_VERSION = 1


def int_to_state(value: int) -> bytes:
    """A non-negative integer of any size as bytes."""
    return value.to_bytes(max(1, (value.bit_length() + 7) // 8), "big")


def int_from_state(data: bytes | int) -> int:
    """The integer back from :func:`int_to_state` (a plain int passes through)."""
    return data if isinstance(data, int) else int.from_bytes(data, "big")


def usable_state(state: Mapping[str, Any] | None, node: str, fingerprint: bytes,
                 outbox: Outbox) -> Mapping[str, Any]:
    """``state`` if it is ``node``'s under this mission file (``fingerprint``); else nothing,
    and every value it left unfinished reported failed in ``outbox``."""
    if not state:
        return {}
    same = (state.get("version") == STATE_VERSION and state.get("node") == node
            and state.get("fingerprint") == fingerprint.hex())
    if same:
        return state
    log.warning("%s: the saved state is from another mission file or version: starting "
                "afresh (its unfinished values are reported failed)", node)
    for name, sender in (state.get("senders") or {}).items():
        items = [*sender.get("queue", ()), *sender.get("flight", ()), *sender.get("items", ())]
        for item in items:
            for dst in item.get("waiting", item.get("dests", ())):
                outbox.reports([Delivery(
                    0.0, name, item["id"], dst, "failed",
                    reason="restarted with another mission file",
                    attempts=item.get("attempts", 0), key=item.get("key"), ref=item.get("ref"))])
    return {}
