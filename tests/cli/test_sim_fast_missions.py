"""``zab sim --fast`` on every shipped mission, as a newcomer first runs one: it ends, and
what the mission carries crosses (a camera's pictures too, from a synthetic camera)."""

from __future__ import annotations

import random
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from bridge.cli.app import app
from bridge.cli.sim_fast import feed, least_feed_s
from bridge.core.events import Delivery, FrameReceived
from bridge.core.loaded import load_mission, parse_mission
from bridge.mission.presets import PRESETS
from bridge.report.age import AgeOfInformation
from bridge.report.model import MissionReport
from bridge.runtime.virtual_fleet import FastFleet, Timed
from tests.conftest import MISSIONS

RUNNER = CliRunner()


@pytest.mark.parametrize("path", sorted(MISSIONS.glob("*.yaml")), ids=lambda p: p.stem)
def test_every_shipped_mission_simulates_on_the_virtual_clock(path: Path,
                                                            mission_key: str) -> None:
    result = RUNNER.invoke(app, ["sim", str(path), "--fast", "--duration", "60"])
    assert result.exit_code == 0, result.output
    assert "Traceback" not in result.output
    assert "simulated in" in result.output


def test_a_synthetic_camera_feeds_an_image_channel(mission_key: str) -> None:
    """bluerov_images: the camera's fragments are sent and delivered, the operator's control
    key is left alone (random controls would cancel every picture)."""
    result = RUNNER.invoke(app, ["sim", str(MISSIONS / "bluerov_images.yaml"), "--fast",
                                 "--duration", "120"])
    assert result.exit_code == 0, result.output
    rows = {line.split("│")[1].strip(): [c.strip() for c in line.split("│")[2:-1]]
            for line in result.output.splitlines() if line.startswith("│")}
    camera, control = rows["camera"], rows["camera.control"]
    assert int(camera[1]) >= 40 and int(camera[2]) >= 40  # a 1600 B picture: 40 trunks
    assert control[1:3] == ["0", "0"]


def test_the_operator_s_image_controls_count_as_delivered() -> None:
    """bluerov_images with two controls put at the surface: the summary's camera.control row
    says both were delivered, as the delivery reports do and the camera applied them (it
    said 0: a control's arrival was no value received), its age counted from the first."""
    loaded = load_mission(MISSIONS / "bluerov_images.yaml")
    ages = AgeOfInformation()
    states: list[str] = []

    def outputs(timed: Timed) -> None:
        event = timed.output
        if isinstance(event, FrameReceived):
            for channel in event.channels:
                ages.arrived(channel, timed.node, timed.time)
        elif isinstance(event, Delivery) and event.channel == "camera.control":
            states.append(event.state)

    fleet = FastFleet(loaded, seed=0, on_output=outputs, keep_outputs=False)
    feed(fleet, random.Random(0), 200.0)
    fleet.put("operator", "camera/control", {"budget_bytes": 777}, at=20.0, ref="budget")
    fleet.put("operator", "camera/control", {"roi": [0.25, 0.25, 0.75, 0.75]}, at=60.0,
              ref="roi")
    fleet.run_until(200.0)
    images = fleet.cores["rov"].images
    assert images is not None
    camera = images.cameras[loaded.table.by_name("camera").index + 1]
    assert camera.settings["budget_bytes"] == 777 and camera.settings["roi"] is not None
    assert states.count("delivered") == 2, states
    report = MissionReport.build(loaded, fleet.cores, ages, 0.0, fleet.now,
                                 fleet.water_stats(), clock="virtual")
    control = report.channels["camera.control"]
    assert control.sent >= 2 and control.delivered == 2
    assert control.age is not None and control.age.max_s < 200.0 - 60.0


def tiny_interval_odometry() -> str:
    """ros2_odometry as shipped, its odometry channel at ``interval_s: 1e-6``."""
    text = (MISSIONS / "ros2_odometry.yaml").read_text()
    return text.replace("    to: ship\n", "    to: ship\n    interval_s: 1.0e-6\n", 1)


def test_a_tiny_interval_is_fed_no_faster_than_frames_can_leave() -> None:
    """Before, the synthetic application put a value every interval_s (a million a virtual
    second): ``zab sim --fast`` never ended. Now no faster than a one-byte frame's airtime."""
    loaded = parse_mission(tiny_interval_odometry(), "ros2_odometry.yaml")
    assert loaded.mission.channels[0].interval_s == 1e-6
    fleet = FastFleet(loaded, seed=0)
    puts: list[tuple[float, str]] = []
    fleet.put = lambda node, key, value, **_: puts.append((fleet.now, key))  # type: ignore[method-assign]
    feed(fleet, random.Random(0), 2.0)
    fleet.run_until(2.0)
    least = least_feed_s(fleet, "auv1")
    assert least == PRESETS["evologics-s2c-im"].airtime(1)
    odom = [t for t, key in puts if "odom" in key]
    assert 2.0 / least - 2 <= len(odom) <= 2.0 / least + 1, len(odom)


def test_a_tiny_interval_simulates_quickly(mission_key: str, tmp_path: Path) -> None:
    path = tmp_path / "ros2_odometry.yaml"
    path.write_text(tiny_interval_odometry())
    start = time.monotonic()
    result = RUNNER.invoke(app, ["sim", str(path), "--fast", "--duration", "60"])
    assert result.exit_code == 0, result.output
    assert "simulated in" in result.output
    assert time.monotonic() - start < 30  # (a few seconds; before, not done after 40)
