"""How much wider a track gets while it coasts without a compass: the turns it cannot see.

A constant-velocity prediction with the tracker's small acceleration noise says where a vehicle
that held its course is; over a long gap without ranges (out of range, a lost cycle or ten) it
may as well have turned, to any heading, at any time. With a turn about every ``turn_every_s``
(``q = 1 − e^(−gap/turn_every_s)`` the chance of one in the gap), at speed ``v``, a turn at a
uniform time within the gap to a uniform heading moves the velocity by ``v`` per axis (1-σ)
and the position by ``v·gap/√3`` per axis, correlated (``v²·gap/2``): added, weighted by
``q``. (A vehicle that reached the end of a line and came back is then inside the published
ellipse, and the next ranges are not refused for disagreeing with a course it no longer
holds.)
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from bridge.ranging.kalman import Matrix


def coast_widened(x: Sequence[float], p: Sequence[Sequence[float]], gap_s: float,
                  turn_every_s: float) -> Matrix:
    """``p`` (4×4, of ``[x, y, vx, vy]``) widened for ``gap_s`` seconds of coasting in which
    the vehicle may have turned (once every ``turn_every_s`` seconds, at its speed)."""
    out = [list(row) for row in p]
    if gap_s <= 0 or turn_every_s <= 0:
        return out
    v2 = x[2] ** 2 + x[3] ** 2
    q = -math.expm1(-gap_s / turn_every_s)
    for i in (0, 1):
        out[i][i] += q * v2 * gap_s**2 / 3
        out[i + 2][i + 2] += q * v2
        out[i][i + 2] += q * v2 * gap_s / 2
        out[i + 2][i] += q * v2 * gap_s / 2
    return out


__all__ = ["coast_widened"]
