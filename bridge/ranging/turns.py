"""Unseen turns without a compass: a Gaussian sum over heading jumps at constant speed (#16).

A small vehicle holds its course, then turns within a second or two; without a compass only the
ranges can show it, and from one anchor they cannot tell which way (any turn fits its circle).
So beside the track (the likeliest component) the tracker keeps a few components that turned:
at every range, in the gap since the track's previous one, it may have turned by any angle of
a ring (``ring_deg``), keeping its speed (1-σ :data:`SPEED_SHARE` of it) — prior share
``gap / turn_every_s`` spread over the ring. Each component then takes every range as an EKF
of its own and is weighted by how well it predicted it; the unlikely are pruned, the alike
merged, and the likeliest becomes the track. The published estimate is the mixture: tight on a
straight (the turned components die at the next range from another anchor) and as wide as the
candidates after a turn (until the ranges choose).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from bridge.ranging import kalman

SPEED_SHARE = 0.1
"""1-σ change of speed through a turn, as a share of the speed held before it."""

Component = Any  # the tracker's ``_Hypothesis``: x, p, time, log_w, turns, steps


def _clone(h: Component) -> Component:
    return dataclasses.replace(h, x=h.x.copy(), p=h.p.copy(), turns=list(h.turns),
                               steps=list(h.steps), blend=None, pending=[])


class TurnMixture:
    """The turned components beside one track; ``log_w`` relative to the track's (0)."""

    def __init__(self, turn_every_s: float, ring_deg: float, keep: int = 12,
                 floor: float = 1e-4, min_speed_mps: float = 0.2) -> None:
        self.turn_every_s = turn_every_s
        self.angles = [math.radians(ring_deg * k) for k in range(1, round(360 / ring_deg))]
        self.across = math.tan(math.radians(ring_deg / 2)) / 2  # ring's 1-σ, share of speed
        self.keep, self.floor, self.min_speed = keep, math.log(floor), min_speed_mps
        self.components: list[Component] = []

    def spawn(self, track: Component, t: float, predict: Callable[[Component, float], None],
              remember: Callable[[Component, float, np.ndarray], None]) -> None:
        """The track may have turned between its time and ``t`` (a range's): one component per
        angle of the ring, turned halfway through the gap (the variance of when included)."""
        gap = t - track.time
        speed = float(np.hypot(track.x[2], track.x[3]))
        if gap <= 0 or speed < self.min_speed:
            return
        prior = min(gap / self.turn_every_s, 0.5)
        base = _clone(track)
        base.steps = []
        predict(base, track.time + gap / 2)
        v = base.x[2:].copy()
        for c in self.components:
            c.log_w -= math.log1p(-prior)  # the track's own share shrinks by the prior
        along, across = (SPEED_SHARE * speed) ** 2, (self.across * speed) ** 2
        when = gap**2 / 12  # the variance of when in the gap, per (m/s)² of change
        for angle in self.angles:
            x, p = kalman.turned(base.x.tolist(), base.p.tolist(), angle)
            ux, uy = x[2] / speed, x[3] / speed  # along the new velocity
            kalman.spread(p, ux, uy, along, across)
            kalman.widen(p, x[2] - float(v[0]), x[3] - float(v[1]), when)
            comp = _clone(base)
            comp.x, comp.p = np.array(x), np.array(p)
            remember(comp, comp.time, v)
            comp.log_w = math.log(prior / len(self.angles)) - math.log1p(-prior)
            self.components.append(comp)

    def update(self, track_gain: float, take: Callable[[Component], float]) -> None:
        """Every component takes the range (``take`` returns its log-likelihood); weights
        relative to the track's, which gained ``track_gain``."""
        for c in self.components:
            c.log_w += take(c) - track_gain
        self.components = [c for c in self.components if c.log_w >= self.floor]

    def merge(self, track: Component, near_m: float = 0.3, near_mps: float = 0.3) -> None:
        """Components alike (within ``near_m`` and ``near_mps``) are one, the likelier kept
        with both weights; one like the track is the track's."""
        self.components.sort(key=lambda c: -c.log_w)
        kept: list[Component] = []
        absorbed = 0.0  # the track's extra weight, from components like it
        for c in self.components:
            twin = next((k for k in [track, *kept] if _alike(c, k, near_m, near_mps)), None)
            if twin is None:
                kept.append(c)
            elif twin is track:
                absorbed += math.exp(c.log_w)
            else:
                twin.log_w = float(np.logaddexp(twin.log_w, c.log_w))
        for k in kept:
            k.log_w -= math.log1p(absorbed)
        self.components = kept[:self.keep]

    def likeliest(self) -> Component | None:
        """The component more likely than the track, if one is."""
        best = max(self.components, key=lambda c: c.log_w, default=None)
        return best if best is not None and best.log_w > 0 else None

    def swap(self, track: Component, best: Component) -> None:
        """``best`` becomes the track (its state and history copied in); the track's old state
        a component; weights relative to the new track."""
        old = _clone(track)
        shift = best.log_w
        old.log_w = -shift
        self.components = [c for c in self.components if c is not best]
        for c in self.components:
            c.log_w -= shift
        self.components.append(old)
        track.x, track.p, track.time = best.x.copy(), best.p.copy(), best.time
        track.turns, track.steps, track.blend = list(best.turns), list(best.steps), None

    def moments(self, track_x: np.ndarray, track_p: np.ndarray, t: float,
                predicted: Callable[[np.ndarray, np.ndarray, float],
                                    tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray,
                                                                             np.ndarray]:
        """The mixture's mean and covariance at ``t`` (the track's state already there)."""
        if not self.components:
            return track_x, track_p
        states = [(1.0, track_x, track_p)] + [
            (math.exp(c.log_w), *predicted(c.x, c.p, max(t - c.time, 0.0)))
            for c in self.components]
        total = sum(w for w, _, _ in states)
        mean = sum(w * x for w, x, _ in states) / total
        cov = sum(w * (p + np.outer(x - mean, x - mean)) for w, x, p in states) / total
        return np.asarray(mean), np.asarray(cov)


def _alike(a: Component, b: Component, near_m: float, near_mps: float) -> bool:
    """Whether two components are one (near in position and velocity, at the same time)."""
    return abs(a.time - b.time) < 1e-9 and float(np.hypot(*(a.x[:2] - b.x[:2]))) < near_m \
        and float(np.hypot(*(a.x[2:] - b.x[2:]))) < near_mps
