"""Collect what a mission report plots from the fleet's events (pure: no I/O, no plotting).

Every node's events (:mod:`bridge.core.events`: frames sent and received, ranges, positions
...) carry the node's clock in ``time``: wall seconds in ``zab sim``, virtual seconds with
``--fast``. ``truth`` tells where each node really is at a time (the simulated water), so
tracks and range errors can be drawn against it.
"""

from __future__ import annotations

import math
from collections import Counter, defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field

from bridge.core.events import (
    Event,
    FrameDropped,
    FrameReceived,
    FrameSent,
    PayloadDrops,
    Position,
    Range,
    SendFailed,
)

Xyz = tuple[float, float, float]
Truth = Callable[[float], dict[str, Xyz]]

TRACK_STEP_S = 1.0  # truth is sampled at most this often (at frame times)


@dataclass
class Recording:
    """Time series of one run, times in seconds from its first event."""

    frames: list[tuple[float, str, int, list[str]]] = field(default_factory=list)
    arrivals: dict[tuple[str, str], list[float]] = field(default_factory=lambda: defaultdict(list))
    tracks: dict[str, list[tuple[float, float, float]]] = field(
        default_factory=lambda: defaultdict(list))
    fixes: dict[str, list[tuple[float, float, float, float | None]]] = field(
        default_factory=lambda: defaultdict(list))
    ranges: list[tuple[float, str, str, float, float | None]] = field(default_factory=list)
    drops: Counter[tuple[str, str]] = field(default_factory=Counter)
    end_s: float = 0.0


class MissionRecorder:
    """An event sink, ``recorder(node, event)``, building a :class:`Recording`."""

    def __init__(self, truth: Truth | None = None) -> None:
        self.truth = truth
        self.recording = Recording()
        self._t0: float | None = None
        self._last_track = -math.inf

    def _t(self, t: float) -> float | None:
        if not math.isfinite(t):
            return None
        if self._t0 is None:
            self._t0 = float(t)
        rel = float(t) - self._t0
        self.recording.end_s = max(self.recording.end_s, rel)
        return rel

    def __call__(self, node: str, event: Event) -> None:
        t = self._t(event.time)
        if t is None:
            return
        rec = self.recording
        match event:
            case FrameSent(size=size, channels=channels):
                rec.frames.append((t, node, size, list(channels)))
                self._sample_truth(t, event.time)
            case FrameReceived(channels=channels):
                for channel in channels:
                    rec.arrivals[(channel, node)].append(t)
            case Range(peer=peer, range_m=measured) if math.isfinite(measured):
                truth = self._distance(node, peer, event.time)
                rec.ranges.append((t, node, peer, measured, truth))
            case Position(xy=(x, y, sigma)):
                rec.fixes[node].append((t, x, y, sigma))
            case FrameDropped(reason=why) | SendFailed(error=why):
                rec.drops[(node, why or event.kind)] += 1
            case PayloadDrops(drops=drops):
                for _, _, count, why in drops:
                    rec.drops[(node, why)] += count

    def _sample_truth(self, t: float, clock: float) -> None:
        if self.truth is None or t - self._last_track < TRACK_STEP_S:
            return
        self._last_track = t
        for name, (x, y, _) in self.truth(clock).items():
            self.recording.tracks[name].append((t, x, y))

    def _distance(self, a: str, b: str, clock: float) -> float | None:
        if self.truth is None:
            return None
        where = self.truth(clock)
        if a not in where or b not in where:
            return None
        return math.dist(where[a], where[b])


def age_series(arrivals: list[float], end: float,
               limit: int | None = None) -> tuple[list[float], list[float]]:
    """The age-of-information sawtooth of one receiver: (times, ages), from the first
    arrival to ``end``; the age drops to 0 at each arrival. With more than ``limit`` teeth,
    consecutive teeth are merged, each merged tooth as tall as the tallest it holds (the
    worst ages stay visible)."""
    teeth = list(zip(arrivals, [*arrivals[1:], end], strict=True))
    group = 1 if limit is None or len(teeth) <= limit else math.ceil(len(teeth) / limit)
    times: list[float] = []
    ages: list[float] = []
    for i in range(0, len(teeth), group):
        start, stop = max(teeth[i:i + group], key=lambda tooth: tooth[1] - tooth[0])
        times += [teeth[i][0], start, stop]
        ages += [0.0, 0.0, stop - start]
    if group > 1 and teeth:  # the line ends with the age at the end, as an unmerged one does
        times += [teeth[-1][0], end]
        ages += [0.0, end - teeth[-1][0]]
    return times, ages


def truth_from(names: dict[str, int], position: Callable[[int, float], Xyz]) -> Truth:
    """A :data:`Truth` from a water's ``position(address, time)``; nodes not in the water
    (``KeyError``) are left out."""

    def where(t: float) -> dict[str, Xyz]:
        out: dict[str, Xyz] = {}
        for name, address in names.items():
            try:
                x, y, depth = position(address, t)
            except KeyError:
                continue
            out[name] = (float(x), float(y), float(depth))
        return out

    return where
