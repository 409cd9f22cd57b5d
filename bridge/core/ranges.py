"""A node's ranges and fixes as outputs: DLBL delays of the frames it sends and hears, ranges
its modem measures, pings it asks for, and what :class:`Positioning` makes of them (pure).

Each range goes out as the ``range/<peer>`` status and a :class:`Range` event, each fix (the
tracker's estimate, or a bare fix where there is no tracker) as ``position`` and a
:class:`Position` event.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from bridge.core.events import Position, Range, RangeFailed
from bridge.core.outputs import Outbox
from bridge.core.positioning import Positioning, Update
from bridge.core.reception import Reception
from bridge.mission.model import Mission

__all__ = ["Ranges"]

Drop = Callable[[str, str, float], None]
"""Counts a payload that cannot be used: ``(key, reason, now)``."""


class Ranges:
    """Positioning of one node, with what it outputs."""

    def __init__(self, mission: Mission, positioning: Positioning, outbox: Outbox,
                 drop: Drop) -> None:
        self.mission = mission
        self.positioning = positioning
        self.outbox = outbox
        self.drop = drop
        self.dlbl = mission.wire.dlbl
        # output key -> anchor: live anchor positions this bridge decodes from frames itself
        self.anchor_keys = {key: anchor for anchor, key in mission.ranging.anchor_keys.items()
                            if anchor in positioning.anchors}
        self._ranged_last = False  # a range never takes two transmit opportunities in a row

    # -- frames ----------------------------------------------------------------------------------

    def on_transmit(self, at: float) -> list[int | None]:
        """The DLBL delays of a frame starting at modem time ``at``."""
        return self.positioning.on_transmit(at)

    def forget_transmit(self, at: float) -> None:
        """The frame that was to start at ``at`` never left."""
        self.positioning.forget_transmit(at)

    def anchor_value(self, key: str, value: Any, anchors: dict[str, tuple[float, float, float]],
                     now: float) -> None:
        """A value on output ``key``: if it is an anchor's live position
        (``ranging.anchor_keys``), kept in ``anchors`` for the frame's ranges (counted as a
        dropped payload if it has no finite x, y, depth)."""
        anchor = self.anchor_keys.get(key)
        if anchor is None:
            return
        try:
            position = tuple(float(value[k]) for k in ("x", "y", "depth"))
            if not all(map(math.isfinite, position)):
                raise ValueError("not finite")
        except (TypeError, KeyError, ValueError) as exc:
            self.drop(key, f"needs numbers x, y, depth: {exc}", now)
            return
        anchors[anchor] = position  # type: ignore[assignment]

    def heard(self, src: str, rx: Reception, delays: tuple[int | None, ...], modem_now: float,
              now: float, anchors: dict[str, tuple[float, float, float]]) -> None:
        """The frame ``rx`` from ``src`` carried ``delays`` (and the live ``anchors``
        positions); ``modem_now``: the modem clock now."""
        positioning = self.positioning
        if self.dlbl:
            start = float(rx.meta.get("start", rx.time))  # (the modem's clock, as the delays)
            self._positioned(positioning.on_receive(src, start, delays, modem_now, now,
                                                    anchors), now)
        else:
            for anchor, position in anchors.items():
                positioning.set_anchor(anchor, position, now)

    # -- the modem's own ranges ------------------------------------------------------------------

    def modem_range(self, peer: str, travel_time_s: float, method: str, time: float,
                    now: float) -> None:
        """The modem measured a range itself (a ping, a propagation time)."""
        self._positioned(self.positioning.on_modem_range(peer, travel_time_s, method, time), now)

    def due(self, now: float) -> int | None:
        """The address to ask the modem to range to at this transmit opportunity
        (``ranging.ping``); never at two opportunities in a row, so frames still go out."""
        if self._ranged_last:
            self._ranged_last = False
            return None
        peer = self.positioning.ping_due(now)
        return None if peer is None else self.mission.address_of(peer)

    def asked(self, peer: str, now: float, error: str | None) -> None:
        """A range to ``peer`` was asked of the modem; ``error`` says why it failed."""
        self._ranged_last = True
        self.positioning.pinged(peer, now)
        if error is not None:
            self.outbox.event(RangeFailed(now, peer, error))

    def next_ping(self) -> float | None:
        return self.positioning.next_ping()

    def tick(self, now: float) -> None:
        """Coasting, or lost, is news."""
        if estimate := self.positioning.report(now):
            self._positioned(Update((), None, estimate), now)

    def _positioned(self, update: Update, now: float) -> None:
        """Publish the ranges of ``update`` and its fix (or why there is none)."""
        for rng in update.ranges:
            event = Range(**{**self.positioning.range_payload(rng), "time": now})
            self.outbox.status(f"range/{rng.peer}", event.to_dict())
            self.outbox.event(event)
        found = update.estimate if update.estimate is not None else update.fix
        if found is not None:  # the tracker's estimate; a bare fix where there is no tracker
            position = Position(now, found)
            self.outbox.status("position", position.to_dict())
            self.outbox.event(position)
