"""Commands from the GUI: forms from the mission, checks, and pending → sent/delivered/failed."""

from __future__ import annotations

import msgpack
import pytest
import yaml

from bridge.core.loaded import LoadedMission, load_mission, parse_mission
from bridge.errors import MissionError
from bridge.gui.commands import Command, CommandBook, CommandError, command_channels
from bridge.gui.model import GuiModel
from tests.conftest import MISSIONS


@pytest.fixture(scope="module")
def morph() -> LoadedMission:
    return load_mission(MISSIONS / "morph.yaml")


def report(ref: str, state: str, dst: str = "gcv", reason: str | None = None) -> bytes:
    return msgpack.packb({"channel": "mission_command", "id": 1, "dst": dst, "state": state,
                          "reason": reason, "attempts": 1, "time": 0.0, "key": "command",
                          "ref": ref})


def test_command_channels_are_what_the_node_sends_to_others(morph):
    channels = {c.channel: c for c in command_channels(morph, "ssv")}
    assert set(channels) == {"surface_fix", "mission_command"}
    command = channels["mission_command"]
    assert command.destinations == ("gcv", "lsv", "cv1", "cv2")
    assert not command.reliable
    (element,) = command.elements
    assert element.key == "command"
    action, leg = element.fields
    assert (action.kind, action.values) == ("enum", ("none", "start", "hold", "resume",
                                                     "surface", "abort"))
    assert (leg.kind, leg.minimum, leg.maximum) == ("integer", 0, 63)
    # a plug-in codec's bounds come from its own schema
    lat = channels["surface_fix"].elements[0].fields[0]
    assert (lat.path, lat.kind, lat.minimum, lat.maximum) == ("lat", "number", -90, 90)
    # joined at a vehicle, the GUI could send what that vehicle sends
    assert {c.channel for c in command_channels(morph, "cv1")} == {"nav", "status"}


def test_reliable_channels_come_first_when_the_mission_has_them(morph):
    data = yaml.safe_load((MISSIONS / "morph.yaml").read_text())
    channel = next(c for c in data["channels"] if c["name"] == "mission_command")
    channel.update(reliable=True, latching=False)
    try:
        loaded = parse_mission(yaml.safe_dump(data, sort_keys=False), "reliable.yaml")
    except MissionError as exc:
        if "unknown key" not in str(exc):
            raise
        pytest.skip("this mission model has no reliable channels yet")
    first = command_channels(loaded, "ssv")[0]
    assert (first.channel, first.reliable) == ("mission_command", True)


def test_a_command_becomes_the_payload_on_the_input_key(morph):
    model = GuiModel(morph, "ssv")
    puts = model.command({"channel": "mission_command", "vehicle": "lsv",
                          "values": {"action": "hold", "leg": "12"}}, "r1", 10.0)
    assert puts == [("command", msgpack.packb({"action": "hold", "leg": 12}),
                     "application/msgpack")]
    (item,) = model.take()
    assert (item["kind"], item["ref"], item["state"], item["vehicle"]) == (
        "command", "r1", "pending", "lsv")


@pytest.mark.parametrize(("request_", "message"), [
    ({"channel": "nav", "vehicle": "gcv", "values": {}}, "sends no channel 'nav'"),
    ({"channel": "mission_command", "vehicle": "ssv", "values": {}}, "does not reach 'ssv'"),
    ({"channel": "mission_command", "vehicle": "gcv", "values": {"action": "start"}},
     "'leg' is missing"),
    ({"channel": "mission_command", "vehicle": "gcv",
      "values": {"action": "start", "leg": 64}}, "above the maximum 63"),
    ({"channel": "mission_command", "vehicle": "gcv",
      "values": {"action": "start", "leg": 1.5}}, "not a whole number"),
    ({"channel": "mission_command", "vehicle": "gcv",
      "values": {"action": "jump", "leg": 1}}, "not one of none, start"),
    ({"channel": "mission_command", "vehicle": "gcv",
      "values": {"action": "start", "leg": 1, "speed": 2}}, "unknown field 'speed'"),
    ({"channel": "mission_command", "vehicle": "gcv",
      "values": {"action": "start", "leg": "nan"}}, "not a finite number"),
    ({"channel": "mission_command", "vehicle": "gcv", "values": "start"}, "1 element"),
    ({"channel": "mission_command", "vehicle": "gcv",  # (OverflowError, the socket closed)
      "values": {"action": "start", "leg": 10 ** 400}}, "not a finite number"),
    ({"channel": "surface_fix", "vehicle": "gcv", "values": {"lat": -91, "lon": 3}},
     "below the minimum -90"),
])
def test_a_wrong_command_is_refused_with_a_reason(morph, request_, message):
    model = GuiModel(morph, "ssv")
    with pytest.raises(CommandError, match=message):
        model.command(request_, "r", 0.0)
    assert model.take() == []


def test_a_command_on_a_key_family_goes_to_the_vehicle_s_member_key():
    """zspace's fleet_depth has a member per AUV (keys: {nodes: auv.*}): the GUI put the
    command on the family's expression (fleet/*/depth_order), which the bridge counts as naming
    no member and never sends, while the page showed it sent."""
    model = GuiModel(load_mission(MISSIONS / "zspace.yaml"), "top")
    puts = model.command({"channel": "fleet_depth", "vehicle": "auv2",
                          "values": {"depth_m": 10}}, "r1", 0.0)
    assert puts == [("fleet/auv2/depth_order", msgpack.packb({"depth_m": 10.0}),
                     "application/msgpack")]


def test_best_effort_commands_count_as_sent_after_a_while(morph):
    model = GuiModel(morph, "ssv")
    model.command({"channel": "mission_command", "vehicle": "gcv",
                   "values": {"action": "start", "leg": 1}}, "r1", 100.0)
    model.take()
    model.tick(101.0)
    assert model.take() == []
    model.tick(100.0 + model.book.sent_after_s)
    (item,) = model.take()
    assert (item["ref"], item["state"]) == ("r1", "sent")


def test_delivery_reports_with_our_ref_settle_the_command(morph):
    model = GuiModel(morph, "ssv")
    for ref in ("ok", "bad"):
        model.command({"channel": "mission_command", "vehicle": "gcv",
                       "values": {"action": "start", "leg": 1}}, ref, 0.0)
    key = "@zab/morph/ssv/delivery/mission_command"
    model.ingest(key, report("ok", "queued"), "application/msgpack", 0.5)
    model.ingest(key, report("ok", "delivered", dst="lsv"), "application/msgpack", 1.0)
    model.ingest(key, report("ok", "delivered"), "application/msgpack", 2.0)
    model.ingest(key, report("bad", "failed", reason="ttl"), "application/msgpack", 3.0)
    model.ingest(key, report("someone-else", "failed"), "application/msgpack", 4.0)
    book = model.book.commands
    assert (book["ok"].state, book["ok"].detail, book["ok"].others) == (
        "delivered", "queued", {"lsv": "delivered"})
    assert (book["bad"].state, book["bad"].reason) == ("failed", "ttl")
    events = [i["text"] for i in model.take() if i["kind"] == "event"]
    assert len(events) == 2 and all("failed" in t for t in events)  # ours and theirs


def test_the_book_forgets_the_oldest_commands():
    book = CommandBook(size=2)
    for i in range(3):
        book.add(Command(f"r{i}", "gcv", "c", {}, False, float(i)))
    assert list(book.commands) == ["r1", "r2"]
    assert book.report({"ref": "r0", "state": "delivered"}, 5.0) is None


def test_form_fields_show_the_units_the_mission_declares(morph):
    text = (MISSIONS / "morph.yaml").read_text()
    data = yaml.safe_load(text)
    channel = next(c for c in data["channels"] if c["name"] == "mission_command")
    channel["elements"][0]["fields"][1]["units"] = "legs"
    loaded = parse_mission(yaml.safe_dump(data, sort_keys=False))
    command = next(c for c in command_channels(loaded, "ssv") if c.channel == "mission_command")
    action, leg = command.elements[0].fields
    assert (action.units, leg.units) == (None, "legs")
    assert loaded.table.fingerprint == morph.table.fingerprint  # units are not on the wire


def test_the_form_opens_on_a_channel_named_as_a_command(morph):
    """Without an acknowledged channel, the command channel comes before a sensor value (the
    surface's GPS fix), whatever their order in the mission."""
    assert [c.channel for c in command_channels(morph, "ssv")] == [
        "mission_command", "surface_fix"]


def test_a_command_on_a_ros2_topic_is_its_cdr_on_the_publisher_s_key(mission_key: str) -> None:
    """ros2_odometry's cmd_vel from the GUI went as msgpack on the topic's key expression
    (0/auv1/cmd_vel_remote/*/*), and the bridge dropped it ('unknown ROS 2 type *'): it
    goes as the Twist's CDR on the key a ROS 2 publisher of the topic uses at the node."""
    from bridge.runtime.virtual_fleet import FastFleet

    loaded = load_mission(MISSIONS / "ros2_odometry.yaml")
    model = GuiModel(loaded, "ship")
    values = {"linear.x": "0.5", "linear.z": "0", "angular.z": "0.1"}
    ((key, payload, encoding),) = model.command(
        {"channel": "cmd_vel", "vehicle": "auv1", "values": values}, "r1", 10.0)
    assert "*" not in key and key.startswith("0/auv1/cmd_vel_remote/geometry_msgs::msg::dds_::")
    assert isinstance(payload, bytes) and encoding == ""
    core = FastFleet(loaded, seed=1).cores["ship"]
    taken = next(k for k in core.bindings if core.ros2_input(k) is not None)
    core.ingest(taken, payload, encoding, 10.0, sample_key=key)
    assert not core.stats.payloads_dropped
