"""``none``: no access control; a node sends whenever something is due, at least
``min_gap_s`` after its previous frame (pure). Its opportunities have no ``until``: no turn
ends, so a modem may retry a frame for as long as it tries."""

from __future__ import annotations

from typing import Any

from bridge.core.mac.base import MacReport, Opportunity, Schedule, airtime_share
from bridge.core.mac.random_access import RandomAccess
from bridge.core.mac.timing import busy_s
from bridge.mission.model import NoMac

__all__ = ["Free", "FreeSchedule"]


class FreeSchedule(Schedule):
    """No access control: any time, with a minimum gap between frames."""

    def __init__(self, mac: NoMac) -> None:
        self.min_gap_s = mac.min_gap_s
        self._last: float | None = None

    def earliest(self, now: float, last_start: float | None) -> float:
        """When the next frame may start."""
        if last_start is None:
            return now
        return max(now, last_start + self.min_gap_s)

    def next_opportunity(self, now: float, due: float | None) -> Opportunity | None:
        if due is None:
            return None
        return Opportunity(max(self.earliest(now, self._last), due))

    def on_sent(self, start: float, end: float) -> None:
        self._last = start


class Free(RandomAccess):
    """``mac: none``."""

    def __init__(self, mission: Any) -> None:
        super().__init__(mission)
        assert isinstance(mission.mac, NoMac)
        self.model: NoMac = mission.mac

    def _schedule(self, node: str, seed: int | None) -> Schedule:
        return FreeSchedule(self.model)

    def _report(self, node: str, airtime_s: float | None, data_per_s: float) -> MacReport:
        spacing = max(busy_s(self.mission, node) or 0.0, self.model.min_gap_s)
        per_s = 1 / spacing if spacing else None
        return MacReport(spacing or None, airtime_share(airtime_s, per_s, data_per_s),
                         "no access control: collisions possible", True, per_s)
