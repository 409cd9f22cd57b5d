"""An image channel through a real ``zab sim``, with plain Zenoh applications: a JPEG put on
the ROV's Zenoh comes out at the operator's as ever sharper PNGs; the operator's ROI and
request, put or asked in a get, change the next picture; a corrupt picture is a counted
drop."""

from __future__ import annotations

import contextlib
import io
import json
import queue
import time
from collections.abc import Iterator
from pathlib import Path

import msgpack
import pytest
import yaml
import zenoh
from PIL import Image

from bridge.image.formats import write_image
from bridge.image.synthetic import seabed
from tests.conftest import MISSIONS
from tests.zsim import app, mission_file, zab_sim

JPEG = write_image(seabed(480, 640, seed=2, colour=False), "jpeg", quality=92)
"""A camera's picture: 32 kB, over any cap a channel of the mission's fields would give."""


def refinements(inbox: queue.Queue[dict[str, str]], until: float) -> list[dict[str, str]]:
    """PNG metadata of the pictures that arrive until the final one (or ``until``)."""
    got: list[dict[str, str]] = []
    while time.time() < until:
        try:
            text = inbox.get(timeout=max(0.0, until - time.time()))
        except queue.Empty:
            break
        got.append(text)
        if text["zab:final"] == "true":
            break
    return got


@contextlib.contextmanager
def rov_and_operator(mission: Path, endpoints: dict[str, list[str]]
                     ) -> Iterator[tuple[zenoh.Session, zenoh.Session,
                                         queue.Queue[dict[str, str]]]]:
    """``zab sim`` of ``mission`` with a plain app at the ROV and one at the operator, and
    the PNG metadata of each picture the operator gets on rov/camera."""
    inbox: queue.Queue[dict[str, str]] = queue.Queue()

    def on_picture(sample: zenoh.Sample) -> None:
        assert str(sample.encoding) == "image/png"
        inbox.put(dict(Image.open(io.BytesIO(sample.payload.to_bytes())).text))  # type: ignore[attr-defined]

    with contextlib.ExitStack() as stack:
        stack.enter_context(zab_sim(mission, endpoints))
        rov = app(endpoints["rov"])
        stack.callback(rov.close)
        operator = app(endpoints["operator"])
        stack.callback(operator.close)
        operator.declare_subscriber("rov/camera", on_picture)
        yield rov, operator, inbox


def test_pictures_cross_zab_sim_and_sharpen(tmp_path: Path) -> None:
    text = (MISSIONS / "bluerov_images.yaml").read_text().replace(
        "budget_bytes: 1600", "budget_bytes: 300").replace(
        "publish_interval_s: 1.0", "publish_interval_s: 0.0")
    mission, endpoints = mission_file(text, tmp_path)
    stats: queue.Queue[dict] = queue.Queue()
    with rov_and_operator(mission, endpoints) as (rov, operator, inbox):
        rov.declare_subscriber("@zab/bluerov_images/rov/stats",
                               lambda s: stats.put(msgpack.unpackb(s.payload.to_bytes())))
        time.sleep(1.0)  # the subscriptions reach the bridges
        rov.put("rov/camera", JPEG, encoding=zenoh.Encoding("image/jpeg"))
        first = refinements(inbox, time.time() + 60)
        sizes = [int(t["zab:bytes"]) for t in first]
        assert len(first) >= 3 and sizes == sorted(sizes)
        assert first[-1]["zab:final"] == "true" and first[-1]["zab:roi"] == "null"

        operator.put("camera/control", msgpack.packb({"roi": [0.25, 0.25, 0.75, 0.75],
                                                      "request": "now"}),
                     encoding=zenoh.Encoding("application/msgpack"))
        second = refinements(inbox, time.time() + 60)
        assert second and second[-1]["zab:final"] == "true"
        assert second[-1]["zab:roi"] == "[0.25, 0.25, 0.75, 0.75]"
        assert second[-1]["zab:sequence"] != first[-1]["zab:sequence"]

        replies = list(operator.get("camera/control?request=now;roi=none;budget_bytes=200",
                                    timeout=10))
        assert len(replies) == 1 and replies[0].ok is not None
        settings = json.loads(replies[0].ok.payload.to_bytes())
        assert settings["roi"] is None and settings["budget_bytes"] == 200
        third = refinements(inbox, time.time() + 60)
        assert third and third[-1]["zab:final"] == "true" and third[-1]["zab:roi"] == "null"
        assert int(third[-1]["zab:bytes"]) <= 200 < int(second[-1]["zab:bytes"])
        refused = list(operator.get("camera/control?request=later", timeout=10))
        assert len(refused) == 1 and refused[0].err is not None
        assert "request 'later'" in refused[0].err.payload.to_string()

        rov.put("rov/camera", b"\xff\xd8\xff" + b"\0" * 100,
                encoding=zenoh.Encoding("image/jpeg"))
        deadline = time.time() + 10
        dropped = 0
        while not dropped and time.time() < deadline:
            with contextlib.suppress(queue.Empty):
                dropped = stats.get(timeout=2)["payloads_dropped"].get("rov/camera", 0)
        assert dropped == 1


def test_a_ros2_camera_crosses_and_comes_out_as_compressed_images(tmp_path: Path) -> None:
    """A ROS 2 node's CompressedImage, put as rmw_zenoh's publisher puts it (its CDR on the
    topic's exact key, type and hash in it), comes out at the operator as PNGs and, on the
    mission's ``out_topic``, as CompressedImages a ROS 2 viewer reads (decoded here with
    rosbags, not zab's code). The bridges are in the ROS 2 graph: the ROV's subscribes to the
    camera's topic (image_transport publishes only while something does), the operator's
    publishes the pictures' topic."""
    from rosbags.typesys import Stores, get_typestore

    from bridge.ros2.messages import encode_cdr, type_hash

    text = (MISSIONS / "bluerov_images.yaml").read_text().replace(
        "    in: rov/camera\n",
        "    ros2: {topic: /rov/camera, type: sensor_msgs/msg/CompressedImage,\n"
        "           out_topic: '/{dst}/{src}_camera/compressed', frame_id: rov_camera}\n"
    ).replace("budget_bytes: 1600", "budget_bytes: 200").replace(
        "publish_interval_s: 1.0", "publish_interval_s: 0.0")
    mission, endpoints = mission_file(text, tmp_path)
    key = ("0/rov/camera/sensor_msgs::msg::dds_::CompressedImage_/"
           + type_hash("jazzy", "sensor_msgs/msg/CompressedImage"))
    cdr = encode_cdr("jazzy", "sensor_msgs/msg/CompressedImage",
                     {"format": "jpeg", "data": write_image(seabed(120, 160, seed=3,
                                                                   colour=False), "jpeg")})
    typestore = get_typestore(Stores.ROS2_JAZZY)
    shown: queue.Queue[tuple[object, bytes | None]] = queue.Queue()
    with rov_and_operator(mission, endpoints) as (rov, operator, inbox):
        operator.declare_subscriber(
            "0/operator/rov_camera/compressed/**",
            lambda s: shown.put((typestore.deserialize_cdr(
                s.payload.to_bytes(), "sensor_msgs/msg/CompressedImage"),
                None if s.attachment is None else s.attachment.to_bytes())))
        time.sleep(1.0)  # the subscription reaches the operator's bridge
        tokens = {name: [str(r.ok.key_expr) for r in session.liveliness().get(
            "@ros2_lv/0/**", timeout=2.0) if r.ok] for name, session in (("rov", rov),
                                                                          ("operator", operator))}
        assert any("/MS/" in t and "/%rov%camera/" in t and "CompressedImage" in t
                   for t in tokens["rov"]), tokens
        assert any("/MP/" in t and "/%operator%rov_camera%compressed/" in t
                   for t in tokens["operator"]), tokens
        rov.put(key, cdr)
        got = refinements(inbox, time.time() + 60)
        assert got and got[-1]["zab:final"] == "true"
        assert [int(t["zab:bytes"]) for t in got] == sorted(int(t["zab:bytes"]) for t in got)
        messages = []
        deadline = time.time() + 10
        while len(messages) < len(got) and time.time() < deadline:
            with contextlib.suppress(queue.Empty):
                messages.append(shown.get(timeout=1))
    assert len(messages) == len(got)
    for (message, attachment), text in zip(messages, got, strict=True):
        assert message.format == "mono8; png compressed mono8"  # type: ignore[attr-defined]
        assert message.header.frame_id == "rov_camera"  # type: ignore[attr-defined]
        stamp = message.header.stamp  # type: ignore[attr-defined]
        assert stamp.sec + stamp.nanosec * 1e-9 == pytest.approx(float(text["zab:time"]),
                                                                abs=1e-3)
        picture = Image.open(io.BytesIO(bytes(message.data)))  # type: ignore[attr-defined]
        assert picture.size == (160, 120) and picture.text == text  # type: ignore[attr-defined]
        assert attachment is not None and len(attachment) == 33  # rmw_zenoh's attachment


def test_a_surfaced_rov_s_pictures_reach_ros2_viewers_over_ip(tmp_path: Path) -> None:
    """``zab sim`` with the ROV's bridge and the operator's on one Wi-Fi (a Zenoh peer joining
    their routers, as the surface's access point does): the camera's JPEG reaches the
    operator's ROS 2 topic whole, as it came, read with rosbags by a plain app; nothing
    crosses the water to be shown meanwhile."""
    from rosbags.typesys import Stores, get_typestore

    from bridge.runtime.surface_wifi import access_point

    data = yaml.safe_load((MISSIONS / "bluerov_images.yaml").read_text().replace(
        "    in: rov/camera\n",
        "    in: camera\n    ros2: {out_topic: '/{dst}/{src}_camera/compressed'}\n"))
    data["surfacing"] = {"republish": True}
    for node in data["nodes"].values():  # (as the deploy kit runs them: routers)
        node["zenoh"] = {"mode": "router", "scouting/gossip/enabled": False,
                         "scouting/delay": 0}
    mission, endpoints = mission_file(yaml.safe_dump(data, sort_keys=False), tmp_path)
    typestore = get_typestore(Stores.ROS2_JAZZY)
    shown: queue.Queue[object] = queue.Queue()
    pngs: list[bytes] = []
    with contextlib.ExitStack() as stack:
        stack.enter_context(zab_sim(mission, endpoints))
        rov, operator = app(endpoints["rov"]), app(endpoints["operator"])
        stack.callback(rov.close)
        stack.callback(operator.close)
        operator.declare_subscriber("0/operator/rov_camera/compressed/**", lambda s: shown.put(
            typestore.deserialize_cdr(s.payload.to_bytes(), "sensor_msgs/msg/CompressedImage")))
        operator.declare_subscriber("rov/camera", lambda s: pngs.append(s.payload.to_bytes())
                                    if str(s.encoding) == "image/png" else None)
        wifi = access_point(endpoints["operator"] + endpoints["rov"])
        stack.callback(wifi.close)
        time.sleep(2.0)  # the bridges' tokens cross; they switch over
        rov.put("camera", JPEG, encoding=zenoh.Encoding("image/jpeg"))
        message = shown.get(timeout=10)
        time.sleep(2.0)  # (refinements crossing the water would show by now)
    assert message.format == "mono8; jpeg compressed mono8"  # type: ignore[attr-defined]
    assert bytes(message.data) == JPEG  # type: ignore[attr-defined]
    assert shown.empty() and pngs == []
