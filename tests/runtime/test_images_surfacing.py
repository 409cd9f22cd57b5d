"""Image channels and surfacing, on the virtual clock: while the operator is reachable over
IP the camera's picture reaches it whole (relayed as it came on the output key) and not as
acoustic refinements; a picture already crossing goes on to its end; after the dive,
pictures cross the water again."""

from __future__ import annotations

import io
from typing import Any

import numpy as np
import pytest
from PIL import Image, ImageOps

from bridge.core.loaded import parse_mission
from bridge.core.surfacing import Relay
from bridge.runtime.virtual_fleet import FastFleet
from tests.conftest import MISSIONS
from tests.runtime.test_images_fleet import JPEG, PICTURE, pictures

SAME_KEY = (MISSIONS / "bluerov_images.yaml").read_text().replace(
    "mission: bluerov_images", "mission: bluerov_images\nsurfacing: {republish: true}")
MISSION = SAME_KEY.replace(  # (the camera's own key: relayed to rov/camera)
    "    in: rov/camera\n", "    in: camera\n")


def relays(fleet: FastFleet, node: str) -> list[Relay]:
    return [o.output for o in fleet.outputs if o.node == node and isinstance(o.output, Relay)]


def test_a_surfaced_operator_gets_the_picture_whole_and_no_coarser_copies() -> None:
    fleet = FastFleet(parse_mission(MISSION, "surf.yaml"), seed=1)
    fleet.ip_link("operator", "rov", True)
    fleet.put("rov", "camera", JPEG, encoding="image/jpeg", at=1.0)
    fleet.run_until(40.0)
    [relay] = relays(fleet, "rov")
    assert (relay.key, relay.data, relay.encoding) == ("rov/camera", JPEG, "image/jpeg")
    assert pictures(fleet) == []  # nothing crossed the water to be shown
    assert fleet.cores["rov"].images is not None
    camera = next(iter(fleet.cores["rov"].images.inputs.values()))
    assert camera.current is None and camera.last is not None  # kept for a request

    fleet.ip_link("operator", "rov", False)  # the dive: a request sends it acoustically
    fleet.put("operator", "camera/control", {"request": "now"}, at=41.0)
    fleet.run_until(80.0)
    got = pictures(fleet)
    assert got and got[-1][1]["zab:final"] == "true"


def test_a_picture_crossing_when_the_operator_surfaces_is_shown_to_its_end() -> None:
    fleet = FastFleet(parse_mission(MISSION, "surf.yaml"), seed=1)
    fleet.put("rov", "camera", JPEG, encoding="image/jpeg", at=1.0)
    fleet.run_until(8.0)
    assert len(pictures(fleet)) >= 2
    fleet.ip_link("operator", "rov", True)
    fleet.run_until(40.0)
    got = pictures(fleet)
    assert got[-1][1]["zab:final"] == "true"  # (it came before the IP path: never put there)
    assert relays(fleet, "rov") == []


def test_a_picture_begun_by_a_camera_that_has_not_noticed_the_surfacing_is_not_shown() -> None:
    fleet = FastFleet(parse_mission(MISSION, "surf.yaml"), seed=1)
    fleet.cores["operator"].ip_reachable("rov", True, 0.5)  # (the ROV's bridge: not yet)
    fleet.put("rov", "camera", JPEG, encoding="image/jpeg", at=1.0)
    fleet.run_until(40.0)
    assert pictures(fleet) == []
    surfacing = fleet.cores["operator"].surfacing
    assert surfacing is not None and surfacing.duplicates > 0


def test_a_picture_asked_for_while_surfaced_comes_over_ip_where_it_can() -> None:
    fleet = FastFleet(parse_mission(MISSION, "surf.yaml"), seed=1)
    fleet.ip_link("operator", "rov", True)
    fleet.put("rov", "camera", JPEG, encoding="image/jpeg", at=1.0)
    fleet.put("operator", "camera/control", {"request": "now"}, at=10.0)
    fleet.run_until(40.0)
    assert [r.key for r in relays(fleet, "rov")] == ["rov/camera", "rov/camera"]  # put, asked
    assert pictures(fleet) == []


def test_where_the_output_key_is_the_input_key_a_picture_asked_for_crosses_and_shows() -> None:
    """The operator's applications saw the put itself over IP; asked for again, the picture
    can only cross the water, and the operator shows it."""
    fleet = FastFleet(parse_mission(SAME_KEY, "same.yaml"), seed=1)
    fleet.ip_link("operator", "rov", True)
    fleet.put("rov", "rov/camera", JPEG, encoding="image/jpeg", at=1.0)
    fleet.run_until(8.0)
    assert relays(fleet, "rov") == [] and pictures(fleet) == []  # (seen as put: not sent)
    fleet.put("operator", "camera/control", {"request": "now"}, at=10.0)
    fleet.run_until(50.0)
    got = pictures(fleet)
    assert got and got[-1][1]["zab:final"] == "true"


ROS2_OUT = MISSION.replace("    in: camera\n", "    in: camera\n    ros2: {out_topic: "
                          "/operator/rov_camera/compressed, frame_id: rov_camera}\n")


def compressed_images(fleet: FastFleet, node: str) -> list[Any]:
    """The CompressedImages ``node`` published, read with rosbags."""
    from rosbags.typesys import Stores, get_typestore

    typestore = get_typestore(Stores.ROS2_JAZZY)
    out = []
    for t, p in fleet.published(node):
        if p.ros2 is not None:
            assert p.key.startswith("0/operator/rov_camera/compressed/sensor_msgs::msg::dds_::"
                                    "CompressedImage_/")
            out.append(typestore.deserialize_cdr(p.ros2.encode(p.value, t),
                                                 "sensor_msgs/msg/CompressedImage"))
    return out


def ros2_pictures(fleet: FastFleet, node: str) -> list[tuple[str, bytes]]:
    """The CompressedImages ``node`` published: their format and data."""
    return [(m.format, bytes(m.data)) for m in compressed_images(fleet, node)]


def test_a_surfaced_operator_s_ros2_topic_gets_the_picture_as_it_came() -> None:
    """``ros2.out_topic`` while surfaced: the camera's bridge publishes the JPEG as it came
    on the operator's ROS 2 topic (nothing crosses the water, and the operator publishes
    nothing); after the dive, the operator publishes the refinements again."""
    fleet = FastFleet(parse_mission(ROS2_OUT, "surf.yaml"), seed=1)
    fleet.ip_link("operator", "rov", True)
    fleet.put("rov", "camera", JPEG, encoding="image/jpeg", at=1.0)
    fleet.run_until(40.0)
    assert ros2_pictures(fleet, "rov") == [("mono8; jpeg compressed mono8", JPEG)]
    assert [m.header.frame_id for m in compressed_images(fleet, "rov")] == ["rov_camera"]
    assert ros2_pictures(fleet, "operator") == [] and pictures(fleet) == []

    fleet.ip_link("operator", "rov", False)
    fleet.put("operator", "camera/control", {"request": "now"}, at=41.0)
    fleet.run_until(80.0)
    got = ros2_pictures(fleet, "operator")
    assert len(got) == len(pictures(fleet)) >= 2
    assert {f for f, _ in got} == {"mono8; png compressed mono8"}


@pytest.mark.parametrize(("mode", "exif"), [("P", None), ("RGB", 6), ("I;16", None)])
def test_a_file_a_ros2_viewer_would_misread_is_made_anew_or_said_so(
        mode: str, exif: int | None) -> None:
    """A palette PNG and an EXIF-turned one are made anew as the channel's PNG (OpenCV
    would show the palette's indices, or the picture on its side); a 16-bit one goes as it
    is, said ``mono16``."""
    picture = Image.fromarray(PICTURE).convert("RGB")
    if mode == "I;16":
        picture = Image.fromarray(np.asarray(picture.convert("L"), dtype=np.uint16) * 257)
    elif mode == "P":
        picture = picture.convert("P")
    out = io.BytesIO()
    if exif is not None:
        tags = picture.getexif()
        tags[0x0112] = exif
        picture.save(out, format="PNG", exif=tags.tobytes())
    else:
        picture.save(out, format="PNG")
    fleet = FastFleet(parse_mission(ROS2_OUT, "surf.yaml"), seed=1)
    fleet.ip_link("operator", "rov", True)
    fleet.put("rov", "camera", out.getvalue(), encoding="image/png", at=1.0)
    fleet.run_until(10.0)
    [(fmt, data)] = ros2_pictures(fleet, "rov")
    if mode == "I;16":
        assert (fmt, data) == ("mono16; png compressed mono16", out.getvalue())
        return
    assert fmt == "mono8; png compressed mono8" and data != out.getvalue()
    shown = np.asarray(Image.open(io.BytesIO(data)))
    upright = np.asarray(ImageOps.exif_transpose(Image.open(out)).convert("L"))
    assert shown.shape == upright.shape and np.abs(
        shown.astype(int) - upright.astype(int)).max() <= 1


def test_a_picture_asked_for_again_where_it_must_cross_shows_on_ros2_whole_only() -> None:
    """The output key is the input key: asked for while surfaced, the picture crosses the
    water to be shown on it again; the ROS 2 topic has had it whole over IP, and gets no
    coarser copies after it."""
    fleet = FastFleet(parse_mission(SAME_KEY.replace(
        "    in: rov/camera\n",
        "    in: rov/camera\n    ros2: {out_topic: /operator/rov_camera/compressed}\n"),
        "same.yaml"), seed=1)
    fleet.ip_link("operator", "rov", True)
    fleet.put("rov", "rov/camera", JPEG, encoding="image/jpeg", at=1.0)
    fleet.put("operator", "camera/control", {"request": "now"}, at=10.0)
    fleet.run_until(50.0)
    assert pictures(fleet)[-1][1]["zab:final"] == "true"  # (crossed to be shown)
    assert ros2_pictures(fleet, "rov") == [("mono8; jpeg compressed mono8", JPEG)] * 2
    assert ros2_pictures(fleet, "operator") == []


@pytest.mark.parametrize(("topic", "keys"), [
    ("/rov/camera/compressed", ["0/rov/camera/compressed"]),
    ("/{dst}/rov_camera", ["0/operator/rov_camera", "0/pilot/rov_camera"])])
def test_two_surfaced_receivers_get_the_picture_once_a_topic(topic: str, keys: list[str]) -> None:
    """One topic for every receiver (no ``{dst}``) gets the picture once, not once each;
    ``zab check`` warns that every receiver publishes every picture on it."""
    text = MISSION.replace(
        "    to: operator\n    in: camera\n",
        f"    to: [operator, pilot]\n    in: camera\n    ros2: {{out_topic: '{topic}'}}\n"
    ).replace("  rov:\n", "  pilot:\n    address: 3\n    role: surface\n"
              "    position: {x: 0, y: 1, depth: 0.5}\n  rov:\n", 1)
    assert "pilot]" in text
    fleet = FastFleet(parse_mission(text, "two.yaml"), seed=1)
    fleet.ip_link("operator", "rov", True)
    fleet.ip_link("pilot", "rov", True)
    fleet.put("rov", "camera", JPEG, encoding="image/jpeg", at=1.0)
    fleet.run_until(10.0)
    published = sorted(p.key.rsplit("/", 2)[0] for _, p in fleet.published("rov")
                       if p.ros2 is not None)
    assert published == keys
    from bridge.report.check import check_mission  # zab check says so beforehand

    shared = [w for w in check_mission(parse_mission(text)).warnings if "share" in w]
    assert shared == ([] if "{dst}" in topic else [
        "image channel 'camera': rov's receivers operator, pilot share one ROS 2 topic "
        "(/rov/camera/compressed): where their ROS 2 graphs meet, each picture comes once "
        "from each (give out_topic {dst})"])
