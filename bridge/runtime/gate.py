"""What a node publishes on ``@zab/<mission>/<node>/events``, at a bounded rate.

Every event goes to the node's observers (its mission log, a fleet's report) as it comes, but
a frame dropped is news a flood of junk datagrams can make thousands of times a second: on
``…/events`` each drop reason goes out at most once every :data:`EVERY_S`, the next one saying
how many were held back since (``held_back``). Payload drops come already summarised (at most
one :class:`~bridge.core.events.PayloadDrops` a second) and every other event is rare (a
link's change, a failed delivery, a modem down): those all go out.
"""

from __future__ import annotations

import math

from bridge.core.events import Event, FrameDropped

EVERY_S = 1.0


class EventGate:
    """Decides which events go out, and counts those held back."""

    def __init__(self) -> None:
        self._last: dict[str, float] = {}
        self._held: dict[str, int] = {}
        self.held_back = 0

    def admit(self, event: Event, now: float) -> int | None:
        """None: hold ``event`` back; else it goes out, with how many like it were held back
        since the last that went out."""
        if not isinstance(event, FrameDropped):
            return 0
        reason = event.reason
        if now - self._last.get(reason, -math.inf) < EVERY_S:
            self._held[reason] = self._held.get(reason, 0) + 1
            self.held_back += 1
            return None
        self._last[reason] = now
        return self._held.pop(reason, 0)
