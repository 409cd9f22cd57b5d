"""Seed 001's mobile experiment, simulated for the tracker: pure, seeded, on a virtual clock.

Geometry (seed 001 V-C): three anchors on a jetty, on one line (x = 0), 12.6 m, 20.9 m and
33.5 m apart (V-A), hydrophones 0.9 m deep; the vehicle sails a 10 m × 30 m rectangle east of
them at :data:`SPEED_MPS`, 0.9 m deep, round and round (the west leg 5 m from the line).

Noise (seed 001 V-A, V-C): range standard deviation 11.8 cm at 12.6 m, 9.3 cm at 20.9 m and
1.7 cm at 33.5 m (linear in between, held beyond); the share of requests an anchor answered
while the vehicle moved: middle 86 %, left 41 %, right 36 % (``reception="seed001"``) or every
one (``"all"``). Optional gross errors (``outliers``): a range made longer by 2–10 m (multipath)
or shorter by 1–5 m (a wrong clock), never by less than the gate could tell.

Ranges are DLBL (:mod:`bridge.ranging.dlbl`) on a TDMA cycle of ``slot_s`` per node, the
vehicle first: each range is half of a two-way exchange, leg 1 from the vehicle's emission to
the anchor, leg 2 from the anchor's emission to the vehicle, each leg's travel time solved for
the moving vehicle. The vehicle's compass gives its heading (``heading_sigma_deg``)
``heading_hz`` times a second; speed is not measured unless ``speed``.
"""

from __future__ import annotations

import bisect
import math
import random
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from bridge.mission.path import Path, rectangle
from bridge.ranging.tracker import Estimate, RangeObs, RangeTracker, profile_at

DEPTH_M = 0.9
ANCHORS: dict[str, tuple[float, float, float]] = {
    "left": (0.0, 0.0, DEPTH_M), "middle": (0.0, 12.6, DEPTH_M), "right": (0.0, 33.5, DEPTH_M),
}
SPEED_MPS = 1.5
SOUND_SPEED_MPS = 1480.0
NOISE_AT = ((12.6, 0.118), (20.9, 0.093), (33.5, 0.017))
"""(distance m, range standard deviation m) measured at the jetty, seed 001 fig. 8."""
MODEL_SIGMA_M = 0.05
"""What the tracker's range model adds to the measurement noise (the node's motion within a
round trip, a turn in it): a floor under :data:`NOISE_AT`'s 1.7 cm."""


def tracker_noise(model_sigma_m: float = MODEL_SIGMA_M) -> tuple[tuple[float, float], ...]:
    """The range noise profile a tracker should expect here (``TrackerConfig.range_sigma_at``):
    seed 001's measured noise, with ``model_sigma_m`` added in quadrature."""
    return tuple((d, math.hypot(s, model_sigma_m)) for d, s in NOISE_AT)


RECEPTION = {"middle": 0.86, "left": 0.41, "right": 0.36}
"""Share of ranging requests each anchor answered in the mobile case (86, 41, 36 of 100)."""
PUBLISHED = {
    "static σx, σy (m)": "0.035, 0.040",
    "static mean error (m)": "0.54",
    "ranging σ (m) @12.6/20.9/33.5 m": "0.118 / 0.093 / 0.017",
    "ranging error bound (m)": "< 0.30",
    "mobile error (m)": "not given (no ground truth; GPS off by ≥ 2 m)",
}
"""What seed 001 published, to print beside measured figures."""


CORNERS = ((5.0, 5.0), (15.0, 5.0), (15.0, 35.0), (5.0, 35.0))
"""The rectangle's corners (x, y), in sailing order."""


def route(turn_radius_m: float = 0.0) -> Path:
    """Seed 001's rectangle: from (5, 5) east 10 m, north 30 m, at :data:`SPEED_MPS`.

    ``turn_radius_m`` 0: the corners are turned instantly (no vehicle can: infinite
    acceleration); else as arcs of that radius (polylines of 5° steps), as a vehicle turns."""
    if turn_radius_m <= 0:
        return rectangle(CORNERS[0], 10.0, 30.0, DEPTH_M, SPEED_MPS)
    r = turn_radius_m
    points: list[tuple[float, float, float]] = []
    for k, (cx, cy) in enumerate(CORNERS):
        # the arc's centre is r inside the corner; it turns anticlockwise through 90°
        ox = cx + (r if cx == CORNERS[0][0] else -r)
        oy = cy + (r if cy == CORNERS[0][1] else -r)
        for step in range(19):
            a = math.radians(180.0 + 90.0 * k + 5.0 * step)
            points.append((ox + r * math.cos(a), oy + r * math.sin(a), DEPTH_M))
    points = points[9:] + points[:9]  # from the middle of the first corner, as near (5, 5)
    return Path(tuple(points), SPEED_MPS, loop=True)


def range_sigma(distance_m: float) -> float:
    """Seed 001's range standard deviation at ``distance_m``."""
    return profile_at(NOISE_AT, distance_m)


def heading_at(path: Path, t: float) -> float:
    """The compass heading (degrees) the vehicle is sailing at ``t``."""
    a, b = path.position_at(t), path.position_at(t + 0.01)
    return math.degrees(math.atan2(b[0] - a[0], b[1] - a[1])) % 360


@dataclass(frozen=True)
class Event:
    """A measurement at ``time``: a range (``obs``) or a compass reading (``heading``)."""

    time: float
    obs: RangeObs | None = None
    heading: float | None = None
    speed: float | None = None
    outlier: bool = False


def _arrival(path: Path, anchor: Sequence[float], t_emit: float) -> float:
    """When a sound emitted by ``anchor`` at ``t_emit`` reaches the moving vehicle."""
    t = t_emit
    for _ in range(6):
        t = t_emit + math.dist(path.position_at(t), anchor) / SOUND_SPEED_MPS
    return t


def events(duration_s: float, anchors: Sequence[str] = ("left", "middle", "right"), *,
           seed: int = 1, reception: str = "seed001", heading: bool = True,
           speed: bool = False, outliers: float = 0.0, slot_s: float = 0.4,
           heading_sigma_deg: float = 2.0, heading_hz: float = 1.0,
           turn_radius_m: float = 0.0) -> Iterator[Event]:
    """The measurements of ``duration_s`` seconds, in time order, sailing
    ``route(turn_radius_m)``."""
    rnd = random.Random(seed)
    path = route(turn_radius_m)
    cycle = slot_s * (1 + len(ANCHORS))
    order = list(ANCHORS)
    pending: list[tuple[float, int, Event]] = []
    serial = 0
    next_heading = 0.0
    k = 0
    while True:
        t0 = k * cycle
        if t0 > duration_s:
            break
        own = path.position_at(t0)
        for i, name in enumerate(order):
            if name not in anchors:
                continue
            a = ANCHORS[name]
            share = RECEPTION[name] if reception == "seed001" else 1.0
            if rnd.random() >= share:
                continue
            d1 = math.dist(own, a)
            t_a = t0 + slot_s * (i + 1)
            t_rx = _arrival(path, a, t_a)
            d2 = math.dist(path.position_at(t_rx), a)
            true = (d1 + d2) / 2
            measured = true + rnd.gauss(0.0, range_sigma(true))
            bad = outliers > 0 and rnd.random() < outliers
            if bad:
                measured = true + (rnd.uniform(2, 10) if rnd.random() < 0.6
                                   else -rnd.uniform(1, 5))
            obs = RangeObs(name, measured, t_rx, a, span_s=t_rx - t0)
            serial += 1
            bisect.insort(pending, (t_rx, serial, Event(t_rx, obs=obs, outlier=bad)))
        while next_heading < t0 + cycle and next_heading <= duration_s:
            if heading:
                true_heading = heading_at(path, next_heading)
                reading = (true_heading + rnd.gauss(0.0, heading_sigma_deg)) % 360
                spd = SPEED_MPS + rnd.gauss(0.0, 0.05) if speed else None
                serial += 1
                bisect.insort(pending, (next_heading, serial,
                                        Event(next_heading, heading=reading, speed=spd)))
            next_heading += 1.0 / heading_hz
        while pending and pending[0][0] < t0 + cycle:
            yield pending.pop(0)[2]
        k += 1
    while pending:
        yield pending.pop(0)[2]


@dataclass(frozen=True)
class Sample:
    """The tracker's estimate after one range, beside the truth."""

    time: float
    estimate: Estimate
    truth: tuple[float, float]
    error_m: float | None
    nees: float | None
    mirrored: bool


def replay(tracker: RangeTracker, stream: Iterator[Event] | Sequence[Event],
           path: Path | None = None) -> list[Sample]:
    """Feed ``stream`` to ``tracker``; after every range, its estimate against the truth.

    ``mirrored``: the estimate is nearer the truth's mirror image across the anchors' line
    (x = 0) than the truth, i.e. the track took the wrong side.
    """
    path = path or route()
    tracker.set_depth(DEPTH_M)
    out: list[Sample] = []
    for event in stream:
        if event.heading is not None:
            tracker.on_heading(event.time, event.heading, event.speed)
            continue
        assert event.obs is not None
        tracker.on_range(event.obs)
        est = tracker.estimate(event.time)
        tx, ty, _ = path.position_at(event.time)
        if not est.has_position:
            out.append(Sample(event.time, est, (tx, ty), None, None, False))
            continue
        e = np.array([est.x - tx, est.y - ty])
        cov = np.array(est.cov)
        nees = float(e @ np.linalg.solve(cov, e))
        mirrored = math.dist((est.x, est.y), (-tx, ty)) < math.dist((est.x, est.y), (tx, ty))
        out.append(Sample(event.time, est, (tx, ty), float(np.hypot(*e)), nees, mirrored))
    return out


def percentile(values: Sequence[float], q: float) -> float:
    """The ``q`` quantile (0–1) of ``values``, nearest rank."""
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, max(0, math.ceil(q * len(ordered)) - 1))]


NEES_BOUNDS_2D = (0.0506, 7.378)
"""χ² with two degrees of freedom, 2.5 % and 97.5 %: a consistent filter's NEES lies inside
these for 95 % of updates."""


def flips(samples: Sequence[Sample]) -> int:
    """How many times the published position went over to the mirror side."""
    count, before = 0, False
    for s in samples:
        if s.error_m is None:
            continue
        if s.mirrored and not before:
            count += 1
        before = s.mirrored
    return count
