"""Link health: is each peer up, degraded or down, from when it was last heard (pure)."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

from bridge.mission.model import Mission, TdmaMac


class LinkState(StrEnum):
    UP = "up"
    DEGRADED = "degraded"
    DOWN = "down"


@dataclass(frozen=True)
class LinkThresholds:
    """Silence after which a link is degraded, then down."""

    degraded_after_s: float
    down_after_s: float

    @classmethod
    def for_mission(cls, mission: Mission) -> LinkThresholds:
        if isinstance(mission.mac, TdmaMac):
            cycle = mission.mac.slot_s * len(mission.mac.order)
            degraded, down = 2 * cycle, 4 * cycle
        else:
            degraded, down = 10.0, 30.0
        link = mission.link
        degraded = link.degraded_after_s or degraded
        down = link.down_after_s or max(down, degraded)
        return cls(degraded, max(down, degraded))

    def state(self, last_heard: float | None, now: float) -> LinkState:
        if last_heard is None or now - last_heard >= self.down_after_s:
            return LinkState.DOWN
        if now - last_heard >= self.degraded_after_s:
            return LinkState.DEGRADED
        return LinkState.UP
