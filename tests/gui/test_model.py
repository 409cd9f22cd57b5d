"""The GUI's pure picture of the fleet: keys at the surface, positions, links, events."""

from __future__ import annotations

import json

import msgpack
import pytest

from bridge.core.loaded import LoadedMission, load_mission
from bridge.gui.keys import SurfaceKeys
from bridge.gui.model import GuiModel, shown
from tests.conftest import MISSIONS

MSGPACK = "application/msgpack"


@pytest.fixture(scope="module")
def morph() -> LoadedMission:
    return load_mission(MISSIONS / "morph.yaml")


def pack(value: object) -> bytes:
    return msgpack.packb(value, use_bin_type=True)


def kinds(items: list[dict]) -> list[str]:
    return [i["kind"] for i in items]


def test_keys_at_the_surface_name_each_vehicle_channel_and_its_navigation(morph):
    keys = SurfaceKeys(morph, "ssv")
    assert [(s.channel, s.src, s.nav) for s in keys.sources["gcv/nav"]] == [("nav", "gcv", True)]
    assert [(s.channel, s.src, s.nav) for s in keys.sources["cv2/status"]] == [
        ("status", "cv2", False)]
    # what ssv itself sends is read on its input keys there
    assert [(s.channel, s.src) for s in keys.sources["command"]] == [("mission_command", "ssv")]
    # target_reference goes lsv -> gcv only: the surface never sees it
    assert "lsv/target_reference" not in keys.sources
    assert "@zab/morph/**" in keys.subscriptions()
    status = keys.status("@zab/morph/ssv/link/gcv")
    assert (status.node, status.topic, status.name) == ("ssv", "link", "gcv")
    assert keys.status("@zab/other/ssv/stats") is None
    assert keys.status("@zab/morph/ssv/a/b/c") is None


def test_keys_refuse_an_unknown_node(morph):
    with pytest.raises(ValueError, match="nodes: ssv, gcv"):
        SurfaceKeys(morph, "nemo")


def test_navigation_moves_a_vehicle_and_draws_its_track(morph):
    model = GuiModel(morph, "ssv", track_points=3)
    for i in range(5):
        model.ingest("gcv/nav", pack({"x": 20.0 + i, "y": 30.0, "depth": 12.0, "heading": 0,
                                      "speed": 1.0}), MSGPACK, 100.0 + i)
    items = model.take()
    positions = [i for i in items if i["kind"] == "position"]
    assert [p["x"] for p in positions] == [20.0, 21.0, 22.0, 23.0, 24.0]
    assert {p["source"] for p in positions} == {"nav"}
    channels = [i for i in items if i["kind"] == "channel"]
    assert channels[-1]["interval_s"] == pytest.approx(1.0)
    assert channels[-1]["count"] == 5
    assert channels[0]["interval_s"] is None
    # the track keeps the newest points only; a snapshot carries it whole
    track = next(i for i in model.snapshot() if i["kind"] == "track")
    assert track == {"kind": "track", "node": "gcv", "source": "nav",
                     "points": [[22.0, 30.0, 102.0], [23.0, 30.0, 103.0], [24.0, 30.0, 104.0]]}


def test_json_payloads_are_read_too(morph):
    model = GuiModel(morph, "ssv")
    model.ingest("cv1/status", json.dumps({"battery": 80, "mode": "survey", "leak": False})
                 .encode(), "application/json", 5.0)
    (item,) = model.take()
    assert item["node"] == "cv1" and item["value"] == {"battery": 80, "mode": "survey",
                                                       "leak": False}


def test_unreadable_payloads_are_counted_and_logged_once(morph):
    model = GuiModel(morph, "ssv")
    for t in range(3):
        model.ingest("lsv/nav", b"\xc1\xc1", MSGPACK, float(t))
    model.ingest("lsv/nav", pack({"x": "north"}), MSGPACK, 4.0)  # not a position
    items = model.take()
    events = [i for i in items if i["kind"] == "event"]
    assert len(events) == 1 and "lsv/nav" in events[0]["text"]
    assert model.dropped["lsv/nav"] == 4
    assert "position" not in kinds(items)


def test_keys_the_gui_does_not_know_are_ignored(morph):
    model = GuiModel(morph, "ssv")
    model.ingest("somebody/else", pack({"x": 1}), MSGPACK, 1.0)
    model.ingest("@zab/morph/nemo/stats", pack({"frames_sent": 1}), MSGPACK, 1.0)
    assert model.take() == []


def test_stats_give_links_last_heard_and_dropped_frames(morph):
    model = GuiModel(morph, "ssv")
    stats = {"node": "ssv", "time": 1000.0, "frames_sent": 3, "frames_received": 5,
             "frames_dropped": {}, "payloads_dropped": {}, "send_errors": 0,
             "last_heard": {"gcv": 998.0}, "links": {"gcv": "up", "lsv": "down"}}
    # the bridge's clock is 900 s ahead of the GUI's: only differences count
    model.ingest("@zab/morph/ssv/stats", pack(stats), MSGPACK, 100.0)
    items = model.take()
    heard = next(i for i in items if i["kind"] == "heard")
    assert heard == {"kind": "heard", "node": "gcv", "last_heard": 98.0}
    links = {i["node"]: i["state"] for i in items if i["kind"] == "link"}
    assert links == {"gcv": "up", "lsv": "down"}
    events = [(e["level"], e["text"]) for e in items if e["kind"] == "event"]
    # a peer not heard yet, at the start, is no fault: not an error line
    assert events == [("info", "link ssv ↔ gcv: up"), ("info", "link ssv ↔ lsv: not heard yet")]
    # the next stats: same links (no news), two more frames dropped failing the check
    stats = {**stats, "time": 1001.0, "frames_dropped": {"check": 2}, "send_errors": 1}
    model.ingest("@zab/morph/ssv/stats", pack(stats), MSGPACK, 101.0)
    items = model.take()
    assert "link" not in kinds(items) and "heard" not in kinds(items)
    texts = [e["text"] for e in items if e["kind"] == "event"]
    assert any("dropped 2 frames" in t and "same mission file" in t for t in texts)
    assert not any("(s)" in t for t in texts)
    assert any("1 modem send error" in t for t in texts)


def test_link_changes_are_logged_once_from_any_source(morph):
    model = GuiModel(morph, "ssv")
    model.ingest("@zab/morph/ssv/link/cv1", pack({"peer": "cv1", "state": "up",
                                                  "last_heard": 50.0, "silent_s": 0.0}),
                 MSGPACK, 10.0)
    model.ingest("@zab/morph/ssv/link/cv1", pack({"peer": "cv1", "state": "degraded",
                                                  "last_heard": 50.0, "silent_s": 16.0}),
                 MSGPACK, 26.0)
    model.liveliness("@zab/morph/ssv/link/cv1", False, 40.0)  # the token vanished
    model.ingest("@zab/morph/ssv/link/cv1", pack({"peer": "cv1", "state": "down",
                                                  "last_heard": 50.0, "silent_s": 30.0}),
                 MSGPACK, 40.1)
    items = model.take()
    assert [i["state"] for i in items if i["kind"] == "link"] == ["up", "degraded", "down"]
    events = [i["text"] for i in items if i["kind"] == "event"]
    assert events == ["link ssv ↔ cv1: up", "link ssv ↔ cv1: degraded (silent 16 s)",
                      "link ssv ↔ cv1: down"]


def test_ranges_and_fixes(morph):
    model = GuiModel(morph, "ssv")
    model.ingest("@zab/morph/ssv/range/gcv", pack({"peer": "gcv", "range_m": 38.2,
                                                   "method": "dlbl", "time": 1.0}), MSGPACK, 7.0)
    model.ingest("@zab/morph/lsv/position", pack({"fix": True, "x": 1.0, "y": 60.0,
                                                  "depth": 10.0, "sigma_m": 0.3,
                                                  "anchors": ["ssv", "gcv"]}), MSGPACK, 8.0)
    model.ingest("@zab/morph/cv1/position", pack({"fix": False, "reason": "too_few_anchors"}),
                 MSGPACK, 9.0)
    items = model.take()
    assert items[0] == {"kind": "range", "observer": "ssv", "peer": "gcv", "range_m": 38.2,
                        "time": 7.0, "method": "dlbl"}
    assert items[1]["kind"] == "position" and items[1]["source"] == "fix"
    assert (items[1]["node"], items[1]["sigma_m"]) == ("lsv", 0.3)
    assert len(items) == 2


def test_events_stream_replaces_counter_deltas(morph):
    model = GuiModel(morph, "ssv")
    base = {"time": 0.0, "frames_dropped": {}, "send_errors": 0}
    model.ingest("@zab/morph/ssv/stats", pack(base), MSGPACK, 0.0)
    model.ingest("@zab/morph/ssv/events", pack({"kind": "frame_dropped", "node": "ssv",
                                                "src": "cv2", "reason": "forged",
                                                "data": b"\x00" * 40}), MSGPACK, 1.0)
    model.ingest("@zab/morph/ssv/events", pack({"kind": "modem_down", "node": "ssv",
                                                "error": "/dev/ttyUSB0 gone"}), MSGPACK, 1.5)
    model.ingest("@zab/morph/ssv/stats", pack({**base, "frames_dropped": {"forged": 1}}),
                 MSGPACK, 2.0)
    events = [i for i in model.take() if i["kind"] == "event"]
    assert [(e["level"], e["category"]) for e in events] == [("warn", "frame"),
                                                            ("error", "driver")]
    assert "from cv2" in events[0]["text"] and "authentication" in events[0]["text"]
    assert "/dev/ttyUSB0 gone" in events[1]["text"]


def test_transfers_log_when_they_end(morph):
    model = GuiModel(morph, "ssv")
    report = {"channel": "image", "peer": "gcv", "id": 4, "fragments_done": 3,
              "fragments_total": 9, "bytes": 300, "state": "receiving", "time": 1.0}
    model.ingest("@zab/morph/ssv/transfer/image", pack(report), MSGPACK, 1.0)
    model.ingest("@zab/morph/ssv/transfer/image", pack({**report, "state": "failed"}),
                 MSGPACK, 2.0)
    items = model.take()
    assert [i["state"] for i in items if i["kind"] == "transfer"] == ["receiving", "failed"]
    (event,) = [i for i in items if i["kind"] == "event"]
    assert "3/9 fragments" in event["text"] and event["level"] == "error"
    assert len([i for i in model.snapshot() if i["kind"] == "transfer"]) == 1


def test_snapshot_rebuilds_what_the_items_said(morph):
    model = GuiModel(morph, "ssv")
    model.ingest("cv2/nav", pack({"x": 1.0, "y": 2.0, "depth": 3.0, "heading": 4,
                                  "speed": 0.5}), MSGPACK, 1.0)
    model.ingest("@zab/morph/ssv/link/cv2", pack({"state": "up", "silent_s": 0.5}),
                 MSGPACK, 1.0)
    live = model.take()
    snapshot = model.snapshot()
    assert {json.dumps(i, sort_keys=True) for i in live} <= {
        json.dumps(i, sort_keys=True) for i in snapshot}
    json.dumps(snapshot, allow_nan=False)  # ready for the websocket as it is


def test_shown_values_are_small_and_json_safe():
    assert shown(b"\x01\x02") == "0102"
    assert shown(bytes(100)).endswith("(100 B)")
    assert shown(float("nan")) is None
    assert len(shown(list(range(1000)))) == 65
    assert shown({"a": {"b": (1, 2)}}) == {"a": {"b": [1, 2]}}


def test_links_by_kind_each_peers_route_and_a_relays_load() -> None:
    loaded = load_mission(MISSIONS / "umci_relay.yaml")
    model = GuiModel(loaded, "surface")
    description = model.description()
    assert [(link["name"], link["kind"], link["members"]) for link in description["links"]] \
        == [("acoustic", "acoustic", ["surface", "rov1", "rov2"]), ("rf", "rf", ["rov1", "rov2"])]
    assert description["routes"]["rov2"]["path"] == ["surface", "rov1", "rov2"]
    assert description["routes"]["rov1"]["path"] == ["surface", "rov1"]
    prefix = "@zab/umci_relay"
    model.ingest(f"{prefix}/rov1/links/rf/rov2", pack({"peer": "rov2", "link": "rf",
                                                        "state": "up"}), MSGPACK, 10.0)
    model.ingest(f"{prefix}/rov1/links/rf/rov2", pack({"state": "up"}), MSGPACK, 11.0)  # no news
    model.ingest(f"{prefix}/rov2/route/surface", pack({"peer": "surface", "link": "acoustic",
                                                        "was": "rf", "via": "rov1",
                                                        "reason": "failover"}), MSGPACK, 12.0)
    model.ingest(f"{prefix}/rov1/stats", pack({"node": "rov1", "time": 12.0, "network": {
        "relayed": 41, "waiting": {"acoustic": 2, "rf": 0}}}), MSGPACK, 13.0)
    items = model.take()
    hops = [i for i in items if i["kind"] == "hop"]
    assert [(h["observer"], h["link"], h["peer"], h["state"]) for h in hops] == [
        ("rov1", "rf", "rov2", "up")]
    [route] = [i for i in items if i["kind"] == "route"]
    assert (route["observer"], route["peer"], route["link"], route["reason"]) == (
        "rov2", "surface", "acoustic", "failover")
    [stats] = [i for i in items if i["kind"] == "stats"]
    assert stats["relayed"] == 41 and stats["carrying"] == {"acoustic": 2, "rf": 0}
    assert {"hop", "route"} <= set(kinds(model.snapshot()))


def test_the_log_says_links_per_link_and_switches_in_words() -> None:
    from bridge.gui.eventlog import describe_event

    up = describe_event("rov1", {"kind": "peer_link", "peer": "rov2", "link": "rf",
                                 "state": "down"})
    assert up is not None and (up.level, up.text) == ("error", "link rov1 ↔ rov2 over rf: down")
    moved = describe_event("rov2", {"kind": "link_switched", "peer": "surface",
                                    "link": "acoustic", "was": "rf", "reason": "failover"})
    assert moved is not None and moved.text == \
        "rov2: traffic to surface over acoustic (failover from rf)"


def test_a_third_bridge_s_copy_of_a_value_is_not_an_arrival(morph):
    """cv2 surfaced: its Zenoh joined ssv's, so what cv2's bridge heard and published (the
    gcv's nav) reaches the GUI too, beside ssv's own copy; cv2's own values over IP count."""
    model = GuiModel(morph, "ssv")
    nav = pack({"x": 20.0, "y": 30.0, "depth": 12.0, "heading": 0, "speed": 1.0})
    model.ingest("gcv/nav", nav, MSGPACK, 100.0, "ssv")
    model.ingest("gcv/nav", nav, MSGPACK, 100.01, "cv2")  # cv2's copy
    model.ingest("cv2/nav", nav, MSGPACK, 100.02, "cv2")  # over IP
    model.ingest("gcv/nav", nav, MSGPACK, 107.5, "ssv")
    channels = [i for i in model.take() if i["kind"] == "channel"]
    gcv = [c for c in channels if c["node"] == "gcv"]
    assert [c["interval_s"] for c in gcv] == [None, 7.5] and gcv[-1]["count"] == 2
    assert [c["node"] for c in channels if c["node"] == "cv2"] == ["cv2"]


def test_events_read_as_sentences(morph):
    from bridge.gui.eventlog import describe_event

    up = describe_event("ssv", {"kind": "surfaced", "peer": "cv2", "ip": True, "time": 1.0})
    down = describe_event("ssv", {"kind": "surfaced", "peer": "cv2", "ip": False, "time": 2.0})
    assert up is not None and up.text == ("ssv: cv2 reached over IP (one of them surfaced): "
                                          "channels between them no longer cross the water")
    assert down is not None and down.text == ("ssv: cv2 no longer reached over IP (dived): "
                                              "channels between them cross the water again")
    restarted = describe_event("ssv", {"kind": "peer_restarted", "peer": "gcv", "epoch": 3,
                                       "was": 2, "time": 3.0})
    assert restarted is not None and restarted.level == "warn"
    assert restarted.text == "ssv: gcv restarted without its saved state (epoch 2 → 3)"
    other = describe_event("ssv", {"kind": "mission_mismatch", "peer": "lsv",
                                   "fingerprint": "ab", "ours": "cd", "time": 4.0})
    assert other is not None and "lsv runs another mission file" in other.text
    down = describe_event("ssv", {"kind": "modem_down", "error": "pty gone", "time": 5.0})
    assert down is not None and down.level == "error"
    assert down.text == "ssv: modem unavailable: pty gone (retrying)"
    back = describe_event("ssv", {"kind": "modem_up", "down_s": 42.3, "retries": 5,
                                  "time": 47.3})
    assert back is not None and back.level == "info"
    assert back.text == "ssv: modem back after 42.3 s (5 retries)"


def test_a_node_nobody_answers_for_is_said_plainly(morph):
    from bridge.gui.server import unreachable

    zenoh_says = ("Unable to connect to any of [Single(tcp/127.0.0.1:7501)]! at "
                  "/root/.cargo/git/checkouts/zenoh/src/net/runtime/orchestrator.rs:447.")
    assert unreachable(zenoh_says, "ssv", ["tcp/127.0.0.1:7501"]) == (
        "nothing answers at tcp/127.0.0.1:7501: is ssv's bridge running (zab run, zab sim or "
        "zab demo)?")
    assert unreachable("no route to the node", "ssv", []) == "no route to the node"


def test_a_ros2_topic_s_cdr_samples_are_read_by_its_type(mission_key: str) -> None:
    """ros2_odometry at the ship: the bridge publishes the Odometry as CDR on its rmw_zenoh
    key; the GUI read every sample as msgpack and counted it unreadable, so no ROS 2 value
    ever showed. A malformed one is still a counted drop."""
    loaded = load_mission(MISSIONS / "ros2_odometry.yaml")
    odom = loaded.table.by_name("odom").elements[0]
    assert odom.ros2 is not None
    key = odom.output_key("auv1", "ship")
    model = GuiModel(loaded, "ship")
    value = {"pose": {"pose": {"position": {"x": 12.5, "y": -3.0, "z": -20.0}}}}
    model.ingest(key, odom.ros2.encode(value, 100.0), "", 5.0)
    (item,) = model.take()
    assert item["node"] == "auv1" and item["value"]["pose"]["pose"]["position"]["x"] == 12.5
    assert item["value"]["child_frame_id"] == "auv1/base_link"
    model.ingest(key, b"\x00\x01\x00\x00\x07", "", 6.0)
    assert any("malformed CDR" in str(i.get("text", "")) for i in model.take())
