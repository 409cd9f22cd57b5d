"""End to end through the real runtime (``zab sim`` nodes over the simulated water): a vehicle
sails seed 001's rectangle with only two anchors on the jetty, its own compass on its nav key,
and the position it publishes stays within a metre of the truth, round the corner."""

from __future__ import annotations

import math
import threading
import time

import yaml

from bridge.mission.path import Path
from bridge.ranging import seed001
from tests.conftest import on_free_ports
from tests.harness import Inbox, outside_session, put, running_fleet

LONG = True  # 22 s of a real-time fleet: handed out first
SLOT_S = 0.4
LEFT, RIGHT = seed001.ANCHORS["left"], seed001.ANCHORS["right"]
WAYPOINTS = [{"x": x, "y": y, "depth": d} for x, y, d in seed001.route().waypoints]
MISSION = {
    "mission": "jetty2",
    "wire": {"dlbl": True},
    "modem": {"backend": "sim", "frame_bytes": 32, "options": {"preset": "evologics-s2c-im"}},
    "mac": {"type": "tdma", "slot_s": SLOT_S, "guard_s": 0.05, "order": ["auv", "a1", "a2"]},
    "ranging": {"anchors": ["a1", "a2"], "sound_speed_mps": 1500},
    "nodes": {
        "a1": {"address": 1, "role": "surface",
               "position": {"x": LEFT[0], "y": LEFT[1], "depth": LEFT[2]}},
        "a2": {"address": 2, "role": "surface",
               "position": {"x": RIGHT[0], "y": RIGHT[1], "depth": RIGHT[2]}},
        "auv": {"address": 3, "nav_key": "nav", "path": {
            "waypoints": WAYPOINTS, "speed_mps": seed001.SPEED_MPS, "loop": True}},
    },
}
RUN_S = 22.0  # round the (15, 5) corner at 6.7 s and 15 m up the east leg


def test_published_position_of_a_moving_vehicle_stays_within_a_metre() -> None:
    loaded = on_free_ports(yaml.safe_dump(MISSION), "jetty2.yaml")
    path = Path.from_spec(loaded.mission.nodes["auv"].path)
    with running_fleet(loaded) as fleet:
        water = fleet.water
        assert water is not None and water.started_at is not None
        start = water.started_at
        app = outside_session(loaded, "auv")
        stop = threading.Event()

        def compass() -> None:  # the vehicle's own navigation: depth and heading, 5 Hz
            while not stop.wait(0.2):
                t = time.time() - start
                x, y, depth = path.position_at(t)
                put(app, "nav", {"x": x, "y": y, "depth": depth,
                                 "heading": seed001.heading_at(path, t)})

        publisher = threading.Thread(target=compass, daemon=True)
        try:
            inbox = Inbox()
            app.declare_subscriber("@zab/jetty2/auv/position", inbox)
            publisher.start()
            got = []
            while time.time() - start < RUN_S:
                got.extend(inbox.drain(0.5))
        finally:
            stop.set()
            publisher.join()
            app.close()
    tracked = [v for _, v, _ in got if v["fix"]]
    assert len(tracked) >= 15, got
    assert {v["reason"] for _, v, _ in got if not v["fix"]} <= {"too_few_anchors", "ambiguous"}
    errors = []
    for v in tracked:
        assert v["state"] == "tracking" and v["x"] > 0  # never the mirror image
        assert set(v["anchors"]) <= {"a1", "a2"} and len(v["cov"]) == 2
        if v["time"] - tracked[0]["time"] > 2.0:  # a cycle or two to learn the speed
            truth = path.position_at(v["time"] - start)
            errors.append(math.dist((v["x"], v["y"]), truth[:2]))
    assert errors and max(errors) < 1.0, errors
    assert tracked[-1]["time"] - start > 10.0 / seed001.SPEED_MPS + 5.0  # round the corner
    assert abs(math.hypot(tracked[-1]["vx"], tracked[-1]["vy"]) - seed001.SPEED_MPS) < 0.3
