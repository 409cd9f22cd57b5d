"""``zab sim --fast`` on every shipped mission, as a newcomer first runs one: it ends, and
what the mission carries crosses (a camera's pictures too, from a synthetic camera)."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from bridge.cli.app import app
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
