"""The outbox builds only the outputs its runtime carries out, and counts them all."""

from __future__ import annotations

import random
from pathlib import Path

from bridge.cli.sim_fast import feed
from bridge.core.events import Event
from bridge.core.loaded import load_mission
from bridge.core.outputs import Outbox, Publish, Status
from bridge.runtime.virtual_fleet import FastFleet

MORPH = Path(__file__).resolve().parents[2] / "deploy" / "missions" / "morph.yaml"


def test_an_outbox_for_events_only_builds_no_publication_or_status_but_counts_them() -> None:
    for kinds, built in (((Event,), False), ((object,), True), (None, True),
                         ((Publish, Status), True)):
        outbox = Outbox(kinds)
        outbox.publish("a/b", 1.0, "application/msgpack", latched=False)
        outbox.status("link/x", {"state": "up"})
        assert [type(o) for o in outbox.take()] == ([Publish, Status] if built else []), kinds
        assert outbox.stats.values_published == 1


def run(kinds: tuple[type, ...]) -> tuple[list[object], dict[str, object]]:
    fleet = FastFleet(load_mission(MORPH), seed=3, loss=0.2, kinds=kinds)
    feed(fleet, random.Random("feed/3"), 120.0)
    fleet.run_until(120.0)
    events = [(t.time, t.node, t.output) for t in fleet.outputs if isinstance(t.output, Event)]
    return events, {name: core.stats for name, core in fleet.cores.items()}


def test_a_fleet_that_keeps_only_events_sees_the_same_events_and_counters() -> None:
    every, every_stats = run((Publish, Status, Event))
    events, stats = run((Event,))
    assert len(every) > 100
    assert events == every
    assert stats == every_stats
