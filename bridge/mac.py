"""Medium access: when may this node start a transmission (pure, time passed in).

``tdma``: slot ``k`` (starting at ``k * slot_s`` seconds after the Unix epoch) belongs to
``order[k % len(order)]``, so vehicles with disciplined clocks agree without talking. A node
sends one frame at the start of each of its slots; the last ``guard_s`` of a slot stays silent
so the frame's tail can cross the water before the next owner speaks.

``none``: send whenever something is due, at least ``min_gap_s`` after the previous frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from bridge.mission import Mission, NoMac, TdmaMac


@dataclass(frozen=True)
class Slot:
    """A transmit opportunity: start no earlier than ``start``, be silent by ``end``."""

    start: float
    end: float


class TdmaSchedule:
    """The static TDMA cycle as seen by one node."""

    def __init__(self, mac: TdmaMac, node: str) -> None:
        self.slot_s = mac.slot_s
        self.guard_s = mac.guard_s
        self.order = tuple(mac.order)
        self.owned = tuple(i for i, owner in enumerate(self.order) if owner == node)
        self.cycle_s = self.slot_s * len(self.order)

    def next_slot(self, after: float) -> Slot | None:
        """This node's first slot starting strictly after ``after``; None if it owns none."""
        if not self.owned:
            return None
        k = math.floor(after / self.slot_s) + 1
        n = len(self.order)
        while (k % n) not in self.owned:
            k += 1
        start = k * self.slot_s
        return Slot(start, start + self.slot_s - self.guard_s)

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


class FreeSchedule:
    """No access control: any time, with a minimum gap between frames."""

    def __init__(self, mac: NoMac) -> None:
        self.min_gap_s = mac.min_gap_s

    def earliest(self, now: float, last_start: float | None) -> float:
        """When the next frame may start."""
        if last_start is None:
            return now
        return max(now, last_start + self.min_gap_s)


def schedule_for(mission: Mission, node: str) -> TdmaSchedule | FreeSchedule:
    mac = mission.mac
    return TdmaSchedule(mac, node) if isinstance(mac, TdmaMac) else FreeSchedule(mac)
