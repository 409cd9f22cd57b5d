"""One node's ranging and localisation, fed by the frames it hears (pure: times passed in).

DLBL ranges come from the delay vectors every frame carries (:mod:`bridge.ranging.dlbl`);
ranges to anchors with known positions give a fix (:func:`bridge.ranging.localise.locate`).
The runtime publishes what this returns under ``@zab/<mission>/<node>/range/<peer>`` and
``@zab/<mission>/<node>/position``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from bridge.mission import Mission, TdmaMac
from bridge.ranging import DlblRanger, Fix, Range, SoundSpeed, locate

DEFAULT_SOUND_SPEED_MPS = 1500.0


def mission_sound_speed(mission: Mission) -> SoundSpeed:
    """The sound speed the mission sets: fixed, computed from water properties, or 1500 m/s."""
    ranging = mission.ranging
    if ranging.water is not None:
        w = ranging.water
        return SoundSpeed.from_ctd(w.temperature_c, w.salinity_psu, w.depth_m,
                                   equation=w.equation, lat_deg=w.latitude_deg)
    return SoundSpeed.fixed(ranging.sound_speed_mps or DEFAULT_SOUND_SPEED_MPS)


def mission_anchors(mission: Mission) -> tuple[str, ...]:
    if mission.ranging.anchors is not None:
        return tuple(mission.ranging.anchors)
    return tuple(n for n, node in mission.nodes.items()
                 if node.role == "surface" and node.position is not None)


@dataclass(frozen=True)
class Update:
    """What one reception produced: ranges, and a fix when the anchors allowed one."""

    ranges: tuple[Range, ...]
    fix: Fix | None


class Positioning:
    """DLBL bookkeeping, the latest range to each peer, anchor positions and fixes."""

    def __init__(self, mission: Mission, node: str) -> None:
        ranging = mission.ranging
        self.node = node
        self.sound_speed = mission_sound_speed(mission)
        cycle = None
        max_travel = 1.0
        if isinstance(mission.mac, TdmaMac):
            order = mission.mac.order
            cycle = mission.mac.slot_s * len(order)
            owned = [i for i, n in enumerate(order) if n == node]
            if owned:  # a reply must not match two of our own transmissions
                gaps = [(b - a) % len(order) or len(order)
                        for a, b in zip(owned, [*owned[1:], owned[0]], strict=True)]
                max_travel = min(max_travel, 0.45 * min(gaps) * mission.mac.slot_s)
        self.ranger = DlblRanger(node, tuple(mission.nodes), tx_latency_s=ranging.tx_latency_s,
                                 rx_latency_s=ranging.rx_latency_s, max_travel_s=max_travel,
                                 cycle_s=cycle)
        self.anchors = tuple(a for a in mission_anchors(mission) if a != node)
        self.localises = node not in mission_anchors(mission) and len(self.anchors) >= 2
        self.anchor_positions: dict[str, tuple[float, float, float]] = {
            a: (p.x, p.y, p.depth) for a in self.anchors
            if (p := mission.nodes[a].position) is not None
        }
        own = mission.nodes[node].position
        self.depth: float | None = own.depth if own else None
        self.previous: tuple[float, float] | None = (own.x, own.y) if own else None
        self.fix_max_age_s = ranging.fix_max_age_s or cycle or 30.0
        self.latest: dict[str, Range] = {}

    def on_transmit(self, t_start: float) -> list[int | None]:
        return self.ranger.on_transmit(t_start)

    def forget_transmit(self, t_start: float) -> None:
        self.ranger.forget_transmit(t_start)

    def set_depth(self, depth: float) -> None:
        self.depth = depth

    def set_anchor(self, anchor: str, position: tuple[float, float, float]) -> None:
        self.anchor_positions[anchor] = position

    def set_water(self, temperature_c: float, salinity_psu: float, depth_m: float) -> None:
        self.sound_speed = SoundSpeed.from_ctd(temperature_c, salinity_psu, depth_m)

    def on_receive(self, src: str, t_rx_start: float, delays: Sequence[int | None],
                   now: float) -> Update:
        ranges = tuple(self.ranger.on_receive(src, t_rx_start, delays))
        for rng in ranges:
            self.latest[rng.peer] = rng
        fix = self.locate(now) if ranges and self.localises else None
        return Update(ranges, fix)

    def locate(self, now: float) -> Fix | None:
        """A fix from the fresh ranges to anchors with known positions, or None."""
        if self.depth is None:
            return None
        names, anchors, ranges = [], [], []
        for anchor in self.anchors:
            rng, pos = self.latest.get(anchor), self.anchor_positions.get(anchor)
            if rng is None or pos is None or now - rng.time > self.fix_max_age_s:
                continue
            names.append(anchor)
            anchors.append(pos)
            ranges.append(rng.range_m(self.sound_speed.mps))
        fix = locate(anchors, ranges, self.depth, self.previous, names=names)
        if fix is not None:
            self.previous = (fix.x, fix.y)
        return fix

    def range_payload(self, rng: Range) -> Mapping[str, Any]:
        return rng.payload(self.sound_speed.mps)
