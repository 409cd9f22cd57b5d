"""``tdma``: slot ``k`` (starting ``k * slot_s`` after the Unix epoch) belongs to
``order[k % len(order)]``; vehicles with disciplined clocks agree without talking. The last
``guard_s`` of a slot stays silent: a slot's opportunity has that as its ``until``, so a modem
never begins a transmission or a retry in it, nor in the next node's slot. With DLBL every slot
carries a frame (pure)."""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from typing import Any

from bridge.core.mac.base import EPS, LATE_S, Mac, MacReport, Opportunity, OpportunityKind, Schedule
from bridge.mission.model import TdmaMac

__all__ = ["Slot", "Tdma", "TdmaSchedule"]


@dataclass(frozen=True)
class Slot:
    """A TDMA slot: start no earlier than ``start``, be silent by ``end``."""

    start: float
    end: float


class TdmaSchedule(Schedule):
    """The static TDMA cycle as seen by one node."""

    fixed = True

    def __init__(self, mac: TdmaMac, node: str, *, always: bool = False) -> None:
        self.slot_s = mac.slot_s
        self.guard_s = mac.guard_s
        self.order = tuple(mac.order)
        self.owned = tuple(i for i, owner in enumerate(self.order) if owner == node)
        self.cycle_s = self.slot_s * len(self.order)
        self.always = always
        self._used = -math.inf

    def next_slot(self, after: float) -> Slot | None:
        """This node's first slot starting strictly after ``after``; None if it owns none."""
        if not self.owned:
            return None
        k = math.floor(after / self.slot_s) + 1
        n, owned = len(self.order), self.owned  # owned: ascending slot indices
        phase = k % n
        i = bisect.bisect_left(owned, phase)  # the first owned slot at or after k's phase
        k += owned[i] - phase if i < len(owned) else owned[0] + n - phase
        start = k * self.slot_s
        return Slot(start, start + self.slot_s - self.guard_s)

    def next_opportunity(self, now: float, due: float | None) -> Opportunity | None:
        late = min(LATE_S, self.usable_s() / 10)
        slot = self.next_slot(max(self._used, now - late - EPS))
        if slot is None:
            return None
        return Opportunity(slot.start, slot.start + late, self.always, None, OpportunityKind.SLOT,
                           slot.end)

    def on_sent(self, start: float, end: float) -> None:
        self._used = max(self._used, start)

    def on_skipped(self, now: float) -> None:
        self._used = max(self._used, now)

    def usable_s(self) -> float:
        """Seconds of each slot in which a frame must fit (airtime + propagation)."""
        return self.slot_s - self.guard_s

    def worst_gap_s(self) -> float | None:
        """Longest wait between two of this node's slot starts."""
        if not self.owned:
            return None
        n = len(self.order)
        starts = sorted(self.owned)
        gaps = [(b - a) for a, b in zip(starts, [*starts[1:], starts[0] + n], strict=True)]
        return max(gaps) * self.slot_s


class Tdma(Mac):
    """Static TDMA over the mission's ``order``."""

    def __init__(self, mission: Any) -> None:
        super().__init__(mission)
        assert isinstance(mission.mac, TdmaMac)
        self.model: TdmaMac = mission.mac

    def schedule(self, node: str, seed: int | None = None) -> TdmaSchedule:
        return TdmaSchedule(self.model, node, always=self.mission.wire.dlbl)

    def problems(self) -> list[tuple[tuple[str | int, ...], str]]:
        return [(("mac", "order", i), f"unknown node {owner!r}")
                for i, owner in enumerate(self.model.order) if owner not in self.mission.nodes]

    def turn_missing(self, node: str) -> str | None:
        if node in self.model.order:
            return None
        return f"it owns no TDMA slot (mac.order); add {node} to mac.order"

    def report(self, node: str, airtime_s: float | None, data_per_s: float) -> MacReport:
        tdma = TdmaSchedule(self.model, node)
        gap = tdma.worst_gap_s()
        per_s = len(tdma.owned) / tdma.cycle_s
        share = None if airtime_s is None else round(min(1.0, airtime_s * per_s), 4)
        return MacReport(gap, share, "" if gap else "owns no slot: listens only",
                         turns_per_s=per_s)

    def check_node(self, node: str, need_s: float | None,
                   airtime_s: float | None) -> tuple[dict[str, Any], list[str]]:
        schedule = TdmaSchedule(self.model, node)
        usable = schedule.usable_s()
        warnings = []
        if need_s is not None and need_s > usable:
            warnings.append(f"{node}: TDMA slot leaves {usable:.3f} s but a full frame "
                            f"needs {need_s:.3f} s (modem latency + airtime "
                            f"{airtime_s:.3f} s + propagation)")
        return {"slot_s": usable, "worst_gap_s": schedule.worst_gap_s()}, warnings

    def cycle_s(self) -> float:
        return self.model.slot_s * len(self.model.order)

    def heartbeat_s(self) -> float:
        return self.cycle_s()  # every slot carries a frame

    def retry_s(self) -> float:
        return self.cycle_s()

    def dlbl_travel_s(self, node: str) -> float:
        order = self.model.order
        owned = [i for i, n in enumerate(order) if n == node]
        if not owned:
            return 1.0
        gaps = [(b - a) % len(order) or len(order)
                for a, b in zip(owned, [*owned[1:], owned[0]], strict=True)]
        return min(1.0, 0.45 * min(gaps) * self.model.slot_s)

    def clock_limits(self) -> tuple[float, float]:
        guard = self.model.guard_s
        return (guard / 2 if guard > 0 else self.model.slot_s / 20), guard
