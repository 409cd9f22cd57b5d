"""The tracker says what it said when its traces were recorded (``tests/ranging/traces.py``):
every estimate to 1e-9, every decision exactly, on each path through it."""

from __future__ import annotations

import math

import pytest

from tests.ranging.traces import TRACES, Trace, load, run

INDEPENDENT = True  # pure replays on a virtual clock: xdist may spread them
FLOATS = range(5, 13)
"""The columns of a row that are estimates (x … doubt); the others are decisions."""


@pytest.mark.parametrize("trace", TRACES, ids=lambda t: t.name)
def test_the_tracker_says_what_was_recorded(trace: Trace) -> None:
    recorded = load()[trace.name]
    got = run(trace)
    assert len(got) == len(recorded) > 100
    for old, new in zip(recorded, got, strict=True):
        decisions = [v for k, v in enumerate(old) if k not in FLOATS]
        assert [v for k, v in enumerate(new) if k not in FLOATS] == decisions, (old, new)
        assert all(math.isclose(new[k], old[k], rel_tol=1e-9, abs_tol=1e-9) for k in FLOATS), (
            old, new)


def test_the_traces_cover_every_path() -> None:
    data = load()
    last = {name: rows[-1] for name, rows in data.items()}
    assert last["compass, outliers"][16].keys() >= {"long", "short"}  # refusals by reason
    assert last["no compass"][13] > 5  # manoeuvres taken
    assert last["folded back"][14] >= 1  # a fold
    assert any(r[3] == "lost" and r[4] == "ambiguous" for r in data["no prior"])
    assert any(r[3] == "tracking" for r in data["no prior"])
