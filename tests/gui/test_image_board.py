"""The GUI's image board: a page's control goes on its camera's key."""

from __future__ import annotations

import pytest

from bridge.core.loaded import load_mission, parse_mission
from bridge.gui.images import ImageBoard, ImageControlError
from tests.conftest import MISSIONS
from tests.runtime.test_images_fleet import TWO_CAMERAS


def test_a_card_steers_its_own_camera_where_each_has_a_key() -> None:
    board = ImageBoard(parse_mission(TWO_CAMERAS % ""), "operator")
    key, value = board.control({"channel": "camera", "camera": "rov2", "roi": [0, 0, 0.5, 0.5]})
    assert key == "rov2/camera/control" and value["roi"] == [0.0, 0.0, 0.5, 0.5]
    with pytest.raises(ImageControlError, match="no camera 'rov3'"):
        board.control({"channel": "camera", "camera": "rov3", "request": "now"})
    with pytest.raises(ImageControlError, match="no camera None"):
        board.control({"channel": "camera", "request": "now"})


def test_one_key_steers_every_camera_whichever_card() -> None:
    board = ImageBoard(parse_mission(TWO_CAMERAS % "    control: cameras/control\n"),
                       "operator")
    assert board.control({"channel": "camera", "camera": "rov", "request": "now"})[0] == \
        "cameras/control"
    single = ImageBoard(load_mission(MISSIONS / "bluerov_images.yaml"), "operator")
    assert single.control({"channel": "camera", "request": "now"})[0] == "camera/control"
