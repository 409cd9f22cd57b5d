"""Link health: is each peer up, degraded or down, from when it was last heard (pure).

A node that has nothing to send still sends a *heartbeat* (an empty frame) at least every
``heartbeat_s``, so its peers can tell silence from absence. By default that is one TDMA cycle
(every slot carries a frame), or :data:`FREE_HEARTBEAT_S` with random access; the polled MAC
needs none (every poll and every reply is a frame). A peer is *degraded* after
:data:`DEGRADED_PERIODS` and *down* after :data:`DOWN_PERIODS` of its periods without a frame,
its period being the longer of its heartbeat and the MAC's cycle: at 40 % frame loss a peer
that keeps sending looks down once in about 2 500 periods (0.4 ** 8 per period), where the
former 4 cycles without a heartbeat went down while a sender waited out its retransmissions.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

from bridge.mission.model import Mission, PolledMac, TdmaMac

FREE_HEARTBEAT_S = 10.0
DEGRADED_PERIODS = 3
DOWN_PERIODS = 8


class LinkState(StrEnum):
    UP = "up"
    DEGRADED = "degraded"
    DOWN = "down"


def heartbeat_s(mission: Mission) -> float | None:
    """How often a node sends at least a frame: the mission's ``link.heartbeat_s``, or its
    default from the MAC (None: the MAC makes every node send anyway)."""
    if mission.link.heartbeat_s is not None:
        return mission.link.heartbeat_s
    mac = mission.mac
    if isinstance(mac, TdmaMac):
        return mac.slot_s * len(mac.order)
    if isinstance(mac, PolledMac):
        return None
    return FREE_HEARTBEAT_S


@dataclass(frozen=True)
class LinkThresholds:
    """Silence after which a link is degraded, then down."""

    degraded_after_s: float
    down_after_s: float

    @classmethod
    def for_mission(cls, mission: Mission) -> LinkThresholds:
        mac = mission.mac
        cycle = mac.slot_s * len(mac.order) if isinstance(mac, TdmaMac) else 0.0
        period = max(heartbeat_s(mission) or 0.0, cycle) or FREE_HEARTBEAT_S
        link = mission.link
        degraded = link.degraded_after_s or DEGRADED_PERIODS * period
        down = link.down_after_s or max(DOWN_PERIODS * period, degraded)
        return cls(degraded, max(down, degraded))

    def state(self, last_heard: float | None, now: float) -> LinkState:
        if last_heard is None or now - last_heard >= self.down_after_s:
            return LinkState.DOWN
        if now - last_heard >= self.degraded_after_s:
            return LinkState.DEGRADED
        return LinkState.UP
