"""The GUI's image board: a page's control goes on its camera's key; a picture's metadata,
or, for the camera's own picture put over IP, that it is whole."""

from __future__ import annotations

import io

import pytest
from PIL import Image

from bridge.core.loaded import load_mission, parse_mission
from bridge.gui.images import ImageBoard, ImageControlError
from bridge.image.formats import write_image
from tests.conftest import MISSIONS
from tests.runtime.test_images_fleet import JPEG, PICTURE, TWO_CAMERAS


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


def test_the_camera_s_own_picture_over_ip_is_shown_whole() -> None:
    board = ImageBoard(load_mission(MISSIONS / "bluerov_images.yaml"), "operator")
    item = board.ingest("rov/camera", JPEG, "image/jpeg", 5.0)  # (surfaced: no zab metadata)
    assert item is not None and item["meta"] == {
        "whole": True, "final": True, "bytes": len(JPEG), "budget": len(JPEG),
        "width": 320, "height": 240}
    png = write_image(PICTURE[:120, :160], "png", text={"zab:bytes": "37", "zab:final": "false"})
    item = board.ingest("rov/camera", png, "image/png", 6.0)
    assert item is not None and item["meta"] == {"bytes": 37, "final": False}


def test_the_camera_s_own_picture_turned_by_its_exif_gives_the_size_shown() -> None:
    board = ImageBoard(load_mission(MISSIONS / "bluerov_images.yaml"), "operator")
    image = Image.fromarray(PICTURE)  # 320 × 240, taken with the camera turned
    exif = image.getexif()
    exif[0x0112] = 8
    out = io.BytesIO()
    image.save(out, "JPEG", exif=exif.tobytes())
    item = board.ingest("rov/camera", out.getvalue(), "image/jpeg", 5.0)
    assert item is not None
    assert (item["meta"]["width"], item["meta"]["height"]) == (240, 320)


@pytest.mark.parametrize("kind", ["PNG", "JPEG"])
def test_the_camera_s_own_picture_with_an_exif_block_cut_short_is_shown(kind: str) -> None:
    """A block the picture's decoder cannot read shows the picture upright; the board took
    its size from it and raised (a PNG's: 'not a TIFF file'), so the picture never showed."""
    board = ImageBoard(load_mission(MISSIONS / "bluerov_images.yaml"), "operator")
    image = Image.fromarray(PICTURE)
    exif = image.getexif()
    exif[0x0112] = 6
    out = io.BytesIO()
    image.save(out, kind, exif=exif.tobytes()[:3])
    item = board.ingest("rov/camera", out.getvalue(), f"image/{kind.lower()}", 5.0)
    assert item is not None
    assert (item["meta"]["width"], item["meta"]["height"]) == (320, 240)


def test_a_jpeg_picture_s_metadata_reads_as_a_png_s() -> None:
    """A channel publishing JPEGs (format: jpeg) gave the GUI {"zab:bytes": 37, …} instead of
    {"bytes": 37, …}: its comment's keys had "zab:" put before them again. A camera's own
    JPEG with a JSON comment of its own is still shown whole."""
    board = ImageBoard(load_mission(MISSIONS / "bluerov_images.yaml"), "operator")
    text = {"zab:bytes": "37", "zab:final": "false", "zab:roi": "null"}
    for kind in ("png", "jpeg"):
        item = board.ingest("rov/camera", write_image(PICTURE[:120, :160], kind, text=text),
                            f"image/{kind}", 6.0)
        assert item is not None and item["meta"] == {"bytes": 37, "final": False, "roi": None}
    out = io.BytesIO()
    Image.fromarray(PICTURE).save(out, "JPEG", comment=b'{"exposure_ms": 8}')
    item = board.ingest("rov/camera", out.getvalue(), "image/jpeg", 7.0)
    assert item is not None and item["meta"]["whole"] is True


@pytest.mark.parametrize("message", [
    {"roi": [0, 0, True, True]}, {"width": True}, {"budget_bytes": True}])
def test_a_page_s_boolean_is_no_number(message: dict) -> None:
    """A page's ``true`` is refused where a size or an ROI corner goes, not read as 1."""
    board = ImageBoard(load_mission(MISSIONS / "bluerov_images.yaml"), "operator")
    with pytest.raises(ImageControlError):
        board.control({"channel": "camera", **message})


def test_a_page_s_budget_below_one_fragment_is_refused() -> None:
    board = ImageBoard(load_mission(MISSIONS / "bluerov_images.yaml"), "operator")
    assert board.describe()[0]["min_budget_bytes"] == 37
    with pytest.raises(ImageControlError, match=r"budget_bytes 16 is below .* a 37-byte fragment"):
        board.control({"channel": "camera", "budget_bytes": 16})
    assert board.control({"channel": "camera", "budget_bytes": 37})[1]["budget_bytes"] == 37
