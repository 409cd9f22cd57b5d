"""Position from ranges to anchors (seed 001 section III), pure Python.

Anchors are nodes that know their position (surface nodes with GNSS, or moored). A submerged
node knows its depth, so each slant range ``d`` to an anchor becomes a horizontal range
``r = √(d² − Δz²)`` in the node's plane (seed 001 eq. 4), and:

- two anchors: the two circles meet in two points; the one nearer the previous estimate wins
  (seed 001 III-B). With no previous estimate the ambiguity cannot be resolved and there is no
  fix (the caller starts from its GNSS position at the surface). Circles that do not meet give
  the point of closest approach, with a sigma grown by half the gap.
- three or more: nonlinear least squares on the slant ranges (Levenberg–Marquardt), started
  from the linearised solution, the previous estimate and the circle intersections; sigma from
  the residuals. Anchors on one line leave a mirror ambiguity, resolved like two anchors.
- fewer than two: no fix.

:func:`attempt` says why there is no fix (:class:`NoFix`, published as such); :func:`locate`
returns ``None`` instead.

Coordinates are metres in any local horizontal frame (x east, y north); depth positive down.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

Point = tuple[float, float]
Anchor = tuple[float, float, float]  # x, y, depth


@dataclass(frozen=True)
class Fix:
    """A position estimate: ``sigma_m`` is the 1-σ horizontal error radius (√(σx² + σy²))."""

    x: float
    y: float
    depth: float
    sigma_m: float
    anchors: tuple[str, ...]
    method: str
    residual_m: float = 0.0
    alternative: Point | None = None  # the rejected mirror candidate, if any

    def payload(self, time: float) -> dict[str, bool | float | str | list[str]]:
        """The map published on ``@zab/<mission>/<node>/position``."""
        return {
            "fix": True,
            "x": self.x,
            "y": self.y,
            "depth": self.depth,
            "time": time,
            "sigma_m": self.sigma_m,
            "anchors": list(self.anchors),
            "method": self.method,
        }


NO_FIX_REASONS = {
    "too_few_anchors": "fewer than two anchors with a fresh range and a known position",
    "ambiguous": "two positions fit the ranges and no previous estimate tells them apart",
    "degenerate_geometry": "the anchors' geometry gives no position (e.g. concentric circles)",
    "no_depth": "this node's depth is unknown",
}
"""Why a fix attempt gave no position (``reason`` of :class:`NoFix`)."""


@dataclass(frozen=True)
class NoFix:
    """A fix was attempted and gave no position: ``reason`` is a key of :data:`NO_FIX_REASONS`;
    ``anchors`` are the anchors that had a usable range."""

    reason: str
    anchors: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.reason not in NO_FIX_REASONS:
            raise ValueError(f"unknown no-fix reason {self.reason!r}")

    def payload(self, time: float) -> dict[str, bool | float | str | list[str]]:
        """The map published on ``@zab/<mission>/<node>/position`` instead of a fix."""
        return {
            "fix": False,
            "reason": self.reason,
            "detail": NO_FIX_REASONS[self.reason],
            "anchors": list(self.anchors),
            "time": time,
        }


def horizontal_range(slant_m: float, depth: float, anchor_depth: float) -> float:
    """The range projected into the node's horizontal plane (0 if the slant is too short)."""
    dz = depth - anchor_depth
    return math.sqrt(max(slant_m * slant_m - dz * dz, 0.0))


def intersect_circles(c1: Point, r1: float, c2: Point, r2: float) -> tuple[list[Point], float]:
    """Where two circles meet: ``(points, gap)``.

    Two points (one if tangent) and gap 0 when they meet; otherwise the single point of
    closest approach (halfway across the gap on the line of centres) and the gap in metres.
    Concentric circles give no point.
    """
    dx, dy = c2[0] - c1[0], c2[1] - c1[1]
    d = math.hypot(dx, dy)
    if d < 1e-9:
        return [], abs(r1 - r2)
    ux, uy = dx / d, dy / d
    if d > r1 + r2:  # apart
        gap = d - r1 - r2
        a = r1 + gap / 2
        return [(c1[0] + a * ux, c1[1] + a * uy)], gap
    if d < abs(r1 - r2):  # one inside the other: both nearest points lie on the same ray
        gap = abs(r1 - r2) - d
        a = r1 + gap / 2 if r1 < r2 else r1 - gap / 2
        sign = -1.0 if r1 < r2 else 1.0
        return [(c1[0] + sign * a * ux, c1[1] + sign * a * uy)], gap
    a = (r1 * r1 - r2 * r2 + d * d) / (2 * d)
    h = math.sqrt(max(r1 * r1 - a * a, 0.0))
    mx, my = c1[0] + a * ux, c1[1] + a * uy
    if h < 1e-9:
        return [(mx, my)], 0.0
    return [(mx - h * uy, my + h * ux), (mx + h * uy, my - h * ux)], 0.0


def _solve2(a11: float, a12: float, a22: float, b1: float, b2: float) -> Point | None:
    det = a11 * a22 - a12 * a12
    if abs(det) < 1e-12 * max(a11 * a22, 1e-300):
        return None
    return ((a22 * b1 - a12 * b2) / det, (a11 * b2 - a12 * b1) / det)


def _normal(anchors: Sequence[Anchor], depth: float, p: Point) -> tuple[float, float, float]:
    """JᵀJ of the slant-range model at ``p``: (a11, a12, a22)."""
    a11 = a12 = a22 = 0.0
    for ax, ay, az in anchors:
        ex, ey = p[0] - ax, p[1] - ay
        m = math.sqrt(ex * ex + ey * ey + (depth - az) ** 2) or 1e-9
        jx, jy = ex / m, ey / m
        a11, a12, a22 = a11 + jx * jx, a12 + jx * jy, a22 + jy * jy
    return a11, a12, a22


def dop(anchors: Sequence[Anchor], depth: float, p: Point) -> float:
    """Dilution of precision at ``p``: √trace((JᵀJ)⁻¹), horizontal error per metre of range."""
    a11, a12, a22 = _normal(anchors, depth, p)
    det = a11 * a22 - a12 * a12
    if det <= 1e-12:
        return math.inf
    return math.sqrt((a11 + a22) / det)


def _cost(anchors: Sequence[Anchor], ranges: Sequence[float], depth: float, p: Point) -> float:
    return sum(
        (math.sqrt((p[0] - ax) ** 2 + (p[1] - ay) ** 2 + (depth - az) ** 2) - d) ** 2
        for (ax, ay, az), d in zip(anchors, ranges, strict=True)
    )


def _least_squares(
    anchors: Sequence[Anchor], ranges: Sequence[float], depth: float, start: Point
) -> tuple[Point, float]:
    """Levenberg–Marquardt on slant-range residuals from ``start``: (point, sum of squares)."""
    p, lam = start, 1e-3
    cost = _cost(anchors, ranges, depth, p)
    for _ in range(100):
        a11 = a12 = a22 = g1 = g2 = 0.0
        for (ax, ay, az), d in zip(anchors, ranges, strict=True):
            ex, ey = p[0] - ax, p[1] - ay
            m = math.sqrt(ex * ex + ey * ey + (depth - az) ** 2) or 1e-9
            jx, jy, f = ex / m, ey / m, m - d
            a11, a12, a22 = a11 + jx * jx, a12 + jx * jy, a22 + jy * jy
            g1, g2 = g1 + jx * f, g2 + jy * f
        step = _solve2(a11 * (1 + lam) + 1e-12, a12, a22 * (1 + lam) + 1e-12, -g1, -g2)
        if step is None:
            break
        trial = (p[0] + step[0], p[1] + step[1])
        trial_cost = _cost(anchors, ranges, depth, trial)
        if trial_cost <= cost:
            p, cost, lam = trial, trial_cost, max(lam / 10, 1e-9)
            if math.hypot(*step) < 1e-7:
                break
        else:
            lam *= 10
            if lam > 1e9:
                break
    return p, cost


def _linear(anchors: Sequence[Anchor], hranges: Sequence[float]) -> Point | None:
    """Linearised solution: subtract the first circle's equation from the others."""
    (x0, y0, _), r0 = anchors[0], hranges[0]
    a11 = a12 = a22 = b1 = b2 = 0.0
    for (xi, yi, _), ri in zip(anchors[1:], hranges[1:], strict=True):
        u, v = 2 * (xi - x0), 2 * (yi - y0)
        w = r0 * r0 - ri * ri + xi * xi - x0 * x0 + yi * yi - y0 * y0
        a11, a12, a22, b1, b2 = a11 + u * u, a12 + u * v, a22 + v * v, b1 + u * w, b2 + v * w
    return _solve2(a11, a12, a22, b1, b2)


def _nearest(points: Sequence[Point], previous: Point) -> int:
    return min(range(len(points)), key=lambda i: math.dist(points[i], previous))


def locate(
    anchors: Sequence[Anchor],
    ranges: Sequence[float | None],
    depth: float,
    previous: Point | None = None,
    *,
    names: Sequence[str] | None = None,
    range_sigma_m: float = 0.1,
) -> Fix | None:
    """The node's position from slant ``ranges`` (m) to ``anchors`` (x, y, depth), or None.

    ``depth`` is the node's own depth. Ranges that are None, negative or not finite are
    ignored (a missing reply). ``previous`` (x, y) resolves two-anchor and mirror ambiguities;
    ``range_sigma_m`` is the expected range error, the floor of the sigma reported.
    """
    found = attempt(anchors, ranges, depth, previous, names=names, range_sigma_m=range_sigma_m)
    return found if isinstance(found, Fix) else None


def attempt(
    anchors: Sequence[Anchor],
    ranges: Sequence[float | None],
    depth: float,
    previous: Point | None = None,
    *,
    names: Sequence[str] | None = None,
    range_sigma_m: float = 0.1,
) -> Fix | NoFix:
    """Like :func:`locate`, but a failed attempt says why (:class:`NoFix`)."""
    if len(anchors) != len(ranges):
        raise ValueError(f"{len(anchors)} anchors but {len(ranges)} ranges")
    labels = list(names) if names is not None else [str(i) for i in range(len(anchors))]
    used = [i for i, r in enumerate(ranges) if r is not None and math.isfinite(r) and r >= 0]
    anc: list[Anchor] = [
        (float(anchors[i][0]), float(anchors[i][1]), float(anchors[i][2])) for i in used
    ]
    rng = [float(r) for r in ranges if r is not None and math.isfinite(r) and r >= 0]
    tags = tuple(labels[i] for i in used)
    if len(anc) < 2:
        return NoFix("too_few_anchors", tags)
    hr = [horizontal_range(d, depth, a[2]) for d, a in zip(rng, anc, strict=True)]
    if len(anc) == 2:
        return _two(anc, rng, hr, depth, previous, tags, range_sigma_m)
    return _many(anc, rng, hr, depth, previous, tags, range_sigma_m)


def _two(
    anc: list[Anchor],
    rng: list[float],
    hr: list[float],
    depth: float,
    previous: Point | None,
    tags: tuple[str, ...],
    sigma_r: float,
) -> Fix | NoFix:
    (x1, y1, _), (x2, y2, _) = anc
    points, gap = intersect_circles((x1, y1), hr[0], (x2, y2), hr[1])
    if not points:
        return NoFix("degenerate_geometry", tags)
    alternative = None
    if len(points) == 2:
        if previous is None:
            return NoFix("ambiguous", tags)  # no previous estimate to choose with
        i = _nearest(points, previous)
        p, alternative = points[i], points[1 - i]
    else:
        p = points[0]
    sigma = sigma_r * dop(anc, depth, p)
    method = "circles"
    if gap > 0:
        sigma, method = math.hypot(sigma, gap / 2), "circles-closest"
    residual = math.sqrt(_cost(anc, rng, depth, p) / 2)
    return Fix(p[0], p[1], depth, sigma, tags, method, residual, alternative)


def _many(
    anc: list[Anchor],
    rng: list[float],
    hr: list[float],
    depth: float,
    previous: Point | None,
    tags: tuple[str, ...],
    sigma_r: float,
) -> Fix | NoFix:
    n = len(anc)
    starts: list[Point] = []
    lin = _linear(anc, hr)
    if lin is not None:
        starts.append(lin)
    if previous is not None:
        starts.append((float(previous[0]), float(previous[1])))
    # the two most separated anchors' circle intersections seed both mirror sides
    i, j = max(
        ((a, b) for a in range(n) for b in range(a + 1, n)),
        key=lambda ab: math.dist(anc[ab[0]][:2], anc[ab[1]][:2]),
    )
    pts, _ = intersect_circles(anc[i][:2], hr[i], anc[j][:2], hr[j])
    starts.extend(pts)
    if not starts:
        return NoFix("degenerate_geometry", tags)
    sols: list[tuple[Point, float]] = []
    for s in starts:
        p, cost = _least_squares(anc, rng, depth, s)
        if all(math.dist(p, q) > 1e-3 for q, _ in sols):
            sols.append((p, cost))
    sols.sort(key=lambda pc: pc[1])
    best, best_cost = sols[0]
    # another minimum that fits within what range noise explains is a mirror ambiguity
    slack = best_cost + 9 * sigma_r**2
    rivals = [pc for pc in sols[1:] if pc[1] <= slack and math.dist(pc[0], best) > 0.5]
    alternative = None
    if rivals:
        if previous is None:
            return NoFix("ambiguous", tags)
        candidates = [best, *(q for q, _ in rivals)]
        k = _nearest(candidates, previous)
        chosen = candidates[k]
        alternative = candidates[1] if k == 0 else best
        best, best_cost = chosen, _cost(anc, rng, depth, chosen)
    residual = math.sqrt(best_cost / n)
    spread = math.sqrt(best_cost / (n - 2)) if n > 2 else 0.0
    sigma = max(spread, sigma_r) * dop(anc, depth, best)
    return Fix(best[0], best[1], depth, sigma, tags, "least-squares", residual, alternative)
