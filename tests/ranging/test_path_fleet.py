"""Seed 001's mobile case in the simulated ocean: a vehicle sails a 10 m × 30 m rectangle east of
three anchors on a jetty, and its published positions (the range-domain tracker's) follow it
(round a corner, through the mirror ambiguity of anchors on one line), in real time and on the
virtual clock."""

from __future__ import annotations

import math
import statistics
import time

import pytest
import yaml

from bridge.core.loaded import parse_mission
from bridge.core.node import Status
from bridge.mission.path import Path
from bridge.runtime.virtual_fleet import FastFleet
from tests.conftest import on_free_ports
from tests.harness import Inbox, outside_session, running_fleet

SLOT_S = 0.4
SPEED = 1.5
MISSION = {
    "mission": "jetty",
    "wire": {"dlbl": True},
    "modem": {"backend": "sim", "frame_bytes": 32, "options": {"preset": "evologics-s2c-im"}},
    "mac": {"type": "tdma", "slot_s": SLOT_S, "guard_s": 0.05,
            "order": ["auv", "a1", "a2", "a3"]},
    "ranging": {"anchors": ["a1", "a2", "a3"], "sound_speed_mps": 1500},
    "nodes": {
        "a1": {"address": 1, "role": "surface", "position": {"x": 0, "y": 0, "depth": 0.5}},
        "a2": {"address": 2, "role": "surface", "position": {"x": 0, "y": 20, "depth": 0.5}},
        "a3": {"address": 3, "role": "surface", "position": {"x": 0, "y": 40, "depth": 0.5}},
        "auv": {"address": 4, "path": {
            "waypoints": [{"x": 5, "y": 5, "depth": 1}, {"x": 15, "y": 5, "depth": 1},
                          {"x": 15, "y": 35, "depth": 1}, {"x": 5, "y": 35, "depth": 1}],
            "speed_mps": SPEED, "loop": True}},
    },
}


def test_fixes_follow_a_vehicle_sailing_the_seed001_rectangle() -> None:
    loaded = on_free_ports(yaml.safe_dump(MISSION), "jetty.yaml")
    path = Path.from_spec(loaded.mission.nodes["auv"].path)
    assert path.length_m == 80.0
    with running_fleet(loaded) as fleet:
        water = fleet.water
        assert water is not None and water.started_at is not None
        app = outside_session(loaded, "auv")
        try:
            inbox = Inbox()
            app.declare_subscriber("@zab/jetty/auv/position", inbox)
            got = []  # until the fixes have gone round the first corner, 10 m from the start
            deadline = time.time() + 20.0
            while time.time() < deadline and not any(v["fix"] and v["y"] > 8.0
                                                     for _, v, _ in got[10:]):
                got.extend(inbox.drain(0.5))
        finally:
            app.close()
        start = water.started_at
    fixes = [value for _, value, _ in got if value["fix"]]
    refused = [value for _, value, _ in got if not value["fix"]]
    assert len(fixes) >= 10, got
    assert all(v["reason"] in ("too_few_anchors", "ambiguous") for v in refused)  # starting
    # the published position is the tracker's, at the time it names. With no compass here
    # (ranges and depth only) the instant 90° turn at (15, 5) surprises it for a few seconds
    # (2-3 m); elsewhere, once it has its velocity, it stays within ~half a metre of the truth.
    # (tests/ranging/test_tracker_fleet.py: with the vehicle's heading, within 1 m throughout.)
    corner_s = 10.0 / SPEED
    straight, all_errors = [], []
    for fix in fixes:
        assert fix["depth"] == 1.0 and set(fix["anchors"]) <= {"a1", "a2", "a3"}
        assert fix["x"] > 0 and fix["state"] == "tracking"  # the mirror image never chosen
        t = fix["time"] - start
        error = math.dist((fix["x"], fix["y"]), path.position_at(t)[:2])
        if fix["time"] - fixes[0]["time"] > 3.0:  # two cycles to learn the velocity
            all_errors.append(error)
            if not corner_s - 0.5 < t < corner_s + 5.0:
                straight.append(error)
    assert max(straight) < 0.75, straight  # real time: the machine's load shows a little
    assert max(all_errors) < 4.0, all_errors  # the instant turn, more so on a loaded machine
    travelled = math.dist((fixes[0]["x"], fixes[0]["y"]), (fixes[-1]["x"], fixes[-1]["y"]))
    assert travelled > 6.0, fixes  # it really moved, and the fixes moved with it
    assert fixes[-1]["y"] > 8.0, "turned north at the (15, 5) corner"
    assert 0.5 * SPEED < math.hypot(fixes[-1]["vx"], fixes[-1]["vy"]) < 1.5 * SPEED


def test_two_laps_of_the_rectangle_on_the_virtual_clock() -> None:
    loaded = parse_mission(yaml.safe_dump(MISSION), "jetty.yaml")
    path = Path.from_spec(loaded.mission.nodes["auv"].path)
    fleet = FastFleet(loaded, seed=1)
    fleet.run_until(2 * path.length_m / SPEED)
    fixes = [(t.time, t.output.payload) for t in fleet.outputs
             if t.node == "auv" and isinstance(t.output, Status)
             and t.output.topic == "position" and t.output.payload["fix"]]
    assert len(fixes) > 180  # one per range (three per 1.6 s TDMA cycle) once tracking
    errors, straight, west = [], [], []
    for t, fix in fixes:
        assert fix["x"] > 0 and fix["time"] == t  # the mirror image is never chosen
        truth = path.position_at(t)
        error = math.dist((fix["x"], fix["y"]), truth[:2])
        errors.append(error)
        since_corner = min((t - along / SPEED) % path.duration_s for along in (10, 40, 50, 80))
        if t > 3.0 and since_corner > 5.0:
            straight.append(error)
            if truth[0] == pytest.approx(5.0):
                west.append(error)
    # the tracker, with no compass here, is surprised for a few seconds by each instant 90°
    # turn; between the corners it keeps within half a metre, the west leg (5 m from the line
    # of anchors, where a single fix is ill-conditioned in x) included
    assert max(straight) < 0.5 and max(west) < 0.5, (straight, west)
    assert statistics.fmean(errors) < 0.4 and max(errors) < 2.5, errors
