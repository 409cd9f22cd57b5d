"""Recorded tracker traces: what :class:`RangeTracker` says after every range in a few short
seed 001 runs, one per path through it, kept as data (``tests/ranging/traces.json.gz``).

``tests/ranging/test_traces.py`` replays them and compares every estimate (to 1e-9 m) and
every decision (state, reason, refusals, manoeuvres, folds, restarts) exactly: the tracker
may be made faster, never different without saying so. Record again only for a change of
its maths that is meant, and say what changed in the commit::

    uv run python -m tests.ranging.traces
"""

from __future__ import annotations

import gzip
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bridge.ranging import seed001
from bridge.ranging.seed001 import events
from bridge.ranging.tracker import Prior, RangeTracker, TrackerConfig

FILE = Path(__file__).resolve().parent / "traces.json.gz"
NOISE = seed001.tracker_noise()
START = Prior(0.0, 5.0, 5.0, 2.0)


@dataclass(frozen=True)
class Trace:
    """One seeded run: ``events(duration_s, **stream)`` into a tracker with ``config``."""

    name: str
    config: TrackerConfig
    duration_s: float
    stream: dict[str, Any] = field(default_factory=dict)
    prior: Prior | None = START


TRACES = (
    # 5 Hz compass, 3 anchors every reply heard, 5 % outliers: gating, refusals by reason
    Trace("compass, outliers", TrackerConfig(range_sigma_at=NOISE), 120.0,
          {"reception": "all", "heading_hz": 5.0, "outliers": 0.05, "seed": 6}),
    # 1 Hz compass: a turn's time kept pending, its candidates merged; the ranges' turns
    # widen the covariance, never taken
    Trace("compass 1 Hz", TrackerConfig(range_sigma_at=NOISE), 120.0,
          {"reception": "all", "heading_hz": 1.0, "seed": 2}),
    # no compass, seed 001's reception: turned components, manoeuvre tests taken and not
    Trace("no compass", TrackerConfig(range_sigma_at=NOISE), 120.0,
          {"heading": False, "seed": 1}),
    # no compass, the manoeuvring mode instead of turned components
    Trace("manoeuvring mode", TrackerConfig(range_sigma_at=NOISE, turn_every_s=0.0,
                                            accel_sigma=0.06), 120.0,
          {"heading": False, "seed": 4}),
    # two anchors (a mirror line), no compass: a track that slides over it is folded back
    # (three folds; seed 5's one at 199 s went when a start's σ took the geometry's
    # magnification of the ranges' different times)
    Trace("folded back", TrackerConfig(range_sigma_m=0.12, accel_sigma=0.06, turn_every_s=0.0),
          210.0, {"heading": False, "seed": 6}),
    # two anchors and a compass, no prior: both mirror images until the motion tells
    Trace("no prior", TrackerConfig(), 90.0,
          {"anchors": ("left", "right"), "reception": "all", "seed": 8}, None),
)


def run(trace: Trace) -> list[list[Any]]:
    """After every range: [time, accepted, reason, state, lost reason, x, y, vx, vy, cov xx,
    xy, yy, doubt, manoeuvres, folds, restarts, refusals by reason]."""
    tracker = RangeTracker(trace.config, prior=trace.prior, depth=seed001.DEPTH_M)
    rows: list[list[Any]] = []
    for e in events(trace.duration_s, **trace.stream):
        if e.heading is not None:
            tracker.on_heading(e.time, e.heading, e.speed)
            continue
        assert e.obs is not None
        outcome = tracker.on_range(e.obs)
        est = tracker.estimate(e.time)
        (cxx, cxy), (_, cyy) = est.cov
        rows.append([e.time, outcome.accepted, outcome.reason, est.state, est.reason,
                     est.x, est.y, est.vx, est.vy, cxx, cxy, cyy, est.doubt,
                     tracker.manoeuvres, tracker.folds, tracker.restarts,
                     dict(sorted(tracker.rejected.items()))])
    return rows


def load() -> dict[str, list[list[Any]]]:
    """The recorded traces, by name."""
    data: dict[str, list[list[Any]]] = json.loads(gzip.decompress(FILE.read_bytes()))
    return data


def main() -> None:
    data = {trace.name: run(trace) for trace in TRACES}
    FILE.write_bytes(gzip.compress(json.dumps(data).encode(), mtime=0))
    print(f"{FILE}: {', '.join(f'{k} ({len(v)} ranges)' for k, v in data.items())}")


if __name__ == "__main__":
    main()
