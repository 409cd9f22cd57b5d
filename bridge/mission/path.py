"""Scripted paths: where a simulated node is at a given time, pure and clock-free.

A :class:`Path` is a list of waypoints ``(x, y, depth)`` in metres, followed in order at a
constant ``speed_mps`` along straight legs. Without ``loop`` the node stops at the last waypoint;
with ``loop`` it sails back to the first and goes round again (seed 001's "roughly rectangular
trajectory of 10 m × 30 m" is four waypoints and ``loop``). Time is seconds since the path
started; before 0 the node waits at the first waypoint.
"""

from __future__ import annotations

import bisect
import itertools
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

__all__ = ["Path", "rectangle"]

Waypoint = tuple[float, float, float]


@dataclass(frozen=True)
class Path:
    """Waypoints sailed at ``speed_mps``; ``loop`` closes the route back to the start."""

    waypoints: tuple[Waypoint, ...]
    speed_mps: float
    loop: bool = False
    _ends: tuple[float, ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        points = tuple(_waypoint(p) for p in self.waypoints)
        if not points:
            raise ValueError("a path needs at least one waypoint")
        if not (math.isfinite(self.speed_mps) and self.speed_mps > 0):
            raise ValueError(f"path speed must be a positive number of m/s, not {self.speed_mps}")
        object.__setattr__(self, "waypoints", points)
        stops = [*points, points[0]] if self.loop else list(points)
        ends, total = [], 0.0
        for a, b in itertools.pairwise(stops):
            total += math.dist(a, b)
            ends.append(total)
        object.__setattr__(self, "_ends", tuple(ends))

    @classmethod
    def from_spec(cls, spec: Any) -> Path:
        """A path from the mission's ``path`` model (or any object with ``waypoints``,
        ``speed_mps`` and ``loop``; waypoints with ``x``, ``y``, ``depth`` or as triples)."""
        points = [(p.x, p.y, p.depth) if hasattr(p, "x") else tuple(p) for p in spec.waypoints]
        return cls(tuple(points), float(spec.speed_mps), bool(spec.loop))

    @property
    def length_m(self) -> float:
        """Metres of one pass (with ``loop``, including the leg back to the start)."""
        return self._ends[-1] if self._ends else 0.0

    @property
    def duration_s(self) -> float:
        """Seconds of one pass."""
        return self.length_m / self.speed_mps

    def position_at(self, t: float) -> Waypoint:
        """Where the node is ``t`` seconds after the path started."""
        if not math.isfinite(t):
            raise ValueError(f"path time must be finite, not {t}")
        if not self._ends or self.length_m == 0.0 or t <= 0:
            return self.waypoints[0]
        s = t * self.speed_mps
        if self.loop:
            s %= self.length_m
        elif s >= self.length_m:
            return self.waypoints[-1]
        leg = bisect.bisect_right(self._ends, s)
        leg = min(leg, len(self._ends) - 1)
        start = self._ends[leg - 1] if leg else 0.0
        a = self.waypoints[leg]
        b = self.waypoints[(leg + 1) % len(self.waypoints)]
        span = self._ends[leg] - start
        f = (s - start) / span if span > 0 else 0.0
        return (a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1]), a[2] + f * (b[2] - a[2]))


def rectangle(corner: Sequence[float], width_m: float, height_m: float, depth: float,
              speed_mps: float) -> Path:
    """A looping rectangle from ``corner`` (x, y): east ``width_m``, north ``height_m``."""
    x, y = float(corner[0]), float(corner[1])
    points = [(x, y, depth), (x + width_m, y, depth), (x + width_m, y + height_m, depth),
              (x, y + height_m, depth)]
    return Path(tuple(points), speed_mps, loop=True)


def _waypoint(p: Iterable[float]) -> Waypoint:
    values = tuple(float(v) for v in p)
    if len(values) != 3 or not all(map(math.isfinite, values)):
        raise ValueError(f"a waypoint is three finite numbers (x, y, depth), not {p!r}")
    return (values[0], values[1], values[2])
