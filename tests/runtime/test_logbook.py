"""Mission logs: a real fleet records MCAP files; summary and replay read them back."""

from __future__ import annotations

import json
import math
import queue
import subprocess
import sys
import time
from pathlib import Path

import jsonschema
import pytest
import zenoh
from mcap.reader import make_reader
from typer.testing import CliRunner

from bridge.cli.app import app
from bridge.core.events import Event
from bridge.core.loaded import load_mission
from bridge.image.formats import write_image
from bridge.image.synthetic import seabed
from bridge.runtime.logbook import FleetLogs, LogError, read_log, replay, summarise
from bridge.runtime.virtual_fleet import FastFleet, Timed
from tests.conftest import MISSIONS, REPO, free_port, on_free_ports, udp_ports
from tests.harness import Inbox, outside_session, put, running_fleet

RUNNER = CliRunner()

LAB = """\
mission: loglab
modem: {backend: udp, frame_bytes: 48}
mac: {type: none, min_gap_s: 0.05}
nodes:
  a: {address: 1, modem: {options: {port: PORT_A}}}
  b: {address: 2, modem: {options: {port: PORT_B}}}
channels:
  - name: status
    from: a
    to: b
    elements:
      - in: status
        out: "{src}/status"
        fields:
          - {field: depth, resolution: 0.5, min: 0, max: 300}
          - {field: mode, values: [idle, survey, home]}
          - {field: tag, type: bytes, length: 2}
  - name: command
    from: b
    to: a
    elements: [{in: command, out: "{src}/command", encoding: json,
                fields: [{field: go, type: bool}]}]
"""

VALUES = [{"depth": 10.0 + i, "mode": "survey", "tag": bytes([i, 255 - i])} for i in range(4)]


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """Run a two-node fleet with logs on: four status values a→b, one command b→a."""
    folder = tmp_path_factory.mktemp("logs")
    text = udp_ports(LAB)
    loaded = on_free_ports(text, "loglab.yaml")
    logs = FleetLogs(folder, loaded)
    with running_fleet(loaded, on_event=logs) as fleet:
        a_app, b_app = outside_session(loaded, "a"), outside_session(loaded, "b")
        try:
            inbox = Inbox()
            b_app.declare_subscriber("a/status", inbox)
            time.sleep(0.3)
            received = []
            for value in VALUES:
                put(a_app, "status", value)
                received.append(inbox.get(timeout=10)[1])
            put(b_app, "command", {"go": True})
            deadline = time.time() + 10
            while fleet.nodes["a"].stats.received_per_channel["command"] < 1:
                assert time.time() < deadline, "command never arrived"
                time.sleep(0.05)
        finally:
            a_app.close()
            b_app.close()
        stats = {n: node.stats for n, node in fleet.nodes.items()}
    logs.close()
    return {"loaded": loaded, "logs": logs, "received": received, "stats": stats,
            "folder": folder}


def test_every_frame_is_logged_with_raw_bytes_metadata_and_values(recorded: dict) -> None:
    b = read_log(recorded["logs"].path_of("b"))
    assert b.node == "b" and b.loaded is not None and b.loaded.mission.mission == "loglab"
    assert b.loaded.table.fingerprint == recorded["loaded"].table.fingerprint
    frames = [r for r in b.records if r.kind == "frame_received"]
    status = [f for f in frames if "status" in f.data["values"]]
    assert len(status) == recorded["stats"]["b"].received_per_channel["status"] == len(VALUES)
    for frame, value in zip(status, recorded["received"], strict=True):
        assert frame.data["src"] == "a"
        assert bytes.fromhex(frame.data["data_hex"]) and frame.data["bytes"] == len(
            bytes.fromhex(frame.data["data_hex"]))
        assert isinstance(frame.data["meta"], dict)
        [element] = frame.data["values"]["status"]
        assert element["depth"] == value["depth"] and element["mode"] == value["mode"]
        assert bytes.fromhex(element["tag"]) == value["tag"]
    a = read_log(recorded["logs"].path_of("a"))
    sent = [r for r in a.records if r.kind == "frame_sent"]
    assert len(sent) == recorded["stats"]["a"].frames_sent
    assert sum("status" in r.data["channels"] for r in sent) == len(VALUES)


def test_every_message_matches_its_topic_schema(recorded: dict) -> None:
    """What Foxglove needs: JSON messages, each topic with a JSON Schema they satisfy."""
    for node in ("a", "b"):
        with recorded["logs"].path_of(node).open("rb") as stream:
            reader = make_reader(stream)
            topics = set()
            for schema, channel, message in reader.iter_messages():
                assert channel.message_encoding == "json" and schema is not None
                assert schema.encoding == "jsonschema"
                document = json.loads(schema.data)
                jsonschema.Draft202012Validator.check_schema(document)
                jsonschema.validate(json.loads(message.data), document)
                topics.add(channel.topic)
        assert f"/zab/{node}/frame_sent" in topics and f"/zab/{node}/frame_received" in topics
        assert f"/zab/{node}/channel/{'status' if node == 'b' else 'command'}" in topics


def test_summary_counts_channels_and_ages(recorded: dict) -> None:
    data = summarise(read_log(recorded["logs"].path_of("b")))
    status = data["channels"]["status"]
    assert status["received"] == len(VALUES) and status["from"] == ["a"]
    assert status["sent"] == 0 and data["channels"]["command"]["sent"] == 1
    assert 0 <= status["age_s"] <= data["duration_s"]
    assert data["events"]["frame_received"] == recorded["stats"]["b"].frames_received
    result = RUNNER.invoke(app, ["log", "summary", str(recorded["logs"].path_of("b"))])
    assert result.exit_code == 0, result.output
    assert "status" in result.output and "command" in result.output


def test_replay_republishes_the_decoded_values(recorded: dict) -> None:
    port = free_port()
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    config.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(config)
    try:
        inbox = Inbox()
        session.declare_subscriber("a/status", inbox)
        got_json: list[dict] = []
        session.declare_subscriber("b/command", lambda s: got_json.append(
            {"encoding": str(s.encoding), "value": json.loads(s.payload.to_bytes())}))
        log = recorded["logs"].path_of("b")
        result = subprocess.run(
            [sys.executable, "-m", "bridge", "log", "replay", str(log), "--speed", "20",
             "--connect", f"tcp/127.0.0.1:{port}", "--wait", "0.5"],
            capture_output=True, text=True, timeout=60, cwd=REPO)
        assert result.returncode == 0, result.stderr
        assert f"published {len(VALUES)} values" in result.stdout
        replayed = [inbox.get(timeout=5) for _ in VALUES]
        assert [v for _, v, _ in replayed] == recorded["received"]  # bytes restored too
        assert not got_json  # b's log holds what b received (status), not what it sent
        a_log = recorded["logs"].path_of("a")
        result = subprocess.run(
            [sys.executable, "-m", "bridge", "log", "replay", str(a_log), "--speed", "0",
             "--connect", f"tcp/127.0.0.1:{port}", "--wait", "0.5"],
            capture_output=True, text=True, timeout=60, cwd=REPO)
        assert result.returncode == 0, result.stderr
        deadline = time.time() + 5
        while not got_json and time.time() < deadline:
            time.sleep(0.05)
        assert got_json == [{"encoding": "application/json", "value": {"go": True}}]
    finally:
        session.close()


def test_a_file_that_is_not_a_mission_log_is_refused(tmp_path: Path) -> None:
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file at all")
    with pytest.raises(LogError, match="not a readable MCAP"):
        read_log(junk)
    result = RUNNER.invoke(app, ["log", "summary", str(tmp_path / "missing.mcap")])
    assert result.exit_code == 2 and "no such file" in result.output


SIM = """\
mission: simlog
modem: {backend: sim, frame_bytes: 32, options: {preset: evologics-s2c-im}}
mac: {type: tdma, slot_s: 0.5, guard_s: 0.1, order: [a, b]}
link: {heartbeat_s: 0.5}
nodes:
  a: {address: 1, position: {x: 0, y: 0, depth: 1}}
  b: {address: 2, position: {x: 100, y: 0, depth: 5}}
channels:
  - name: ping
    from: a
    to: b
    elements: [{in: ping, out: "{src}/ping", fields: [{field: n, type: int, min: 0, max: 9}]}]
"""


def test_zab_sim_log_writes_one_file_per_node(tmp_path: Path) -> None:
    loaded = on_free_ports(SIM, "simlog.yaml")
    mission = tmp_path / "simlog.yaml"
    mission.write_text(json.dumps(loaded.mission.model_dump(by_alias=True, mode="json",
                                                            exclude_unset=True)))
    result = subprocess.run(
        [sys.executable, "-m", "bridge", "sim", str(mission), "--duration", "5", "--no-live",
         "--log", str(tmp_path / "logs")], capture_output=True, text=True, timeout=60, cwd=REPO)
    assert result.returncode == 0, result.stderr
    for node, peer in (("a", "b"), ("b", "a")):
        data = summarise(read_log(tmp_path / "logs" / f"simlog-{node}.mcap"))
        assert data["events"]["frame_sent"] >= 2  # heartbeats in its TDMA slots
        assert data["events"]["frame_received"] >= 1
        assert data["node"] == node and data["mission"] == "simlog", peer


@pytest.fixture(scope="module")
def camera_logs(tmp_path_factory: pytest.TempPathFactory) -> tuple[FastFleet, FleetLogs]:
    """bluerov_images on the virtual clock with logs on: one picture crosses whole, and the
    operator sets a budget for the next."""
    loaded = load_mission(MISSIONS / "bluerov_images.yaml")
    logs = FleetLogs(tmp_path_factory.mktemp("camera"), loaded)

    def record(timed: Timed) -> None:
        if isinstance(timed.output, Event):
            logs(timed.node, timed.output)

    fleet = FastFleet(loaded, seed=1, on_output=record)
    fleet.put("rov", "rov/camera", write_image(seabed(120, 160, seed=1, colour=False), "jpeg"),
              encoding="image/jpeg", at=1.0)
    fleet.put("operator", "camera/control", {"budget_bytes": 800}, at=2.0)
    fleet.run_until(40.0)
    logs.close()
    return fleet, logs


def test_a_camera_s_fragments_count_as_its_channel_s_receptions(
        camera_logs: tuple[FastFleet, FleetLogs]) -> None:
    """`zab log summary` at the operator of bluerov_images listed no channel at all: a
    picture's fragments are no values, and only values were counted."""
    fleet, logs = camera_logs
    operator = summarise(read_log(logs.path_of("operator")))["channels"]
    fragments = fleet.cores["operator"].stats.received_per_channel["camera"]
    assert fragments >= 1591 // 37  # (the whole picture)
    assert operator["camera"]["received"] == fragments and operator["camera"]["from"] == ["rov"]
    rov = summarise(read_log(logs.path_of("rov")))["channels"]
    assert rov["camera"]["sent"] >= fragments
    assert rov["camera.control"]["received"] == 1 and operator["camera.control"]["sent"] >= 1


def test_replay_publishes_the_pictures_again(camera_logs: tuple[FastFleet, FleetLogs]) -> None:
    """`zab log replay` of an operator's log where a whole picture crossed published 0
    values: a picture is no value. Each one it published is in the log, and goes out again."""
    fleet, logs = camera_logs
    shown = [(p.key, p.value, p.encoding) for _, p in fleet.published("operator", "rov/camera")]
    assert len(shown) >= 10
    again: list[tuple[str, bytes, str]] = []
    count = replay(read_log(logs.path_of("operator")),
                   lambda key, payload, encoding: again.append((key, payload, encoding)),
                   speed=0)
    assert count == len(again) and again == shown  # the same files, in the same order
    assert b"zab:final\x00true" in again[-1][1]


def test_replay_publishes_ros2_topics_as_a_ros2_publisher_does(tmp_path: Path) -> None:
    """`zab log replay` of a ROS 2 mission put msgpack on rmw_zenoh's keys, with zab's own
    attachment: no ROS 2 node could read it. A plain app now gets CDR (read with rosbags)
    with rmw_zenoh's 33-byte attachment, which names a bridge publisher (so no live bridge
    sends it again), each message stamped as the ship first published it."""
    from rosbags.typesys import Stores, get_typestore

    from bridge.ros2.attachment import from_bridge
    from bridge.ros2.messages import type_hash

    loaded = load_mission(MISSIONS / "ros2_odometry.yaml")
    logs = FleetLogs(tmp_path, loaded)

    def record(timed: Timed) -> None:
        if isinstance(timed.output, Event):
            logs(timed.node, timed.output)

    fleet = FastFleet(loaded, seed=4, on_output=record)
    for i in range(5):
        fleet.put("auv1", "0/auv1/odom/*/*",
                  {"pose": {"pose": {"position": {"x": 10.0 * i, "y": -2.0, "z": -30.0}}}},
                  at=4.0 * i)
    fleet.run_until(25.0)
    logs.close()
    key = ("0/auv1/odom/nav_msgs::msg::dds_::Odometry_/"
           + type_hash("jazzy", "nav_msgs/msg/Odometry"))
    sent = fleet.published("ship", key)
    assert len(sent) >= 4
    typestore = get_typestore(Stores.ROS2_JAZZY)
    port = free_port()
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    config.insert_json5("scouting/multicast/enabled", "false")
    inbox: queue.Queue[tuple[str, bytes, bytes | None]] = queue.Queue()
    session = zenoh.open(config)
    try:
        session.declare_subscriber("0/auv1/odom/**", lambda s: inbox.put((
            str(s.key_expr), s.payload.to_bytes(),
            None if s.attachment is None else s.attachment.to_bytes())))
        result = subprocess.run(
            [sys.executable, "-m", "bridge", "log", "replay", str(logs.path_of("ship")),
             "--speed", "0", "--connect", f"tcp/127.0.0.1:{port}", "--wait", "0.5"],
            capture_output=True, text=True, timeout=60, cwd=REPO)
        assert result.returncode == 0, result.stderr
        assert f"published {len(sent)} values" in result.stdout
        got = [inbox.get(timeout=5) for _ in sent]
    finally:
        session.close()
    for (t, value), (got_key, payload, attachment) in zip(sent, got, strict=True):
        assert got_key == key and attachment is not None and len(attachment) == 33
        assert from_bridge(attachment)
        message = typestore.deserialize_cdr(payload, "nav_msgs/msg/Odometry")
        assert message.pose.pose.position.x == pytest.approx(
            value.value["pose"]["pose"]["position"]["x"])
        assert message.header.frame_id == "odom"
        assert message.header.stamp.sec + message.header.stamp.nanosec * 1e-9 == \
            pytest.approx(t, abs=1e-6)


def test_replay_publishes_a_ros2_camera_s_pictures_on_its_topic_too(tmp_path: Path) -> None:
    """With ``out_topic``, the operator published each picture twice, as a file and as a
    CompressedImage; replay does the same, from the one logged stream."""
    from bridge.core.loaded import parse_mission
    from bridge.ros2.messages import encode_cdr

    text = (MISSIONS / "bluerov_images.yaml").read_text().replace(
        "    in: rov/camera\n",
        "    ros2: {topic: /rov/camera, out_topic: '/{dst}/rov_camera/compressed'}\n").replace(
        "budget_bytes: 1600", "budget_bytes: 300")
    loaded = parse_mission(text)
    logs = FleetLogs(tmp_path, loaded)

    def record(timed: Timed) -> None:
        if isinstance(timed.output, Event):
            logs(timed.node, timed.output)

    fleet = FastFleet(loaded, seed=1, on_output=record)
    fleet.put("rov", "0/rov/camera/*/*", encode_cdr(
        "jazzy", "sensor_msgs/msg/CompressedImage",
        {"format": "jpeg", "data": write_image(seabed(120, 160, seed=1, colour=False), "jpeg")}),
        encoding="application/cdr", at=1.0)
    fleet.run_until(30.0)
    logs.close()
    shown = [(t, p.key, p.value) for t, p in fleet.published("operator")
             if p.key == "rov/camera" or p.ros2 is not None]
    assert len(shown) >= 8 and sum(1 for _, k, _ in shown if k == "rov/camera") == len(shown) / 2
    again: list[tuple[float, str, object]] = []
    count = replay(read_log(logs.path_of("operator")),
                   lambda key, payload, encoding: again.append((math.nan, key, payload)),
                   publish_ros2=lambda key, value, ros2, at: again.append((at, key, value)),
                   speed=0)
    assert count == len(shown)
    for (t, key, value), (at, key_again, value_again) in zip(shown, again, strict=True):
        assert key_again == key and value_again == value
        assert key == "rov/camera" or at == pytest.approx(t)
