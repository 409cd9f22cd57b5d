"""Turned components without a compass (:mod:`bridge.ranging.turns`), on the virtual clock."""

from __future__ import annotations

import math
import random

import numpy as np

from bridge.ranging.seed001 import NEES_BOUNDS_2D
from bridge.ranging.tracker import (
    Estimate,
    Prior,
    RangeObs,
    RangeTracker,
    TrackerConfig,
    _Hypothesis,
    _predicted,
    _remember_turn,
)
from bridge.ranging.turns import TurnMixture

ANCHORS = {"left": (0.0, 0.0, 0.9), "middle": (0.0, 12.6, 0.9), "right": (0.0, 33.5, 0.9)}
TURN_S, SPEED = 10.0, 1.5


def _truth(t: float) -> np.ndarray:
    """East along y = 15 from x = 4, then (at TURN_S) north: an instant 90° turn."""
    if t < TURN_S:
        return np.array([4.0 + SPEED * t, 15.0])
    return np.array([4.0 + SPEED * TURN_S, 15.0 + SPEED * (t - TURN_S)])


def _sail(config: TrackerConfig) -> tuple[list[tuple[float, str, Estimate, float]],
                                         dict[str, int]]:
    """Ranges every 0.53 s from each anchor in turn, but for 2.5 s after the turn from the
    middle one only; (time, anchor, estimate, NEES) after each, and the ranges refused."""
    rnd = random.Random(3)
    tracker = RangeTracker(config, prior=Prior(0.0, 4.0, 15.0, 0.5), depth=0.9)
    order = list(ANCHORS)
    out = []
    for k in range(1, 40):
        t = 0.53 * k
        name = "middle" if TURN_S < t < TURN_S + 2.5 else order[k % 3]
        here = _truth(t)
        r = math.dist((*here, 0.9), ANCHORS[name]) + rnd.gauss(0.0, 0.05)
        tracker.on_range(RangeObs(name, r, t, ANCHORS[name]))
        est = tracker.estimate(t)
        if t < TURN_S / 2:
            continue  # starting
        assert est.has_position
        e = np.array([est.x, est.y]) - here
        out.append((t, name, est, float(e @ np.linalg.solve(np.array(est.cov), e))))
    return out, dict(tracker.rejected)


def test_a_turn_one_anchor_cannot_show_is_in_the_covariance_and_the_speed_is_held() -> None:
    samples, refused = _sail(TrackerConfig())
    unseen = [s for s in samples if TURN_S < s[0] < TURN_S + 2.5]
    assert len(unseen) == 5
    # one anchor fits a turn either way: the estimate is as wide as the candidates, not wrong
    assert all(nees <= NEES_BOUNDS_2D[1] for *_, nees in unseen)
    assert max(math.dist((e.x, e.y), _truth(t)) for t, _, e, _ in unseen) > 1.0
    # the next range from another anchor picks the turn: on the path at its old speed
    seen = [s for s in samples if s[0] > TURN_S + 2.5]
    assert seen[0][1] != "middle"
    for t, _, e, _ in seen:
        assert math.dist((e.x, e.y), _truth(t)) < 0.3
        assert abs(math.hypot(e.vx, e.vy) - SPEED) < 0.1
    # the ranges the straight track refused, the turned one took: none is a bad range
    assert refused == {}


def test_without_turned_components_the_same_turn_is_overconfident() -> None:
    samples, _ = _sail(TrackerConfig(turn_every_s=0.0, wide_accel_sigma=0.0))
    unseen = [nees for t, _, _, nees in samples if TURN_S < t < TURN_S + 2.5]
    assert max(unseen) > 13.8  # χ²₂ at 99.9 %


def test_spawned_turns_keep_the_speed_and_share_the_prior() -> None:
    mixture = TurnMixture(turn_every_s=10.0, ring_deg=45.0)
    track = _Hypothesis(np.array([0.0, 0.0, 1.5, 0.0]), np.diag([0.01, 0.01, 0.001, 0.001]),
                        0.0)

    def predict(h: _Hypothesis, t: float) -> None:
        h.x, h.p = _predicted(h.x, h.p, t - h.time, 0.03)
        h.time = t

    mixture.spawn(track, 0.5, predict, lambda h, when, v: _remember_turn(h, when, v, 10.0))
    comps = mixture.components
    assert len(comps) == 7  # every 45° but none
    assert all(abs(math.hypot(*c.x[2:]) - 1.5) < 1e-9 for c in comps)
    headings = sorted(round(math.degrees(math.atan2(c.x[2], c.x[3]))) % 360 for c in comps)
    assert headings == [0, 45, 135, 180, 225, 270, 315]
    # turned halfway through the gap: from (0.375, 0) on, and the velocity before remembered
    assert all(abs(c.x[0] - 0.375) < 1e-9 and c.turns[-1][0] == 0.25 for c in comps)
    # together they hold the prior (0.5 s of 10 s), relative to the track's 1 − prior
    share = sum(math.exp(c.log_w) for c in comps)
    assert abs(share - 0.05 / 0.95) < 1e-9
    # the likeliest more likely than the track becomes it; the track a component
    best = comps[2]
    best.log_w = 1.0
    mixture.swap(track, best)
    assert np.allclose(track.x, best.x) and len(mixture.components) == 7
    assert any(np.allclose(c.x, [0.0, 0.0, 1.5, 0.0]) and c.log_w == -1.0
               for c in mixture.components)
