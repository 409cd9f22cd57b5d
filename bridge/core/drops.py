"""Dropped payloads, counted per key and cause, told at a bounded rate (pure).

A sample that cannot be used (too long, not msgpack or JSON, not the shape its channel packs)
is counted, never raised. Anyone on the Zenoh network can send thousands a second, so what a
drop *says* is bounded, whatever the input rate:

- the log: one line per key and cause at most every :data:`LOG_EVERY_S` (the first at once,
  then how many more came since, with an example reason);
- events: one :class:`~bridge.core.events.PayloadDrops` summary at most every
  :data:`SUMMARY_EVERY_S`, with the count per key and cause since the last one;
- memory: at most :data:`MAX_KEYS` keys are counted by name (a wildcard input can bring any
  number of them); the rest are counted together under :data:`OTHER_KEYS`.

Causes: ``too_large`` (over the key's cap, refused before decoding), ``undecodable`` (not
msgpack, JSON or CDR; not UTF-8; nested too deep), ``unfit`` (decoded, but not what its
channel packs: a missing field, a wrong type, a value refused out of range), and the few the
runtime adds (``implausible``, ``unpublishable``), ``unbuildable``: an entry or a frame the
core could not build (a bug; left out, keyed by channel, or ``(frame)``), and ``unresumable``:
a latching channel's value saved by an earlier run that no longer fits the mission or cannot
be read (keyed by channel: :mod:`bridge.core.latched`). Gets and replies of queries count here
too (:mod:`bridge.core.queries`), keyed by the asked or local key, with one cause of their own:
``error_reply``, a queryable's reply error (its text told here, as the water cannot carry it).
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from bridge.core.events import PayloadDrops

if TYPE_CHECKING:
    from bridge.wire.channels import ChannelCodec, ElementCodec

log = logging.getLogger("zab.core")

LOG_EVERY_S = 60.0
SUMMARY_EVERY_S = 1.0
MAX_KEYS = 256
OTHER_KEYS = "(other keys)"


@dataclass
class _Told:
    """When a key and cause was last logged, and how many drops since."""

    at: float
    since: int = 0


class DropLedger:
    """The payload drops of one node: counts, log lines and summaries."""

    def __init__(self, node: str) -> None:
        self.node = node
        self.by_key: Counter[str] = Counter()
        self.by_cause: Counter[tuple[str, str]] = Counter()
        self._pending: dict[tuple[str, str], list[Any]] = {}  # [count, first reason] since summary
        self._told: dict[tuple[str, str], _Told] = {}
        self._summarised = -math.inf

    def drop(self, key: str, cause: str, reason: str, now: float) -> PayloadDrops | None:
        """Count one drop; returns a summary when one is due now."""
        if key not in self.by_key and len(self.by_key) >= MAX_KEYS:
            key = OTHER_KEYS
        self.by_key[key] += 1
        what = (key, cause)
        self.by_cause[what] += 1
        pending = self._pending.get(what)
        if pending is None:
            self._pending[what] = [1, reason]
        else:
            pending[0] += 1
        self._log(what, reason, now)
        return self.due(now)

    def _log(self, what: tuple[str, str], reason: str, now: float) -> None:
        told = self._told.get(what)
        if told is None:
            self._told[what] = _Told(now)
            log.warning("%s: dropped a payload on %r: %s (%s; counted, logged at most once a "
                        "minute per key and cause)", self.node, what[0], reason, what[1])
            return
        told.since += 1
        if now - told.at >= LOG_EVERY_S:
            log.warning("%s: dropped %d more payloads on %r (%s) in %.0f s, e.g. %s", self.node,
                        told.since, what[0], what[1], now - told.at, reason)
            told.at, told.since = now, 0

    def due(self, now: float) -> PayloadDrops | None:
        """The summary of the drops since the last one, if there are some and it is time."""
        if not self._pending or now - self._summarised < SUMMARY_EVERY_S:
            return None
        drops = tuple((key, cause, count, reason)
                      for (key, cause), (count, reason) in self._pending.items())
        self._pending = {}
        self._summarised = now
        return PayloadDrops(now, drops)

    def causes(self) -> dict[str, dict[str, int]]:
        """Every drop so far, per key then cause (plain data, for the stats)."""
        out: dict[str, dict[str, int]] = {}
        for (key, cause), count in self.by_cause.items():
            out.setdefault(key, {})[cause] = count
        return out


def clamps(bindings: Mapping[str, Iterable[tuple[ChannelCodec, int, ElementCodec]]]
           ) -> dict[str, dict[str, int]]:
    """Values clamped into their field's range so far (kept, not dropped, but counted), per
    channel then field path; only fields that clamped some."""
    out: dict[str, dict[str, int]] = {}
    for found in bindings.values():
        for channel, _, element in found:
            for path, count in element.layout.clamped.items():
                if count:
                    fields = out.setdefault(channel.name, {})
                    fields[path or "(payload)"] = fields.get(path or "(payload)", 0) + count
    return out
