"""A moving anchor's live position (``ranging.anchor_keys``) rides the same frames as its DLBL
delays: each bridge takes it from the frame it decodes before fusing that frame's range, on
the virtual clock (:class:`~bridge.runtime.virtual_fleet.FastFleet`)."""

from __future__ import annotations

import math

import yaml

from bridge.core.loaded import parse_mission
from bridge.mission.path import Path
from bridge.ranging.tracker import RangeObs
from bridge.runtime.virtual_fleet import FastFleet

SLOT_S = 1.0
MISSION = {
    "mission": "mover",
    "wire": {"dlbl": True},
    "modem": {"backend": "sim", "frame_bytes": 32, "options": {"preset": "evologics-s2c-im"}},
    "mac": {"type": "tdma", "slot_s": SLOT_S, "guard_s": 0.1, "order": ["a1", "a2", "auv"]},
    "ranging": {"anchors": ["a1", "a2"], "anchor_keys": {"a2": "a2/nav"},
                "sound_speed_mps": 1500},
    "nodes": {
        "a1": {"address": 1, "role": "surface", "position": {"x": 0, "y": 0, "depth": 0.5}},
        # a vehicle that weaves, as MORPH's gcv does: a report extrapolated over a cycle or
        # two misses its turns
        "a2": {"address": 2, "path": {"speed_mps": 0.8, "loop": True, "waypoints": [
            {"x": 20, "y": 0, "depth": 12}, {"x": 26, "y": 8, "depth": 12},
            {"x": 20, "y": 16, "depth": 12}, {"x": 26, "y": 24, "depth": 12}]}},
        "auv": {"address": 3, "position": {"x": 10, "y": 30, "depth": 15}},
    },
    "channels": [{"name": "nav", "from": "a2", "to": ".*", "elements": [
        {"in": "nav", "out": "a2/nav", "fields": [
            {"field": "x", "resolution": 0.01, "min": -100, "max": 100},
            {"field": "y", "resolution": 0.01, "min": -100, "max": 100},
            {"field": "depth", "resolution": 0.01, "min": 0, "max": 100}]}]}],
}


def test_a_moving_anchors_range_uses_the_position_its_own_frame_brought() -> None:
    loaded = parse_mission(yaml.safe_dump(MISSION))
    path = Path.from_spec(loaded.mission.nodes["a2"].path)
    fleet = FastFleet(loaded, seed=3, loss=0.0)

    def navigate() -> None:  # a2's own navigation, 1 Hz, on its nav key
        x, y, depth = path.position_at(fleet.now)
        fleet.put("a2", "nav", {"x": x, "y": y, "depth": depth})
        fleet.call_at(fleet.now + 1.0, navigate)

    positioning = fleet.cores["auv"].positioning
    assert positioning is not None and positioning.tracker is not None
    tracker = positioning.tracker
    fused: list[RangeObs] = []
    take = tracker.on_range

    def on_range(obs: RangeObs) -> object:
        fused.append(obs)
        return take(obs)

    tracker.on_range = on_range  # type: ignore[method-assign]
    fleet.call_at(0.0, navigate)
    fleet.run_until(120.0)
    moving = [o for o in fused if o.anchor == "a2" and o.time > 10.0]
    assert len(moving) >= 30
    for obs in moving:
        # the report came with this range's frame: under a second old (a 1 Hz nav sample),
        # not a cycle or more (before: the bridge published it and heard it back over Zenoh
        # after fusing the range, so every range used the report of an earlier frame)
        assert obs.anchor_age_s < 1.0, obs
        for t, where in ((obs.time, obs.anchor_at), (obs.time - obs.span_s, obs.anchor_before)):
            assert where is not None
            assert math.dist(where[:2], path.position_at(t)[:2]) < 1.0, (obs, t)
    assert positioning.anchor_reports["a2"]  # taken from the frames, by the bridge itself
    estimate = positioning.estimate(fleet.now)
    assert estimate is not None and estimate.state == "tracking"
    # 0.29 m with the manoeuvring mode, 0.33 m with turned components (their σ 1.5 / 0.9 m)
    assert math.dist((estimate.x, estimate.y), (10.0, 30.0)) < 0.4
