"""Demand-driven sending: a channel crosses only while an application at a destination
subscribes to its output (``always`` channels regardless); interest travels as ``@want``."""

from __future__ import annotations

import pytest
import yaml

from bridge.core.interest import intersects, wanted_by
from bridge.core.loaded import load_mission, parse_mission
from bridge.errors import FrameError
from bridge.runtime.virtual_fleet import FastFleet
from bridge.wire.frame import FrameCodec
from tests.conftest import MISSIONS

ZSPACE = MISSIONS / "zspace.yaml"


@pytest.mark.parametrize(("a", "b", "meet"), [
    ("auv1/status", "auv1/status", True), ("auv1/status", "auv2/status", False),
    ("*/status", "auv1/status", True), ("**", "auv1/sensors/*/temp", True),
    ("auv1/**", "auv1", True), ("auv1/*", "auv1/sensors/a/temp", False),
    ("auv1/sensors/*/temp", "auv1/sensors/b/temp", True), ("auv$*", "auv1", True),
    ("auv$*", "top", False), ("a/**/c", "a/b/b/c", True), ("a/**/c", "a/b/d", False),
])
def test_key_expressions_meet_like_zenoh(a: str, b: str, meet: bool) -> None:
    assert intersects(a, b) is meet and intersects(b, a) is meet


def sent(fleet: FastFleet, node: str, channel: str) -> int:
    return fleet.cores[node].stats.sent_per_channel[channel]


def test_nothing_crosses_until_subscribed_and_it_stops_after_the_subscriber_leaves() -> None:
    fleet = FastFleet(load_mission(ZSPACE), seed=1)
    fleet.put("auv1", "auv1/status", {"battery": 80, "mode": "survey"})
    fleet.put("auv1", "auv1/alarm", {"leak": False})
    fleet.run_until(30.0)
    assert sent(fleet, "auv1", "status") == 0  # nobody at the surface wants it
    assert sent(fleet, "auv1", "alarm") >= 2  # always: true keeps today's behaviour
    assert fleet.cores["top"].interest.snapshot(fleet.loaded.table)["here"] == []
    fleet.subscribe("top", "auv1/status")
    fleet.run_until(36.0)  # one TDMA cycle for @want to cross, one for the value
    got = fleet.published("top", "auv1/status")
    assert got and got[0][1].value == {"battery": 80, "mode": "survey"}  # the latest, kept
    assert got[0][0] <= 30.0 + 2 * 3.0 + 1e-6
    assert sent(fleet, "auv2", "status") == 0  # auv2 has nothing to say: no value
    fleet.unsubscribe("top", "auv1/status")
    fleet.run_until(42.0)
    before = sent(fleet, "auv1", "status")
    fleet.run_until(90.0)
    assert sent(fleet, "auv1", "status") == before  # stopped within a cycle of leaving


def test_want_is_refreshed_so_a_lost_bitmap_heals() -> None:
    fleet = FastFleet(load_mission(ZSPACE), seed=1)
    fleet.put("auv1", "auv1/status", {"battery": 50, "mode": "idle"})
    fleet.run_until(10.0)
    fleet.stop("auv1")  # deaf for a moment (not long enough for its link to go down)...
    fleet.subscribe("top", "*/status")  # ...while the surface announces its interest
    fleet.run_until(14.0)
    fleet.resume("auv1")
    fleet.run_until(30.0)
    assert fleet.cores["top"].link_states["auv1"].value == "up"
    assert sent(fleet, "auv1", "status") == 0  # it missed the @want
    fleet.run_until(50.0)  # refresh_s: 30
    assert sent(fleet, "auv1", "status") >= 1
    assert fleet.published("top", "auv1/status")


def test_the_bridges_own_inputs_count_as_interest() -> None:
    loaded = load_mission(MISSIONS / "morph.yaml")
    nav = loaded.table.by_name("nav").index
    assert nav in wanted_by(loaded.table, "ssv", ["gcv/nav"])
    assert nav not in wanted_by(loaded.table, "ssv", ["gcv/status"])


def test_want_entry_round_trips_and_another_mission_refuses_it() -> None:
    loaded = load_mission(ZSPACE)
    codec = FrameCodec(loaded.table)
    want = loaded.table.interest
    assert want is not None and want.wire_bits == len(loaded.table)
    data = codec.encode([(want, want.pack({0, 3}))])
    (entry,) = codec.decode(data).entries
    assert entry.channel is want and entry.header == (0, 3)
    text = yaml.safe_load(ZSPACE.read_text())
    del text["demand"]
    without = parse_mission(yaml.safe_dump(text), "no-demand.yaml")
    assert without.table.interest is None
    assert without.table.fingerprint != loaded.table.fingerprint
    with pytest.raises(FrameError):
        FrameCodec(without.table).decode(data)


def test_a_sender_back_from_silence_hears_the_interest_again_at_once() -> None:
    fleet = FastFleet(load_mission(ZSPACE), seed=1)
    fleet.subscribe("top", "auv1/status")
    fleet.run_until(10.0)
    fleet.stop("auv1")
    down_after = fleet.cores["top"].thresholds.down_after_s
    fleet.run_until(10.0 + down_after + 1.0)  # its link goes down at the surface
    assert fleet.cores["top"].link_states["auv1"].value == "down"
    back = fleet.now
    fleet.cores["auv1"] = type(fleet.cores["auv1"])(fleet.loaded, "auv1")  # a restart
    fleet.resume("auv1")
    fleet.put("auv1", "auv1/status", {"battery": 42, "mode": "idle"})
    fleet.run_until(back + 4 * 3.0)  # far sooner than refresh_s (30 s)
    got = [p.value for t, p in fleet.published("top", "auv1/status") if t > back]
    assert got and got[0] == {"battery": 42, "mode": "idle"}


def test_every_channel_and_the_want_fit_one_frame_count() -> None:
    text = yaml.safe_load(ZSPACE.read_text())
    del text["queries"]
    text["channels"] = [c for c in text["channels"] if "keys" not in c][:1]  # one channel
    loaded = parse_mission(yaml.safe_dump(text), "one.yaml")
    codec = FrameCodec(loaded.table)
    assert not codec.repeats and codec.count_bits == 2  # the channel and @want
    want = loaded.table.interest
    channel = loaded.table.channels[0]
    data = codec.encode([(want, want.pack({0})), (channel, 3)])
    assert [e.channel.name for e in codec.decode(data).entries] == ["@want", "status"]
