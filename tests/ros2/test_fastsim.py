"""The virtual-clock fleet plays ROS 2 nodes on ROS 2 inputs: CDR on the exact rmw_zenoh key."""

from __future__ import annotations

import pytest
from rosbags.typesys import Stores, get_typestore

from bridge.core.loaded import load_mission
from bridge.runtime.virtual_fleet import FastFleet
from tests.conftest import MISSIONS
from tests.ros2.test_messages import GOLDEN, ODOM

JAZZY = get_typestore(Stores.ROS2_JAZZY)


def test_ros2_values_cross_on_the_virtual_clock() -> None:
    fleet = FastFleet(load_mission(MISSIONS / "ros2_odometry.yaml"), seed=4)
    for i in range(10):
        fleet.put("auv1", "0/auv1/odom/*/*",
                  {"pose": {"pose": {"position": {"x": 10.0 * i, "y": -2.0, "z": -30.0}}}},
                  at=4.0 * i)
    fleet.run_until(45.0)
    got = fleet.published("ship", f"0/auv1/odom/nav_msgs::msg::dds_::Odometry_/{GOLDEN[ODOM]}")
    assert len(got) >= 8
    t, last = got[-1]
    assert last.ros2 is not None
    msg = JAZZY.deserialize_cdr(last.ros2.encode(last.value, t), ODOM)
    assert msg.pose.pose.position.x == pytest.approx(90.0)
    assert msg.header.frame_id == "odom"
    assert not fleet.cores["auv1"].stats.payloads_dropped
