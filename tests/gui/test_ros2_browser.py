"""``zab gui`` in headless Chromium on a ROS 2 mission (``deploy/missions/ros2_odometry.yaml``):
a vehicle's ``nav_msgs/Odometry``, put as a ROS 2 node's CDR, shows as its fields on the page,
and a ``geometry_msgs/Twist`` sent from the page's command form reaches the vehicle's Zenoh as
the CDR message a ROS 2 subscriber takes, on the key rmw_zenoh's publisher uses."""

from __future__ import annotations

import contextlib
import queue
import time
from pathlib import Path

import zenoh

from bridge.ros2.messages import decode_cdr, encode_cdr, type_hash
from tests.conftest import MISSIONS, needs_browser, on_free_ports
from tests.gui.fleet import mission_text
from tests.gui.test_browser import WAIT_MS, gui_process, open_page
from tests.harness import outside_session, running_fleet

pytestmark = needs_browser

ODOM = ("0/auv1/odom/nav_msgs::msg::dds_::Odometry_/"
        + type_hash("jazzy", "nav_msgs/msg/Odometry"))
"""Where a ROS 2 node on the vehicle publishes /auv1/odom (rmw_zenoh, domain 0)."""


def test_odometry_shows_and_a_twist_from_the_page_reaches_the_vehicle(tmp_path: Path) -> None:
    text = (MISSIONS / "ros2_odometry.yaml").read_text()
    loaded = on_free_ports(text, "ros2_odometry.yaml")
    path = tmp_path / "ros2_odometry.yaml"
    path.write_text(mission_text(text, loaded))
    twists: queue.Queue[tuple[str, dict]] = queue.Queue()

    def on_twist(sample: zenoh.Sample) -> None:
        twists.put((str(sample.key_expr), decode_cdr(
            "jazzy", "geometry_msgs/msg/Twist", sample.payload.to_bytes())))

    with contextlib.ExitStack() as stack:
        stack.enter_context(running_fleet(loaded))
        vehicle = outside_session(loaded, "auv1")
        stack.callback(vehicle.close)
        vehicle.declare_subscriber("0/auv1/cmd_vel/**", on_twist)
        odom = encode_cdr("jazzy", "nav_msgs/msg/Odometry", {
            "pose": {"pose": {"position": {"x": 123.4, "y": -56.7, "z": -12.3},
                              "orientation": {"z": 0.0, "w": 1.0}}},
            "twist": {"twist": {"linear": {"x": 1.5}}}})
        page, errors = open_page(stack, stack.enter_context(gui_process(path)))
        row = '.vehicle-card[data-node="auv1"] tr[data-channel="odom"]'
        deadline = time.time() + WAIT_MS / 1000 * 2
        while time.time() < deadline and not page.is_visible(row):
            vehicle.put(ODOM, odom)  # a ROS 2 node's odometry, until the GUI shows it
            page.wait_for_timeout(1000)
        page.wait_for_selector(row, timeout=WAIT_MS)
        shown = page.inner_text(f"{row} .value")
        assert "child_frame_id auv1/base_link" in shown, shown  # the mission's defaults
        assert "pose.pose.position.x 123.4" in shown, shown  # (the row is cut after a few)

        page.wait_for_selector('#connection[data-state="up"]', timeout=WAIT_MS)
        page.select_option("#command-vehicle", "auv1")
        page.select_option("#command-channel", "cmd_vel")
        page.fill('#command-fields [data-path="linear.x"]', "0.5")
        page.fill('#command-fields [data-path="linear.z"]', "-0.25")
        page.fill('#command-fields [data-path="angular.z"]', "0")
        page.click("#command-send")
        page.wait_for_selector('#commands li[data-vehicle="auv1"]', timeout=WAIT_MS)
        key, twist = twists.get(timeout=WAIT_MS / 1000)
        assert key == ("0/auv1/cmd_vel/geometry_msgs::msg::dds_::Twist_/"
                       + type_hash("jazzy", "geometry_msgs/msg/Twist"))
        assert twist["linear"]["x"] == 0.5 and twist["linear"]["z"] == -0.25
        assert page.inner_text("#command-error") == ""
        assert errors == [], errors
