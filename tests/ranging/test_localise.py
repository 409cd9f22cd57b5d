"""Localisation in seed 001's geometry: two anchors, a third, collinear anchors, a moving node."""

from __future__ import annotations

import math
import random

import pytest

from bridge.ranging.localise import (
    NO_FIX_REASONS,
    Fix,
    NoFix,
    attempt,
    horizontal_range,
    intersect_circles,
    locate,
)
from bridge.ranging.sound_speed import SoundSpeed
from bridge.ranging.track import Track
from bridge.ranging.twr import travel_time

SEED_ANCHORS = [(25.4, 19.3, 0.9), (-17.4, 20.8, 0.9)]  # seed 001 Fig. 10
THIRD = (4.0, -24.0, 0.9)
C = SoundSpeed.from_ctd(12.0, 0.5, 0.9)  # brackish Elbe water, as in seed 001


def twr_range(true_m: float, rnd: random.Random, sigma_t: float) -> float:
    """A two-way ranging measurement with every timestamp jittered by ``sigma_t``."""
    tw, tp = true_m / C.mps, 0.3
    t_tx = 100.0 + rnd.gauss(0, sigma_t)
    t_rx = 100.0 + 2 * tw + tp + rnd.gauss(0, sigma_t)
    tp_measured = tp + rnd.gauss(0, sigma_t) - rnd.gauss(0, sigma_t)
    return C.distance(travel_time(t_tx, t_rx, tp_measured))


def slant(node: tuple[float, float, float], anchor: tuple[float, float, float]) -> float:
    return math.dist(node, anchor)


def percentile(values: list[float], q: float) -> float:
    return sorted(values)[int(q * (len(values) - 1))]


def test_two_anchors_exact_and_ambiguity() -> None:
    node = (0.0, 0.0, 0.9)
    ranges = [slant(node, a) for a in SEED_ANCHORS]
    fix = locate(SEED_ANCHORS, ranges, 0.9, previous=(1.0, -1.0), names=["left", "right"])
    assert fix is not None
    assert (fix.x, fix.y) == pytest.approx((0.0, 0.0), abs=1e-9)
    assert fix.method == "circles" and fix.anchors == ("left", "right")
    assert fix.alternative is not None
    # the other intersection is the mirror of the node across the anchors' line
    mirror = locate(SEED_ANCHORS, ranges, 0.9, previous=fix.alternative)
    assert mirror is not None and math.dist((mirror.x, mirror.y), (0, 0)) > 30
    assert locate(SEED_ANCHORS, ranges, 0.9, previous=None) is None  # cannot choose


def test_projection_uses_both_depths() -> None:
    anchors = [(25.4, 19.3, 0.5), (-17.4, 20.8, 1.5)]
    node = (2.0, -3.0, 6.0)
    fix = locate(anchors, [slant(node, a) for a in anchors], 6.0, previous=(0.0, 0.0))
    assert fix is not None and (fix.x, fix.y, fix.depth) == pytest.approx(node, abs=1e-9)
    assert horizontal_range(5.0, 4.0, 0.0) == pytest.approx(3.0)
    assert horizontal_range(3.0, 4.0, 0.0) == 0.0  # slant shorter than the depth difference


def test_seed_geometry_within_30_cm() -> None:
    rnd = random.Random(2018)
    node = (0.0, 0.0, 0.9)
    errors, sigmas, range_err = [], [], []
    for _ in range(2000):
        ranges = [twr_range(slant(node, a), rnd, 50e-6) for a in SEED_ANCHORS]
        range_err += [r - slant(node, a) for r, a in zip(ranges, SEED_ANCHORS, strict=True)]
        fix = locate(SEED_ANCHORS, ranges, 0.9, previous=(0.5, 0.5), range_sigma_m=0.075)
        assert fix is not None
        errors.append(math.hypot(fix.x, fix.y))
        sigmas.append(fix.sigma_m)
    sigma_r = math.sqrt(sum(e * e for e in range_err) / len(range_err))
    assert 0.05 <= sigma_r <= 0.10  # the ranging noise the seed measured
    assert percentile(errors, 0.95) < 0.3
    rms = math.sqrt(sum(e * e for e in errors) / len(errors))
    assert 0.7 < rms / (sum(sigmas) / len(sigmas)) < 1.3  # reported sigma is honest


def test_non_intersecting_circles_closest_approach() -> None:
    points, gap = intersect_circles((0, 0), 1.0, (5, 0), 2.0)
    assert gap == pytest.approx(2.0) and points == [pytest.approx((2.0, 0.0))]
    points, gap = intersect_circles((0, 0), 5.0, (1, 0), 1.0)  # one inside the other
    assert gap == pytest.approx(3.0) and points == [pytest.approx((3.5, 0.0))]
    assert intersect_circles((0, 0), 5.0, (0, 0), 1.0) == ([], 4.0)
    far_apart = [(-30.0, 0.0, 0.9), (30.0, 0.0, 0.9)]
    fix = locate(far_apart, [25.0, 25.0], 0.9, previous=None)  # 10 m gap: no ambiguity
    assert fix is not None and fix.method == "circles-closest"
    assert (fix.x, fix.y) == pytest.approx((0.0, 0.0)) and fix.sigma_m >= 5.0
    tangent = locate(far_apart, [30.0, 30.0], 0.9, previous=None)
    assert tangent is not None and tangent.method == "circles" and tangent.alternative is None
    assert locate([(0.0, 0.0, 0.9), (0.0, 0.0, 5.0)], [3.0, 4.0], 0.9) is None  # concentric


def test_fewer_than_two_anchors_is_no_fix() -> None:
    assert locate([], [], 1.0) is None
    assert locate(SEED_ANCHORS[:1], [10.0], 0.9, previous=(0, 0)) is None
    assert locate(SEED_ANCHORS, [31.9, None], 0.9, previous=(0, 0)) is None  # a missing reply
    assert locate(SEED_ANCHORS, [31.9, math.nan], 0.9, previous=(0, 0)) is None
    with pytest.raises(ValueError, match="2 anchors but 1 ranges"):
        locate(SEED_ANCHORS, [1.0], 0.9)


def test_a_failed_attempt_says_why() -> None:
    node = (0.0, 0.0, 0.9)
    ranges = [slant(node, a) for a in SEED_ANCHORS]
    names = ["left", "right"]
    one = attempt(SEED_ANCHORS, [ranges[0], None], 0.9, (0, 0), names=names)
    assert one == NoFix("too_few_anchors", ("left",))
    assert attempt(SEED_ANCHORS, ranges, 0.9, None, names=names) == NoFix("ambiguous",
                                                                          ("left", "right"))
    concentric = attempt([(0.0, 0.0, 0.9), (0.0, 0.0, 5.0)], [3.0, 4.0], 0.9, names=names)
    assert isinstance(concentric, NoFix) and concentric.reason == "degenerate_geometry"
    line = [(0.0, 0.0, 0.9), (0.0, 20.0, 0.9), (0.0, 40.0, 0.9)]  # seed 001's jetty
    mirrored = attempt(line, [slant((8.0, 13.0, 0.9), a) for a in line], 0.9)
    assert isinstance(mirrored, NoFix) and mirrored.reason == "ambiguous"
    payload = one.payload(12.5)
    assert payload == {"fix": False, "reason": "too_few_anchors", "anchors": ["left"],
                       "time": 12.5, "detail": NO_FIX_REASONS["too_few_anchors"]}
    fix = attempt(SEED_ANCHORS, ranges, 0.9, (1.0, -1.0), names=names)
    assert isinstance(fix, Fix) and fix.payload(1.0)["fix"] is True
    with pytest.raises(ValueError, match="unknown no-fix reason"):
        NoFix("bad luck")


def test_third_anchor_least_squares() -> None:
    rnd = random.Random(5)
    anchors = [*SEED_ANCHORS, THIRD]
    node = (1.5, 2.0, 0.9)
    errors, residuals = [], []
    for _ in range(1000):
        ranges = [twr_range(slant(node, a), rnd, 50e-6) for a in anchors]
        fix = locate(anchors, ranges, 0.9, previous=None, range_sigma_m=0.075)  # unique
        assert fix is not None and fix.method == "least-squares" and len(fix.anchors) == 3
        errors.append(math.dist((fix.x, fix.y), node[:2]))
        residuals.append(fix.residual_m)
    assert percentile(errors, 0.95) < 0.2
    assert percentile(residuals, 0.5) < 0.1
    # a wild range shows up in the residual and the sigma
    bad = [slant(node, a) for a in anchors]
    bad[2] += 3.0
    fix = locate(anchors, bad, 0.9, range_sigma_m=0.075)
    assert fix is not None and fix.residual_m > 0.5 and fix.sigma_m > 1.0


def test_collinear_anchors_mirror_needs_previous() -> None:
    line = [(0.0, 0.0, 0.9), (0.0, 12.6, 0.9), (0.0, 33.5, 0.9)]  # seed 001 V-C jetty
    node = (6.0, 14.0, 0.9)
    ranges = [slant(node, a) for a in line]
    assert locate(line, ranges, 0.9, previous=None) is None
    east = locate(line, ranges, 0.9, previous=(5.0, 13.0))
    west = locate(line, ranges, 0.9, previous=(-5.0, 13.0))
    assert east is not None and (east.x, east.y) == pytest.approx((6.0, 14.0), abs=1e-6)
    assert west is not None and (west.x, west.y) == pytest.approx((-6.0, 14.0), abs=1e-6)


def rectangle(t: float, speed: float = 0.5) -> tuple[float, float]:
    """A 10 m × 30 m loop east of the jetty, clockwise from (5, 2)."""
    corners = [(5.0, 2.0), (5.0, 32.0), (15.0, 32.0), (15.0, 2.0)]
    s = (t * speed) % 80.0
    for (x0, y0), (x1, y1) in zip(corners, corners[1:] + corners[:1], strict=True):
        side = math.dist((x0, y0), (x1, y1))
        if s <= side:
            f = s / side
            return (x0 + f * (x1 - x0), y0 + f * (y1 - y0))
        s -= side
    raise AssertionError("unreachable")


def test_moving_node_on_rectangle_is_tracked() -> None:
    rnd = random.Random(86)
    anchors = [(0.0, 0.0, 0.9), (0.0, 12.6, 0.9), (0.0, 33.5, 0.9)]
    reception = [0.41, 0.86, 0.36]  # seed 001 V-C: replies heard from each anchor
    track = Track(accel_sigma=0.05)
    track.start(0.0, *rectangle(0.0), sigma_m=2.0)  # GNSS before diving
    raw, filtered, fixes = [], [], 0
    for k in range(1, 160):  # a request every 3 s, two laps
        t = 3.0 * k
        x, y = rectangle(t)
        ranges = [
            twr_range(slant((x, y, 0.9), a), rnd, 50e-6) if rnd.random() < p else None
            for a, p in zip(anchors, reception, strict=True)
        ]
        fix = locate(anchors, ranges, 0.9, previous=track.predict(t), range_sigma_m=0.075)
        if fix is None:
            continue
        fixes += 1
        assert fix.x > 0  # never the mirror image west of the jetty
        raw.append(math.dist((fix.x, fix.y), (x, y)))
        if track.update(t, fix):
            pos = track.position
            assert pos is not None
            filtered.append(math.dist(pos, (x, y)))
    assert fixes > 60
    assert percentile(raw, 0.95) < 0.8
    assert percentile(filtered, 0.95) < 0.6
    assert sum(filtered) / len(filtered) < sum(raw) / len(raw)
    assert track.refused < 0.1 * fixes


def test_track_gate_and_payload() -> None:
    track = Track()
    assert track.predict(0.0) is None and not track.started
    track.update(0.0, Fix(0.0, 0.0, 1.0, 0.2, ("a", "b"), "circles"))
    track.update(10.0, Fix(1.0, 0.0, 1.0, 0.2, ("a", "b"), "circles"))
    assert not track.update(20.0, Fix(60.0, 0.0, 1.0, 0.2, ("a", "b"), "circles"))
    assert track.refused == 1 and track.velocity is not None
    assert track.velocity[0] > 0
    payload = Fix(1.0, 2.0, 3.0, 0.1, ("a", "b"), "circles").payload(5.0)
    assert payload == {
        "fix": True,
        "x": 1.0,
        "y": 2.0,
        "depth": 3.0,
        "time": 5.0,
        "sigma_m": 0.1,
        "anchors": ["a", "b"],
        "method": "circles",
    }
