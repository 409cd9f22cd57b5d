"""Scripted surfacing: a vehicle whose path reaches the surface is on the surface's IP link
while it is there, decided in one place (bridge/sim/scenario.py) for zab sim and zab sim
--fast; acoustic carrying to it stops while surfaced and resumes after the dive, latched state
intact and without a burst."""

from __future__ import annotations

import asyncio
import math

import yaml

from bridge.cli.sim_fast import run_fast
from bridge.core.loaded import parse_mission
from bridge.core.surfacing import Relay
from bridge.mission.path import Path
from bridge.runtime.virtual_fleet import FastFleet
from bridge.sim.scenario import surface_script, surface_windows
from tests.conftest import MISSIONS

CYCLE_S = 3.0  # the example's TDMA cycle
# auv1 rises 10 m at 1 m/s, sails 20 m at the surface, dives 10 m: surfaced ~[10, 30] s
PATH = {"waypoints": [{"x": 40, "y": 30, "depth": 10}, {"x": 40, "y": 30, "depth": 0},
                      {"x": 40, "y": 50, "depth": 0}, {"x": 40, "y": 50, "depth": 10}],
        "speed_mps": 1.0}


def mission(path: dict = PATH):
    data = yaml.safe_load((MISSIONS / "zspace.yaml").read_text())
    data["nodes"]["auv1"]["path"] = path
    return parse_mission(yaml.safe_dump(data, sort_keys=False), "zspace.yaml")


def test_windows_follow_the_path_depth() -> None:
    path = Path.from_spec(mission().mission.nodes["auv1"].path)
    ((a, b),) = surface_windows(path)
    assert math.isclose(a, 9.9) and math.isclose(b, 30.1)
    stays = Path(((0, 0, 5), (0, 0, 0)), 1.0)  # ends at the surface: stays there
    assert surface_windows(stays) == ((4.9, math.inf),)
    loop = Path(((0, 0, 0), (0, 0, 10)), 1.0, loop=True)  # surfaced at both ends of a pass
    assert [(round(x, 3), round(y, 3)) for x, y in surface_windows(loop)] == [
        (0.0, 0.1), (19.9, 20.0)]
    script = surface_script(mission(), start=100.0)
    assert script is not None and script.surface_nodes == ("top",)
    assert not script.surfaced("auv1", 105.0) and script.surfaced("auv1", 120.0)
    assert script.ip_pairs(120.0) == {("top", "auv1")} and script.ip_pairs(131.0) == set()
    assert math.isclose(script.next_change("auv1", 100.0), 109.9)
    assert math.isclose(script.next_change("auv1", 110.0), 130.1)
    assert script.next_change("auv1", 131.0) is None
    data = yaml.safe_load((MISSIONS / "zspace.yaml").read_text())
    del data["surfacing"]  # nobody would switch to IP
    data["nodes"]["auv1"]["path"] = PATH
    assert surface_script(parse_mission(yaml.safe_dump(data), "z.yaml")) is None


def test_a_scripted_surfacing_stops_acoustic_carrying_and_the_dive_resumes_it() -> None:
    f = FastFleet(mission(), seed=1)
    f.subscribe("top", "auv1/status")
    f.put("auv1", "auv1/status", {"battery": 77.3, "mode": "survey"}, at=0.5)
    f.put("auv1", "auv1/alarm", {"leak": False}, at=0.5)
    f.put("auv1", "auv1/status", {"battery": 66.6, "mode": "transit"}, at=15.0)
    f.put("auv1", "auv1/status", {"battery": 55.0, "mode": "transit"}, at=20.0)
    f.run_until(9.8)
    assert f.published("top", "auv1/status")[-1][1].value == {"battery": 77, "mode": "survey"}
    f.run_until(10.5)  # surfaced: both bridges saw the other on IP
    assert f.cores["top"].surfacing.reachable == {"auv1"}
    assert f.cores["auv1"].surfacing.reachable == {"top"}
    sent = dict(f.cores["auv1"].stats.sent_per_channel)
    start = len(f.outputs)
    f.run_until(30.0)
    assert f.cores["auv1"].stats.sent_per_channel == sent  # no status, no alarm acoustically
    assert not [t for t, _ in f.published("top", "auv1/status") if t > 10.5]
    relays = [o.output.key for o in f.outputs[start:] if isinstance(o.output, Relay)]
    assert relays == []  # the output key is the input key: Zenoh carries each sample itself
    f.run_until(30.2)  # dived
    assert f.cores["top"].surfacing.reachable == set()
    f.run_until(30.2 + CYCLE_S)
    after = [p.value for t, p in f.published("top", "auv1/status") if t > 30.1]
    assert after == [{"battery": 55, "mode": "transit"}]  # the latest, once: no burst
    assert len([t for t, _ in f.published("top", "auv1/alarm") if t > 30.1]) == 1
    switches = f.cores["top"].surfacing.switches
    assert [(s["peer"], s["ip"]) for s in switches] == [("auv1", True), ("auv1", False)]


def test_zab_sim_fast_reports_the_scripted_surfacing() -> None:
    out = asyncio.run(run_fast(mission(), duration=60.0, seed=1))
    assert [(s["peer"], s["ip"], round(s["time"], 1)) for s in out.surfacing["auv1"]] == [
        ("top", True, 9.9), ("top", False, 30.1)]


