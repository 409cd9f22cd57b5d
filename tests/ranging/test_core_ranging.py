"""NodeCore's ranging outputs, pure: modem ranges, no-fix reports, range turns."""

from __future__ import annotations

import math

import yaml

from bridge.core.events import Event, Position, Range, RangeFailed
from bridge.core.loaded import parse_mission
from bridge.core.node import NodeCore, Status
from bridge.modems.base import ModemRange, Reception

MISSION = {
    "mission": "pings",
    "mac": {"type": "none"},
    "ranging": {"ping": {"interval_s": 5.0}},
    "link": {"heartbeat_s": 3600.0},
    "nodes": {
        "a1": {"address": 1, "role": "surface", "position": {"x": 0, "y": 0, "depth": 0}},
        "a2": {"address": 2, "role": "surface", "position": {"x": 0, "y": 40, "depth": 0}},
        "auv": {"address": 3, "position": {"x": 30, "y": 20, "depth": 0}},
    },
    "channels": [{"name": "n", "from": "auv", "to": "a1", "elements": [
        {"in": "n", "out": "auv/n", "fields": [{"field": "v", "type": "int", "min": 0,
                                                 "max": 9}]}]}],
}


def test_ranges_turns_and_no_fix_without_dlbl() -> None:
    core = NodeCore(parse_mission(yaml.safe_dump(MISSION)), "auv")
    assert core.positioning is not None and not core.table.dlbl  # ranging.ping alone needs it
    assert core.next_due() == -math.inf  # a range is due at once, even with no data
    ranges = core.ranges
    assert ranges is not None
    assert ranges.due(100.0) == 1
    ranges.asked("a1", 100.0, None)
    core.outbound.last_tx = 100.0  # the heartbeat is not what is due next
    assert ranges.due(101.0) is None and core.next_due() == 105.0
    core.modem_range(ModemRange(1, math.dist((30, 20), (0, 0)) / 1500.0, "ping", 101.0), 101.5)
    out = core.take()
    status = {o.topic: o.payload for o in out if isinstance(o, Status)}
    assert status["range/a1"]["method"] == "ping" and status["range/a1"]["time"] == 101.5
    assert abs(status["range/a1"]["range_m"] - math.dist((30, 20), (0, 0))) < 1e-9
    assert status["position"] == {"fix": False, "state": "lost", "reason": "too_few_anchors",
                                  "anchors": ["a1"], "time": 101.5,
                                  "detail": status["position"]["detail"]}
    assert [type(o) for o in out if isinstance(o, Event)] == [Range, Position]
    assert ranges.due(105.0) == 2  # the other anchor's turn
    ranges.asked("a2", 105.0, "no ping reply")
    (failed,) = core.take()
    assert failed == RangeFailed(105.0, "a2", "no ping reply")
    assert ranges.due(200.0) is None  # the opportunity after a range goes to frames
    assert ranges.due(200.0) == 1
    core.modem_range(ModemRange(2, math.dist((30, 20), (0, 40)) / 1500.0, "ping", 106.0), 106.0)
    fix = next(o.payload for o in core.take() if isinstance(o, Status) and o.topic == "position")
    assert fix["fix"] is True and abs(fix["x"] - 30) < 1e-6 and abs(fix["y"] - 20) < 1e-6
    core.modem_range(ModemRange(9, 0.01, "ping", 107.0), 107.0)  # nobody at address 9
    assert core.take() == []
    # frames still decode without DLBL delays in them
    peer = NodeCore(parse_mission(yaml.safe_dump(MISSION)), "a1")
    assert peer.positioning is None  # a1 is only ranged to
    assert peer.next_due(100.0) == 3700.0  # its first heartbeat, one period after its start
    core.ingest("n", b'{"v": 4}', "application/json", 110.0)
    frame = core.outbound.build(110.0, 110.0)
    assert frame is not None
    peer.receive(Reception(frame.data, 3, 111.0), 111.0)
    assert peer.stats.frames_received == 1
