"""A ROS 2 topic crosses the simulated ocean between two rmw_zenoh Zenoh spaces.

The outside sessions stand for ROS 2 nodes on rmw_zenoh: they use only ``zenoh`` and
``rosbags`` (to write and read CDR), and the keys, attachment and token layout of rmw_zenoh's
design document, written out here by hand.
"""

from __future__ import annotations

import queue
import struct
import time
from typing import Any

import numpy as np
import pytest
import zenoh
from rosbags.typesys import Stores, get_typestore

from tests.conftest import MISSIONS, mission_on_free_ports, on_free_ports, udp_ports
from tests.harness import outside_session, running_fleet

JAZZY = get_typestore(Stores.ROS2_JAZZY)
T = JAZZY.types
ODOM_HASH = "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0"
TWIST_HASH = "RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a"
ODOM_KEY = f"0/auv1/odom/nav_msgs::msg::dds_::Odometry_/{ODOM_HASH}"


class Raw:
    """Collects (key, payload, attachment, arrival time) of a subscriber."""

    def __init__(self) -> None:
        self.items: queue.Queue[tuple[str, bytes, bytes | None, float]] = queue.Queue()

    def __call__(self, sample: zenoh.Sample) -> None:
        attachment = sample.attachment.to_bytes() if sample.attachment is not None else None
        self.items.put((str(sample.key_expr), sample.payload.to_bytes(), attachment,
                        time.time()))

    def get(self, timeout: float) -> tuple[str, bytes, bytes | None, float]:
        return self.items.get(timeout=timeout)


def rmw_attachment(seq: int) -> bytes:
    """What rmw_zenoh attaches: int64 seq, int64 ns, LEB128 16, 16-byte GID (little-endian)."""
    return struct.pack("<qqB16s", seq, time.time_ns(), 16, b"\x42" * 16)


def odometry(x: float, y: float, z: float, qz: float, qw: float, vx: float, wz: float) -> bytes:
    msg = T["nav_msgs/msg/Odometry"](
        header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=1, nanosec=2),
                                        frame_id="auv1/odom_local"),
        child_frame_id="auv1/base_link",
        pose=T["geometry_msgs/msg/PoseWithCovariance"](
            pose=T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=x, y=y, z=z),
                orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=qz, w=qw)),
            covariance=np.full(36, 0.01)),
        twist=T["geometry_msgs/msg/TwistWithCovariance"](
            twist=T["geometry_msgs/msg/Twist"](
                linear=T["geometry_msgs/msg/Vector3"](x=vx, y=0.0, z=0.0),
                angular=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=wz)),
            covariance=np.full(36, 0.02)))
    return bytes(JAZZY.serialize_cdr(msg, "nav_msgs/msg/Odometry"))


def tokens(session: zenoh.Session) -> list[str]:
    return [str(r.ok.key_expr) for r in session.liveliness().get("@ros2_lv/0/**", timeout=2.0)
            if r.ok is not None]


def subscribe(session: zenoh.Session, key: str) -> Raw:
    inbox = Raw()
    session.declare_subscriber(key, inbox)
    time.sleep(0.3)  # let the declaration reach the bridge's session
    return inbox


def test_odometry_crosses_and_arrives_as_a_valid_rmw_zenoh_message() -> None:
    loaded = mission_on_free_ports(MISSIONS / "ros2_odometry.yaml")
    with running_fleet(loaded) as fleet:
        auv, ship = outside_session(loaded, "auv1"), outside_session(loaded, "ship")
        try:
            # ROS 2 graph, before any message: the bridge's node and publisher at the ship...
            ship_tokens = tokens(ship)
            assert any(t.endswith("/0/0/NN/%/%/zab_ship") for t in ship_tokens), ship_tokens
            assert any(t.endswith(f"/MP/%/%/zab_ship/%auv1%odom/nav_msgs::msg::dds_::Odometry_/"
                                  f"{ODOM_HASH}/::,:,:,:,,") for t in ship_tokens), ship_tokens
            # ... and its subscription at the vehicle
            auv_tokens = tokens(auv)
            assert any(t.endswith(f"/MS/%/%/zab_auv1/%auv1%odom/nav_msgs::msg::dds_::Odometry_/"
                                  f"{ODOM_HASH}/::,:,:,:,,") for t in auv_tokens), auv_tokens
            inbox = subscribe(ship, ODOM_KEY)
            sent = time.time()
            auv.put(ODOM_KEY, odometry(123.45, -67.89, -40.12, 0.38268, 0.92388, 1.23, -0.3),
                    attachment=rmw_attachment(1))
            key, payload, attachment, arrived = inbox.get(timeout=6)
            assert key == ODOM_KEY
            msg = JAZZY.deserialize_cdr(payload, "nav_msgs/msg/Odometry")  # valid, complete
            position = msg.pose.pose.position
            assert abs(position.x - 123.45) <= 0.05 + 1e-9  # resolution 0.1
            assert abs(position.y + 67.89) <= 0.05 + 1e-9
            assert abs(position.z + 40.12) <= 0.05 + 1e-9
            step = 2 / 4095  # 12 bits over [-1, 1]
            assert abs(msg.pose.pose.orientation.z - 0.38268) <= step / 2 + 1e-9
            assert abs(msg.pose.pose.orientation.w - 0.92388) <= step / 2 + 1e-9
            assert abs(msg.twist.twist.linear.x - 1.23) <= 0.025 + 1e-9
            assert abs(msg.twist.twist.angular.z + 0.3) <= 2 / 255 / 2 + 1e-9
            # what does not cross comes from the mission's defaults, zero otherwise
            assert msg.header.frame_id == "odom" and msg.child_frame_id == "auv1/base_link"
            assert sent - 1 <= msg.header.stamp.sec + msg.header.stamp.nanosec / 1e9 <= arrived
            assert msg.pose.covariance.tolist() == [0.0] * 36
            # rmw_zenoh's attachment: first sequence number 1, source time, a 16-byte GID
            assert attachment is not None and len(attachment) == 33
            seq, stamp_ns, gid_len, gid = struct.unpack("<qqB16s", attachment)
            assert seq == 1 and gid_len == 16 and len(gid) == 16
            assert sent <= stamp_ns / 1e9 <= arrived
            # a second message: the next sequence number
            auv.put(ODOM_KEY, odometry(1.0, 2.0, -3.0, 0.0, 1.0, 0.0, 0.0),
                    attachment=rmw_attachment(2))
            _, payload, attachment, _ = inbox.get(timeout=6)
            assert attachment is not None and struct.unpack("<q", attachment[:8])[0] == 2
            assert JAZZY.deserialize_cdr(payload, "nav_msgs/msg/Odometry").pose.pose.position.x \
                == pytest.approx(1.0)
            assert fleet.nodes["ship"].stats.received_per_channel["odom"] >= 2
        finally:
            auv.close()
            ship.close()


def test_twist_goes_down_and_bad_input_is_counted_not_fatal() -> None:
    loaded = mission_on_free_ports(MISSIONS / "ros2_odometry.yaml")
    with running_fleet(loaded) as fleet:
        auv, ship = outside_session(loaded, "auv1"), outside_session(loaded, "ship")
        try:
            cmd = subscribe(auv, f"0/auv1/cmd_vel/geometry_msgs::msg::dds_::Twist_/{TWIST_HASH}")
            remote = f"0/auv1/cmd_vel_remote/geometry_msgs::msg::dds_::Twist_/{TWIST_HASH}"
            ship.put(remote, b"\x00\x01\x00\x00\x00\x00", attachment=rmw_attachment(1))
            pose = T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](
                x=1.0, y=2.0, z=3.0), orientation=T["geometry_msgs/msg/Quaternion"](
                x=0.0, y=0.0, z=0.0, w=1.0))
            ship.put("0/auv1/cmd_vel_remote/geometry_msgs::msg::dds_::Pose_/RIHS01_" + "d" * 64,
                     bytes(JAZZY.serialize_cdr(pose, "geometry_msgs/msg/Pose")))
            twist = T["geometry_msgs/msg/Twist"](
                linear=T["geometry_msgs/msg/Vector3"](x=0.73, y=0.0, z=-0.2),
                angular=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.5))
            ship.put(remote, bytes(JAZZY.serialize_cdr(twist, "geometry_msgs/msg/Twist")),
                     attachment=rmw_attachment(2))
            _, payload, attachment, _ = cmd.get(timeout=6)
            got = JAZZY.deserialize_cdr(payload, "geometry_msgs/msg/Twist")
            assert abs(got.linear.x - 0.73) <= 0.025 + 1e-9
            assert abs(got.linear.z + 0.2) <= 0.025 + 1e-9
            assert abs(got.angular.z - 0.5) <= 2 / 255 / 2 + 1e-9
            assert attachment is not None and len(attachment) == 33
            assert fleet.nodes["ship"].stats.payloads_dropped["0/auv1/cmd_vel_remote/*/*"] == 2
        finally:
            auv.close()
            ship.close()


ECHO = """\
mission: rosecho
modem: {backend: udp, frame_bytes: 16}
mac: {type: none, min_gap_s: 0.2}
nodes:
  a: {address: 1, modem: {options: {port: PORT_A}}}
  b: {address: 2, modem: {options: {port: PORT_B}}}
channels:
  - name: up
    from: a
    to: b
    elements:
      - ros2: {topic: /depth, type: std_msgs/msg/Float64}
        fields: [{field: data, min: 0, max: 100, resolution: 0.5}]
  - name: back
    from: b
    to: a
    elements:
      - ros2: {topic: /depth, out_topic: /depth_echo, type: std_msgs/msg/Float64}
        fields: [{field: data, min: 0, max: 100, resolution: 0.5}]
"""


def test_a_bridge_never_re_bridges_its_own_ros2_publication() -> None:
    text = udp_ports(ECHO)
    loaded = on_free_ports(text, "rosecho.yaml")
    key = "0/{}/std_msgs::msg::dds_::Float64_/" + _hash("std_msgs/msg/Float64")
    with running_fleet(loaded) as fleet:
        a, b = outside_session(loaded, "a"), outside_session(loaded, "b")
        try:
            echo = subscribe(a, key.format("depth_echo"))
            depth = subscribe(b, key.format("depth"))
            a.put(key.format("depth"), _float64(42.3), attachment=rmw_attachment(1))
            _, payload, _, _ = depth.get(timeout=4)  # b's bridge published /depth ...
            assert JAZZY.deserialize_cdr(payload, "std_msgs/msg/Float64").data == 42.5
            with pytest.raises(queue.Empty):  # ... and did not send it back as input
                echo.get(timeout=1.5)
            assert fleet.nodes["b"].stats.sent_per_channel["back"] == 0
            b.put(key.format("depth"), _float64(7.0), attachment=rmw_attachment(1))
            _, payload, _, _ = echo.get(timeout=4)  # a ROS 2 node's /depth at b does cross
            assert JAZZY.deserialize_cdr(payload, "std_msgs/msg/Float64").data == 7.0
        finally:
            a.close()
            b.close()


def _hash(msgtype: str) -> str:
    return str(JAZZY.hash_rihs01(msgtype))


def _float64(value: float) -> Any:
    return bytes(JAZZY.serialize_cdr(T["std_msgs/msg/Float64"](data=value),
                                     "std_msgs/msg/Float64"))
