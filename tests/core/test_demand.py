"""Demand-driven sending: a channel crosses only while an application at a destination
subscribes to its output (``always`` channels regardless); interest travels as ``@want``."""

from __future__ import annotations

import time
from pathlib import Path

import msgpack
import pytest
import yaml

from bridge.core.interest import intersects, wanted_by
from bridge.core.loaded import load_mission, parse_mission
from bridge.errors import FrameError
from bridge.runtime.virtual_fleet import FastFleet
from bridge.wire.frame import FrameCodec
from tests.conftest import MISSIONS
from tests.harness import put
from tests.zsim import app as plain_app
from tests.zsim import mission_file, zab_sim

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
    fleet.put("auv1", "status", {"battery": 80, "mode": "survey"})
    fleet.put("auv1", "alarm", {"leak": False})
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
    fleet.put("auv1", "status", {"battery": 50, "mode": "idle"})
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


def latest_stats(session, key: str, seconds: float) -> dict:
    got: list[dict] = []
    sub = session.declare_subscriber(key, lambda s: got.append(
        msgpack.unpackb(s.payload.to_bytes())))
    try:
        end = time.time() + seconds
        while time.time() < end and not got:
            time.sleep(0.05)
        return got[-1] if got else {}
    finally:
        sub.undeclare()


def test_a_subscriber_at_the_surface_turns_a_channel_on_and_off_through_zab_sim(
        tmp_path: Path) -> None:
    mission, endpoints = mission_file(ZSPACE.read_text(), tmp_path)
    with zab_sim(mission, endpoints):
        auv1, top = plain_app(endpoints["auv1"]), plain_app(endpoints["top"])
        try:
            put(auv1, "status", {"battery": 77, "mode": "transit"})
            time.sleep(7.0)  # two TDMA cycles: nothing is wanted yet
            key = "@zab/zspace/auv1/stats"
            assert latest_stats(auv1, key, 3.0)["sent_per_channel"].get("status", 0) == 0
            got: list[tuple[str, dict]] = []
            sub = top.declare_subscriber("auv1/status", lambda s: got.append(
                (str(s.key_expr), msgpack.unpackb(s.payload.to_bytes()))))
            deadline = time.time() + 10.0
            while not got and time.time() < deadline:
                time.sleep(0.05)
            assert got[0] == ("auv1/status", {"battery": 77, "mode": "transit"})
            sub.undeclare()
            time.sleep(4.0)  # the new @want crosses within a cycle
            before = latest_stats(auv1, key, 3.0)["sent_per_channel"]["status"]
            time.sleep(6.0)
            after = latest_stats(auv1, key, 3.0)["sent_per_channel"]["status"]
            assert after == before
        finally:
            auv1.close()
            top.close()


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
    fleet.put("auv1", "status", {"battery": 42, "mode": "idle"})
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
