"""``aloha``: a node sends when due after a random backoff (uniform in ``[0, backoff_s]``;
slotted: whole slots, starts on slot boundaries); after a frame of airtime ``a`` the next
starts at least ``a / max_airtime_share`` later (pure). Random access: its opportunities have
no ``until`` (a modem's retry is one more random access)."""

from __future__ import annotations

import math
import random
from typing import Any

from bridge.core.mac.base import EPS, MacReport, Opportunity, Schedule, airtime_share
from bridge.core.mac.random_access import RandomAccess
from bridge.core.mac.timing import busy_s, frame_time_s
from bridge.mission.model import AlohaMac, Mission

__all__ = ["Aloha", "AlohaSchedule", "aloha_slot_s"]


class AlohaSchedule(Schedule):
    """Pure or slotted ALOHA with a random backoff and an airtime cap."""

    def __init__(self, mac: AlohaMac, slot_s: float | None, rng: random.Random) -> None:
        if mac.slotted and (slot_s is None or slot_s <= 0):
            raise ValueError("slotted ALOHA needs slot_s > 0")
        self.slotted = mac.slotted
        self.slot_s = slot_s
        self.backoff_s = mac.backoff_s
        self.share = mac.max_airtime_share
        self._rng = rng
        self._start: float | None = None  # this frame's start, backoff included, until used
        self._free_at = -math.inf

    def _draw(self) -> float:
        if self.backoff_s <= 0:
            return 0.0
        if self.slotted:
            assert self.slot_s is not None
            return self._rng.randint(0, int(self.backoff_s / self.slot_s + EPS)) * self.slot_s
        return self._rng.uniform(0.0, self.backoff_s)

    def next_opportunity(self, now: float, due: float | None) -> Opportunity | None:
        if due is None:
            return None
        earliest = max(now, due, self._free_at)
        if self._start is None:
            if earliest > now:  # not due yet (say, a heartbeat): wake then, draw then
                return Opportunity(earliest)
            self._start = earliest + self._draw()  # a new frame: draw its backoff once
        start = max(self._start, due, self._free_at)
        if self.slotted:
            assert self.slot_s is not None
            start = math.ceil(start / self.slot_s - EPS) * self.slot_s
        return Opportunity(start)

    def on_sent(self, start: float, end: float) -> None:
        self._start = None
        self._free_at = start + max(0.0, end - start) / self.share

    def on_skipped(self, now: float) -> None:
        self._start = None


def aloha_slot_s(mission: Mission, mac: AlohaMac) -> float | None:
    """The ALOHA slot: given, or the longest frame time of any node."""
    if mac.slot_s is not None:
        return mac.slot_s
    times = [frame_time_s(mission, n) for n in mission.nodes]
    if any(t is None for t in times):
        return None
    return max(t for t in times if t is not None)


class Aloha(RandomAccess):
    """Pure or slotted ALOHA."""

    def __init__(self, mission: Any) -> None:
        super().__init__(mission)
        assert isinstance(mission.mac, AlohaMac)
        self.model: AlohaMac = mission.mac

    def _schedule(self, node: str, seed: int | None) -> Schedule:
        mission, mac = self.mission, self.model
        slot = aloha_slot_s(mission, mac) if mac.slotted else None
        if mac.slotted and slot is None:
            raise ValueError("slotted aloha: slot_s is needed (no modem preset to compute it)")
        base = seed if seed is not None else mission.modem.options.get("seed", 0)
        return AlohaSchedule(mac, slot, random.Random(f"{mission.mission}/{node}/{base}"))

    def problems(self) -> list[tuple[tuple[str | int, ...], str]]:
        found = []
        if self.model.slotted and aloha_slot_s(self.mission, self.model) is None:
            found.append((("mac", "slot_s"), "required for slotted aloha: a node's modem has "
                          "no preset to compute it from"))
        return [*found, *super().problems()]

    def _report(self, node: str, airtime_s: float | None, data_per_s: float) -> MacReport:
        mac = self.model
        spacing = max(busy_s(self.mission, node) or 0.0, (airtime_s or 0.0) /
                      mac.max_airtime_share)
        slot = aloha_slot_s(self.mission, mac) if mac.slotted else 0.0
        worst = spacing + mac.backoff_s + (slot or 0.0)
        per_s = 1 / (spacing + mac.backoff_s / 2) if spacing + mac.backoff_s > 0 else None
        return MacReport(round(worst, 4) if worst > 0 else None,
                         airtime_share(airtime_s, per_s, data_per_s),
                         "random access: collisions possible", True, per_s)

    def check(self, nodes: list[dict[str, Any]]) -> tuple[dict[str, Any], list[str]]:
        mission, mac = self.mission, self.model
        slot = aloha_slot_s(mission, mac) if mac.slotted else None
        data: dict[str, Any] = {"slotted": mac.slotted,
                                "slot_s": None if slot is None else round(slot, 4)}
        warnings = []
        if slot is not None:
            for name in mission.nodes:
                need = frame_time_s(mission, name)
                if need is not None and need > slot:
                    warnings.append(f"{name}: an aloha slot of {slot:.3f} s is shorter "
                                    f"than its largest frame needs ({need:.3f} s)")
        more, also = super().check(nodes)
        return {**data, **more}, [*warnings, *also]
