"""ROS 2 elements in a mission: located errors, and the core's input and output paths."""

from __future__ import annotations

import pytest
from rosbags.typesys import Stores, get_typestore

from bridge.core.events import PayloadDrops
from bridge.core.loaded import parse_mission
from bridge.core.node import NodeCore, Publish
from bridge.errors import MissionError
from bridge.modems.base import Reception
from tests.conftest import MISSIONS
from tests.ros2.test_messages import GOLDEN, ODOM, odometry

JAZZY = get_typestore(Stores.ROS2_JAZZY)
ODOM_KEY = "0/auv1/odom/nav_msgs::msg::dds_::Odometry_/" + GOLDEN[ODOM]

MISSION = """\
mission: rostest
nodes:
  ship: {address: 1, role: surface}
  auv1: {address: 2}
channels:
  - name: odom
    from: auv1
    to: ship
    elements:
      - ros2:
          topic: /auv1/odom
          type: nav_msgs/msg/Odometry
          defaults: {header.frame_id: odom}
        fields:
          - {field: pose.pose.position.x, min: -100, max: 100, resolution: 0.01}
          - {field: pose.pose.position.y, min: -100, max: 100, resolution: 0.01}
"""


def load(text: str = MISSION):
    return parse_mission(text, "rostest.yaml")


def error_of(old: str, new: str) -> str:
    assert old in MISSION
    with pytest.raises(MissionError) as caught:
        load(MISSION.replace(old, new))
    return str(caught.value)


def test_the_example_mission_loads() -> None:
    loaded = parse_mission((MISSIONS / "ros2_odometry.yaml").read_text(), "ros2_odometry.yaml")
    element = loaded.table.by_name("odom").elements[0]
    assert element.ros2 is not None and element.in_key == "0/auv1/odom/*/*"
    assert element.output_key("auv1", "ship") == ODOM_KEY


@pytest.mark.parametrize(("old", "new", "expected"), [
    ("type: nav_msgs/msg/Odometry", "type: nav_msgs/msg/Odometri",
     "rostest.yaml:12:11: channels[0].elements[0].ros2.type: 'nav_msgs/msg/Odometri' is not a "
     "message type of ROS 2 jazzy; did you mean nav_msgs/msg/Odometry"),
    ("type: nav_msgs/msg/Odometry", "type: Odometry",
     "rostest.yaml:12:11: channels[0].elements[0].ros2.type: 'Odometry' is not a ROS 2 message "
     "type like nav_msgs/msg/Odometry"),
    ("pose.pose.position.y", "pose.pose.place.y",
     "rostest.yaml:16:14: channels[0].elements[0].fields[1].field: pose.pose.place.y: "
     "geometry_msgs/msg/Pose has no field 'place'"),
    ("{header.frame_id: odom}", "{header.frame_id: 7}",
     "channels[0].elements[0].ros2.defaults.header.frame_id: header.frame_id: expected a "
     "string, got int"),
    ("{header.frame_id: odom}", "{header.frame: odom}",
     "std_msgs/msg/Header has no field 'frame'"),
    ("topic: /auv1/odom", "topic: auv1/odom", "a ROS 2 topic here is absolute"),
    ("topic: /auv1/odom", "topic: /{dst}/odom", "unknown template {dst}"),
    ("{field: pose.pose.position.x, min: -100, max: 100, resolution: 0.01}",
     "{field: header.frame_id, min: 0, max: 1, bits: 4}",
     "header.frame_id is a string in nav_msgs/msg/Odometry; a float field cannot carry it"),
    ("{field: pose.pose.position.x, min: -100, max: 100, resolution: 0.01}",
     "{field: pose.covariance, min: 0, max: 1, bits: 4, count: 9}",
     "pose.covariance holds exactly 36 values in nav_msgs/msg/Odometry, not count 9"),
    ("      - ros2:", "      - in: odom\n        ros2:",
     "leave out `in` and `out`"),
    ("      - ros2:", "      - encoding: json\n        ros2:",
     "rostest.yaml:10:9: channels[0].elements[0]: a `ros2` element's payloads are "
     "CDR: leave out `encoding`"),
])
def test_bad_ros2_elements_are_located_check_errors(old: str, new: str, expected: str) -> None:
    assert expected in error_of(old, new)


def test_an_element_without_keys_or_topic_is_refused() -> None:
    text = MISSION.replace("      - ros2:", "      - encoding: json\n        nothing:")
    text = text.replace("        nothing:\n", "").replace("          topic: /auv1/odom\n", "")
    text = text.replace("          type: nav_msgs/msg/Odometry\n", "")
    text = text.replace("          defaults: {header.frame_id: odom}\n", "")
    with pytest.raises(MissionError, match="an element needs `in` and `out` keys"):
        load(text)


def test_malformed_cdr_and_unknown_types_are_counted_drops(caplog) -> None:
    core = NodeCore(load(), "auv1")
    listen = "0/auv1/odom/*/*"
    assert list(core.bindings) == [listen]
    core.ingest(listen, b"\x00\x01\x00\x00\x01", "", 1.0, sample_key=ODOM_KEY)
    core.ingest(listen, odometry(), "", 2.0,
                sample_key="0/auv1/odom/geometry_msgs::msg::dds_::PoseStamped_/RIHS01_" + "1" * 64)
    assert core.stats.payloads_dropped[listen] == 2
    reasons = [reason for o in core.take() if isinstance(o, PayloadDrops)
               for _, _, _, reason in o.drops]
    assert "malformed CDR for nav_msgs/msg/Odometry" in reasons[0]
    assert "unknown ROS 2 type geometry_msgs/msg/PoseStamped on /auv1/odom" in reasons[1]
    assert "dropped a payload on '0/auv1/odom/*/*': malformed CDR" in caplog.text
    core.ingest(listen, odometry(x=3.21), "", 3.0, sample_key=ODOM_KEY)
    assert core.stats.payloads_dropped[listen] == 2
    assert core.store.next_due(3.0) is not None


def test_a_value_crosses_from_core_to_core_as_a_complete_message() -> None:
    loaded = load()
    auv, ship = NodeCore(loaded, "auv1"), NodeCore(loaded, "ship")
    auv.ingest("0/auv1/odom/*/*", odometry(x=-12.344), "", 1.0, sample_key=ODOM_KEY)
    frame = auv.outbound.build(1.0, 1.0)
    assert frame is not None
    ship.receive(Reception(frame.data, 2, 1.5), 1.5)
    (out,) = [o for o in ship.take() if isinstance(o, Publish)]
    assert out.key == ODOM_KEY and out.ros2 is not None
    msg = JAZZY.deserialize_cdr(out.ros2.encode(out.value, 1.5), ODOM)
    assert msg.pose.pose.position.x == pytest.approx(-12.344, abs=0.005)
    assert msg.pose.pose.position.y == pytest.approx(-5.5, abs=0.005)
    assert msg.header.frame_id == "odom" and msg.child_frame_id == ""
