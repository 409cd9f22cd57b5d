"""Which saved state a node resumes from (pure).

What a restart must not lose is :meth:`bridge.core.node.NodeCore.state`, plain data the
runtime saves and hands back to the next run. A state saved by another node, under another
mission file or in another version of it is not resumed: the node starts afresh (a new epoch:
its peers resynchronise) and every value that state left unfinished is reported ``failed``.
Only the node's own latching channels' values and key families' names go on to be looked at
channel by channel (:mod:`bridge.core.latched`, :mod:`bridge.core.families`): those whose
channel is unchanged resume, the others are counted drops.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any

from bridge.core.events import Delivery
from bridge.core.outputs import Outbox

__all__ = ["FAILED", "STATE_VERSION", "resumable"]

log = logging.getLogger("zab.core")

STATE_VERSION = 1
"""The version of :meth:`~bridge.core.node.NodeCore.state`'s layout."""
FAILED = "failed"
"""Where :func:`resumable` puts the reports of values left unfinished under another mission."""


def resumable(state: Mapping[str, Any] | None, node: str, fingerprint: str,
              outbox: Outbox) -> Mapping[str, Any]:
    """``state`` if it is ``node``'s under the mission file of ``fingerprint`` (hex); else
    nothing but ``node``'s latched values and key families (checked per channel when
    resumed), and under ``failed`` a report of every value it left unfinished, its time 0
    (the outbound side reports them at the node's first tick, at its time: :data:`FAILED`)."""
    if not state:
        return {}
    same = (state.get("version") == STATE_VERSION and state.get("node") == node
            and state.get("fingerprint") == fingerprint)
    if same:
        return state
    log.warning("%s: the saved state is from another mission file or version: starting "
                "afresh (its unfinished values are reported failed; latched values of "
                "unchanged channels resume)", node)
    failed = [Delivery(0.0, name, item["id"], dst, "failed",
                       reason="restarted with another mission file",
                       attempts=item.get("attempts", 0), key=item.get("key"), ref=item.get("ref"))
              for name, sender in (state.get("senders") or {}).items()
              for item in [*sender.get("queue", ()), *sender.get("flight", ()),
                           *sender.get("items", ())]
              for dst in item.get("waiting", item.get("dests", ()))]
    if failed:
        outbox.unsaved = True  # (the state that held them is gone: saved before they go out)
    kept = {FAILED: failed} if failed else {}
    if state.get("node") != node:
        return kept
    # (each checked against its channel now)
    return {**kept, **{k: state[k] for k in ("latched", "families") if state.get(k) is not None}}
