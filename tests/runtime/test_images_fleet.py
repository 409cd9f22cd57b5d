"""Image channels end to end on the virtual clock: a JPEG put on the ROV comes out at the
operator as ever sharper PNGs; the operator's ROI changes the next picture; lost fragments
are repaired; bad pictures are counted drops."""

from __future__ import annotations

import dataclasses
import io
import itertools
import json
import logging
import re

import numpy as np
import pytest
from PIL import Image

from bridge.core.loaded import load_mission, parse_mission
from bridge.core.node import NodeCore, Status
from bridge.image.formats import write_image
from bridge.image.synthetic import seabed
from bridge.mission.loader import MissionProblems
from bridge.runtime.virtual_fleet import FastFleet
from bridge.wire.images import ImageSpec, merge_control
from tests.conftest import MISSIONS

PICTURE = seabed(240, 320, seed=5, colour=False)
JPEG = write_image(PICTURE, "jpeg", quality=92)


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(float) - b.astype(float)) ** 2))
    return 10 * np.log10(255 ** 2 / max(mse, 1e-9))


def pictures(fleet: FastFleet) -> list[tuple[float, dict[str, str], np.ndarray]]:
    """What the operator published on rov/camera: time, PNG text, pixels."""
    out = []
    for t, p in fleet.published("operator", "rov/camera"):
        assert p.encoding == "image/png"
        image = Image.open(io.BytesIO(p.value))
        out.append((t, dict(image.text), np.asarray(image)))  # type: ignore[attr-defined]
    return out


def test_a_jpeg_on_the_rov_sharpens_at_the_operator() -> None:
    fleet = FastFleet(load_mission(MISSIONS / "bluerov_images.yaml"), seed=1)
    fleet.put("rov", "rov/camera", JPEG, encoding="image/jpeg", at=1.0)
    fleet.run_until(40.0)
    got = pictures(fleet)
    assert len(got) >= 10
    sizes = [int(text["zab:bytes"]) for _, text, _ in got]
    assert sizes == sorted(sizes) and len(set(sizes)) == len(sizes)
    small = np.asarray(Image.fromarray(PICTURE).resize((160, 120), Image.Resampling.LANCZOS))
    quality = [psnr(small, pixels) for _, _, pixels in got]
    assert quality[-1] > quality[0] + 6
    assert got[-1][1]["zab:final"] == "true" and all(t["zab:final"] == "false"
                                                     for _, t, _ in got[:-1])
    assert got[-1][1]["zab:bytes"] == got[-1][1]["zab:budget"]
    statuses = [o.output for o in fleet.outputs if o.node == "operator"
                and isinstance(o.output, Status) and o.output.topic == "images/camera/rov"]
    assert statuses[-1].payload["final"] is True
    # the camera's delivery report names the picture as its pictures do
    reports = [o.output.payload for o in fleet.outputs if o.node == "rov"
               and isinstance(o.output, Status) and o.output.topic == "delivery/camera"]
    assert reports[-1]["state"] == "delivered"
    assert reports[-1]["sequence"] == int(got[-1][1]["zab:sequence"])


def test_the_operator_s_roi_changes_the_next_picture() -> None:
    fleet = FastFleet(load_mission(MISSIONS / "bluerov_images.yaml"), seed=2)
    fleet.put("operator", "camera/control", {"roi": [0.5, 0.5, 1.0, 1.0], "budget_bytes": 400,
                                             "request": "none"}, at=0.5)
    fleet.put("rov", "rov/camera", JPEG, encoding="image/jpeg", at=5.0)
    fleet.run_until(30.0)
    last = pictures(fleet)[-1][1]
    assert last["zab:roi"] == "[0.5, 0.5, 1.0, 1.0]"
    assert int(last["zab:budget"]) <= 400


def test_a_request_sends_the_newest_picture_again_and_cancel_stops_it() -> None:
    fleet = FastFleet(load_mission(MISSIONS / "bluerov_images.yaml"), seed=3)
    fleet.put("rov", "rov/camera", JPEG, encoding="image/jpeg", at=0.5)
    fleet.put("operator", "camera/control", {"request": "cancel"}, at=4.0)
    fleet.run_until(15.0)
    cancelled = [s for s in (o.output for o in fleet.outputs if o.node == "rov")
                 if isinstance(s, Status) and s.topic == "delivery/camera"
                 and s.payload["state"] == "failed"]
    assert cancelled and "cancelled by the operator" in cancelled[0].payload["reason"]
    fleet.put("operator", "camera/control", {"request": "now", "budget_bytes": 300}, at=16.0)
    fleet.run_until(40.0)
    finals = [t for _, t, _ in pictures(fleet) if t["zab:final"] == "true"]
    assert finals and int(finals[-1]["zab:budget"]) <= 300


def test_lost_fragments_are_repaired() -> None:
    fleet = FastFleet(load_mission(MISSIONS / "bluerov_images.yaml"), seed=4, loss=0.2)
    fleet.put("rov", "rov/camera", JPEG, encoding="image/jpeg", at=1.0)
    fleet.run_until(120.0)
    got = pictures(fleet)
    assert got and got[-1][1]["zab:final"] == "true"
    fragments = int(got[-1][1]["zab:budget"]) // 37
    assert fleet.cores["rov"].stats.sent_per_channel["camera"] > fragments  # some sent again


def test_bad_pictures_are_counted_drops() -> None:
    text = (MISSIONS / "bluerov_images.yaml").read_text().replace(
        "    policy: finish", "    accept: [jpeg]\n    max_input_pixels: 50000\n    policy: finish")
    fleet = FastFleet(parse_mission(text), seed=5)
    fleet.put("rov", "rov/camera", b"\xff\xd8\xff not really a jpeg", encoding="image/jpeg")
    fleet.put("rov", "rov/camera", write_image(PICTURE, "png"), encoding="image/png")
    fleet.put("rov", "rov/camera", JPEG, encoding="image/jpeg")  # 76800 pixels: too many
    fleet.put("operator", "camera/control", {"roi": [0.9, 0.1, 0.2, 0.5]})
    fleet.run_until(10.0)
    assert fleet.cores["rov"].stats.payloads_dropped["rov/camera"] == 3
    assert fleet.cores["operator"].stats.payloads_dropped["camera/control"] == 1
    assert fleet.published("operator", "rov/camera") == []


def test_a_decompression_bomb_put_on_the_camera_is_a_counted_too_large_drop(
        caplog: pytest.LogCaptureFixture) -> None:
    """A 100-odd-byte PNG declaring 20000 × 20000 pixels: a too_large drop whose log line
    says so, on the key it came on; nothing escapes, nothing crosses; the next picture goes."""
    from tests.image.test_formats import png_declaring

    caplog.set_level(logging.WARNING)
    fleet = FastFleet(load_mission(MISSIONS / "bluerov_images.yaml"), seed=5)
    fleet.put("rov", "rov/camera", png_declaring(20000, 20000), encoding="image/png", at=1.0)
    fleet.run_until(5.0)
    assert fleet.cores["rov"].outbound.drops.by_cause == {("rov/camera", "too_large"): 1}
    assert any("rov/camera" in r.getMessage() and "decompression bomb" in r.getMessage()
               for r in caplog.records)
    assert not [r for r in caplog.records if r.exc_info]
    fleet.put("rov", "rov/camera", JPEG, encoding="image/jpeg", at=6.0)
    fleet.run_until(40.0)
    assert pictures(fleet)[-1][1]["zab:final"] == "true"


def test_a_png_put_as_a_jpeg_is_a_counted_drop_naming_the_mismatch(
        caplog: pytest.LogCaptureFixture) -> None:
    """The sample's encoding and its bytes disagree: neither is trusted, the log says which
    said what (a ROS 2 CompressedImage's format likewise)."""
    from bridge.ros2.messages import encode_cdr

    caplog.set_level(logging.WARNING)
    fleet = FastFleet(load_mission(MISSIONS / "bluerov_images.yaml"), seed=5)
    fleet.put("rov", "rov/camera", write_image(PICTURE, "png"), encoding="image/jpeg", at=1.0)
    fleet.run_until(30.0)
    assert fleet.cores["rov"].outbound.drops.by_cause == {("rov/camera", "unfit"): 1}
    assert any("rov/camera" in r.getMessage() and "the encoding says image/jpeg but the bytes "
               "are a PNG image" in r.getMessage() for r in caplog.records)
    assert fleet.published("operator", "rov/camera") == []
    fleet = FastFleet(parse_mission(ROS2_MISSION % "CompressedImage"), seed=5)
    cdr = encode_cdr("jazzy", "sensor_msgs/msg/CompressedImage",
                     {"format": "jpeg", "data": write_image(PICTURE, "png")})
    fleet.put("rov", "0/rov/camera/*/*", cdr, encoding="", at=1.0)
    fleet.run_until(30.0)
    assert fleet.cores["rov"].outbound.drops.by_cause == {("0/rov/camera/*/*", "unfit"): 1}
    assert fleet.published("operator", "rov/camera") == []


def test_pictures_replaced_while_one_is_in_flight_are_never_decoded(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A camera faster than the water (policy finish): only the picture sent and the newest
    one when it is done are decoded, not the twenty put between (~13 ms each at 1080p)."""
    from bridge.image import formats

    decoded: list[int] = []
    plain = formats._decoded

    def counted(data: bytes, kind: str, colour: bool) -> np.ndarray:
        decoded.append(len(data))
        return plain(data, kind, colour)

    monkeypatch.setattr(formats, "_decoded", counted)
    frames = [write_image(seabed(240, 320, seed=s, colour=False), "jpeg", quality=92)
              for s in range(21)]
    fleet = FastFleet(load_mission(MISSIONS / "bluerov_images.yaml"), seed=3)
    fleet.put("rov", "rov/camera", JPEG, encoding="image/jpeg", at=1.0)
    for i, frame in enumerate(frames):
        fleet.put("rov", "rov/camera", frame, encoding="image/jpeg", at=2.0 + i * 0.2)
    fleet.run_until(90.0)
    assert decoded == [len(JPEG), len(frames[-1])]
    finals = [pixels for _, t, pixels in pictures(fleet) if t["zab:final"] == "true"]
    assert len(finals) == 2
    newest = np.asarray(Image.fromarray(seabed(240, 320, seed=20, colour=False)).resize(
        (160, 120), Image.Resampling.LANCZOS))
    assert psnr(newest, finals[1]) > 30


def test_a_picture_bad_past_its_header_is_a_counted_drop_when_its_turn_comes() -> None:
    fleet = FastFleet(load_mission(MISSIONS / "bluerov_images.yaml"), seed=4)
    fleet.put("rov", "rov/camera", JPEG[:len(JPEG) // 2], encoding="image/jpeg", at=1.0)
    fleet.run_until(10.0)
    assert fleet.cores["rov"].stats.payloads_dropped["rov/camera"] == 1
    assert fleet.published("operator", "rov/camera") == []
    fleet.put("rov", "rov/camera", JPEG, encoding="image/jpeg", at=11.0)  # the next one goes
    fleet.run_until(50.0)
    assert pictures(fleet)[-1][1]["zab:final"] == "true"


ROS2_MISSION = (MISSIONS / "bluerov_images.yaml").read_text().replace(
    "    in: rov/camera\n", "    ros2: {topic: /rov/camera, type: sensor_msgs/msg/%s}\n")


@pytest.mark.parametrize("policy", ["finish", "cancel"])
def test_a_bad_picture_after_a_good_one_does_not_forget_the_good_one(policy: str) -> None:
    """A picture bad past its header put while a good one crosses: a counted drop, and the
    good one goes on to its end and stays the one a request sends again."""
    text = (MISSIONS / "bluerov_images.yaml").read_text().replace(
        "policy: finish", f"policy: {policy}")
    fleet = FastFleet(parse_mission(text), seed=4)
    fleet.put("rov", "rov/camera", JPEG, encoding="image/jpeg", at=1.0)
    fleet.put("rov", "rov/camera", JPEG[:len(JPEG) // 2], encoding="image/jpeg", at=3.0)
    fleet.run_until(40.0)
    assert fleet.cores["rov"].stats.payloads_dropped["rov/camera"] == 1
    finals = [t for _, t, _ in pictures(fleet) if t["zab:final"] == "true"]
    assert len(finals) == 1
    reports = [r["state"] for r in delivery(fleet)]
    assert "failed" not in reports and reports[-1] == "delivered"
    fleet.put("operator", "camera/control", {"request": "now"}, at=41.0)
    fleet.run_until(80.0)
    finals = [t for _, t, _ in pictures(fleet) if t["zab:final"] == "true"]
    assert len(finals) == 2 and finals[1]["zab:sequence"] != finals[0]["zab:sequence"]


def test_a_camera_sized_picture_is_not_over_its_key_s_cap() -> None:
    """The runtime refuses a sample over ``payload_cap`` before the core sees it: a picture
    key's cap is the pictures', not that of the mission's longest channel (16 kB here)."""
    camera = write_image(seabed(480, 640, seed=2, colour=False), "jpeg", quality=92)
    assert len(camera) > 20_000
    for text, key in ((MISSIONS / "bluerov_images.yaml").read_text(), "rov/camera"), \
            (ROS2_MISSION % "CompressedImage", "0/rov/camera/*/*"):
        core = NodeCore(parse_mission(text), "rov")
        assert core.payload_cap(key) >= 1 << 20, key


def test_ros2_compressed_and_raw_pictures_cross() -> None:
    from bridge.ros2.messages import encode_cdr

    small = np.asarray(Image.fromarray(PICTURE).resize((160, 120), Image.Resampling.LANCZOS))
    rgb = np.repeat(small[..., None], 3, axis=2)
    raw = {"height": 120, "width": 160, "encoding": "bgr8", "is_bigendian": 0, "step": 480,
           "data": rgb[..., ::-1].tobytes()}
    for msgtype, tree in (("CompressedImage", {"format": "jpeg", "data": JPEG}),
                          ("Image", raw)):
        fleet = FastFleet(parse_mission(ROS2_MISSION % msgtype), seed=6)
        cdr = encode_cdr("jazzy", f"sensor_msgs/msg/{msgtype}", tree)
        fleet.put("rov", "0/rov/camera/*/*", cdr, encoding="", at=1.0)
        fleet.put("rov", "0/rov/camera/*/*", cdr[:20], encoding="", at=2.0)  # cut: dropped
        fleet.run_until(40.0)
        got = pictures(fleet)
        assert got and got[-1][1]["zab:final"] == "true", msgtype
        assert psnr(small, got[-1][2]) > 30, msgtype
        assert fleet.cores["rov"].stats.payloads_dropped["0/rov/camera/*/*"] == 1


def test_a_raw_camera_s_frames_are_laid_out_only_when_sent(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A ROS 2 camera of raw Images at 30 frames a second: each frame was laid out (and made
    grey) as it came, ~30 ms for 1080p rgb8, so a core went to pictures that were replaced
    before they were sent (`zab sim` at 100 % of a core; 24 % now). Only a frame about to be
    sent is laid out."""
    from bridge.image import formats
    from bridge.ros2.messages import encode_cdr

    laid_out = []
    real = formats._raw_pixels
    monkeypatch.setattr(formats, "_raw_pixels", lambda *a: laid_out.append(1) or real(*a))
    rgb = np.repeat(PICTURE[..., None], 3, axis=2)
    cdr = encode_cdr("jazzy", "sensor_msgs/msg/Image", {
        "height": 240, "width": 320, "encoding": "rgb8", "is_bigendian": 0, "step": 960,
        "data": rgb.tobytes()})
    fleet = FastFleet(parse_mission(ROS2_MISSION % "Image"), seed=6)
    for i in range(300):  # ten seconds of frames
        fleet.put("rov", "0/rov/camera/*/*", cdr, encoding="", at=1.0 + i / 30)
    fleet.run_until(11.0)
    sent = fleet.cores["rov"].stats.sent_per_channel.get("camera", 0)
    assert sent and pictures(fleet)
    assert 1 <= len(laid_out) <= 3, len(laid_out)  # the picture in flight (policy: finish)


def test_a_colour_camera_s_pictures_come_out_as_colour_jpegs() -> None:
    """colour: true and format: jpeg: the operator's viewer gets RGB JPEGs (their metadata as
    JSON in the comment) in the camera's colours, sharpening."""
    import json

    text = (MISSIONS / "bluerov_images.yaml").read_text().replace(
        "    height: 120\n", "    height: 120\n    colour: true\n    format: jpeg\n"
        "    jpeg_quality: 95\n")
    fleet = FastFleet(parse_mission(text), seed=8)
    picture = seabed(240, 320, seed=5)
    picture[80:160, 100:220] = (250, 30, 30)  # a red box on the seabed
    fleet.put("rov", "rov/camera", write_image(picture, "jpeg", quality=95),
              encoding="image/jpeg", at=1.0)
    fleet.run_until(40.0)
    got = []
    for _, p in fleet.published("operator", "rov/camera"):
        assert p.encoding == "image/jpeg"
        image = Image.open(io.BytesIO(p.value))
        assert image.format == "JPEG" and image.mode == "RGB"
        got.append((json.loads(image.info["comment"]), np.asarray(image)))
    assert len(got) >= 10 and got[-1][0]["zab:final"] == "true"
    assert [int(meta["zab:bytes"]) for meta, _ in got] == sorted(
        int(meta["zab:bytes"]) for meta, _ in got)
    small = np.asarray(Image.fromarray(picture).resize((160, 120), Image.Resampling.LANCZOS))
    assert psnr(small, got[-1][1]) > psnr(small, got[0][1]) + 6
    assert psnr(small, got[-1][1]) > 30
    box = got[-1][1][45:75, 55:105].reshape(-1, 3).mean(axis=0)
    assert box[0] > 220 and box[1] < 60 and box[2] < 60, box  # still red


def delivery(fleet: FastFleet) -> list[dict]:
    """The camera's delivery reports, in order."""
    return [o.output.payload for o in fleet.outputs if o.node == "rov"
            and isinstance(o.output, Status) and o.output.topic == "delivery/camera"]


def test_a_camera_sending_on_request_sends_only_the_newest_when_asked() -> None:
    text = (MISSIONS / "bluerov_images.yaml").read_text().replace(
        "    policy: finish", "    send: on_request\n    policy: finish")
    fleet = FastFleet(parse_mission(text), seed=8)
    shots = [seabed(240, 320, seed=s, colour=False) for s in (1, 2, 3)]
    for i, shot in enumerate(shots):
        fleet.put("rov", "rov/camera", write_image(shot, "jpeg", quality=92),
                  encoding="image/jpeg", at=1.0 + i)
    fleet.run_until(20.0)
    assert pictures(fleet) == [] and delivery(fleet) == []  # nothing goes unasked
    fleet.put("operator", "camera/control", {"request": "now"}, at=21.0)
    fleet.run_until(70.0)
    got = pictures(fleet)
    assert got[0][0] > 21.0 and got[-1][1]["zab:final"] == "true"
    assert len({t["zab:sequence"] for _, t, _ in got}) == 1  # one picture: the newest
    small = [np.asarray(Image.fromarray(shot).resize((160, 120), Image.Resampling.LANCZOS))
             for shot in shots]
    assert psnr(small[2], got[-1][2]) > 40 > 30 > max(psnr(s, got[-1][2]) for s in small[:2])
    assert [r["state"] for r in delivery(fleet)] == ["queued", "sent", "delivered"]


def test_a_request_sends_the_last_good_picture_where_the_newest_does_not_decode() -> None:
    text = (MISSIONS / "bluerov_images.yaml").read_text().replace(
        "    policy: finish", "    send: on_request\n    policy: finish")
    fleet = FastFleet(parse_mission(text), seed=8)
    fleet.put("rov", "rov/camera", JPEG, encoding="image/jpeg", at=1.0)
    fleet.put("operator", "camera/control", {"request": "now"}, at=2.0)
    fleet.run_until(40.0)
    fleet.put("rov", "rov/camera", JPEG[:len(JPEG) // 2], encoding="image/jpeg", at=41.0)
    fleet.put("operator", "camera/control", {"request": "now"}, at=42.0)
    fleet.run_until(90.0)
    assert fleet.cores["rov"].stats.payloads_dropped["rov/camera"] == 1
    finals = [t for _, t, _ in pictures(fleet) if t["zab:final"] == "true"]
    assert len(finals) == 2  # the good one, sent again
    assert [r["state"] for r in delivery(fleet)].count("delivered") == 2


def test_a_picture_unfinished_after_its_ttl_is_given_up_for_the_next() -> None:
    """ttl_s 10 against the ~27 s a 1.6 kB picture takes: each is reported failed at 10 s and
    the next one starts; none is shown as final."""
    text = (MISSIONS / "bluerov_images.yaml").read_text().replace(
        "    policy: finish", "    ttl_s: 10\n    policy: finish")
    fleet = FastFleet(parse_mission(text), seed=8)
    fleet.put("rov", "rov/camera", JPEG, encoding="image/jpeg", at=1.0)
    fleet.put("rov", "rov/camera", write_image(seabed(240, 320, seed=2, colour=False), "jpeg"),
              encoding="image/jpeg", at=2.0)
    fleet.run_until(60.0)
    failed = [r for r in delivery(fleet) if r["state"] == "failed"]
    assert [r["reason"] for r in failed] == ["older than ttl_s=10"] * 2
    assert failed[1]["sequence"] == failed[0]["sequence"] + 1
    assert failed[0]["time"] == pytest.approx(12.0, abs=1.0)  # 10 s after it began, at a turn
    got = pictures(fleet)
    assert {t["zab:sequence"] for _, t, _ in got} == {str(r["sequence"]) for r in failed}
    assert all(t["zab:final"] == "false" for _, t, _ in got)
    from bridge.report.check import check_mission  # zab check says so beforehand

    warned = [w for w in check_mission(parse_mission(text)).warnings if "ttl_s" in w]
    assert len(warned) == 1 and warned[0].startswith(
        "image channel 'camera': a picture of 1591 B takes up to ")
    assert warned[0].endswith("more than its ttl_s=10: such a picture is given up unfinished "
                              "(raise ttl_s or lower budget_bytes)")
    assert not [w for w in check_mission(parse_mission(text.replace("ttl_s: 10", "ttl_s: 60"))
                                         ).warnings if "ttl_s" in w]


def test_a_newer_picture_waits_or_cancels_as_the_policy_says() -> None:
    other = write_image(seabed(240, 320, seed=9, colour=False), "jpeg", quality=92)
    for policy in ("finish", "cancel"):
        text = (MISSIONS / "bluerov_images.yaml").read_text().replace(
            "policy: finish", f"policy: {policy}")
        fleet = FastFleet(parse_mission(text), seed=7)
        fleet.put("rov", "rov/camera", JPEG, encoding="image/jpeg", at=1.0)
        fleet.put("rov", "rov/camera", other, encoding="image/jpeg", at=6.0)
        fleet.run_until(80.0)
        finals = [t["zab:sequence"] for _, t, _ in pictures(fleet) if t["zab:final"] == "true"]
        reports = [o.output.payload for o in fleet.outputs if o.node == "rov"
                   and isinstance(o.output, Status) and o.output.topic == "delivery/camera"]
        failed = [r for r in reports if r["state"] == "failed"]
        if policy == "finish":  # both pictures, one after the other
            assert len(finals) == 2 and not failed
        else:  # the first gave way to the second at once
            assert len(finals) == 1
            assert failed and "cancelled by a newer value" in failed[0]["reason"]


def test_steering_answers_the_settings_and_a_control_that_changes_nothing_stays_home() -> None:
    from bridge.runtime.image_queries import control_from_parameters

    fleet = FastFleet(load_mission(MISSIONS / "bluerov_images.yaml"), seed=6)
    images = fleet.cores["operator"].images
    assert images is not None
    sent = fleet.cores["operator"].stats.sent_per_channel["camera.control"]
    settings = images.steer("camera/control", {}, 0.0)
    assert settings == {"width": 160, "height": 120, "budget_bytes": 1600, "roi": None,
                        "request": "none"}
    fleet.run_until(10.0)
    assert fleet.cores["operator"].stats.sent_per_channel["camera.control"] == sent
    asked = control_from_parameters("request=now;roi=0.25,0.25,0.75,0.75;width=80;_timeout=5")
    assert asked == {"request": "now", "roi": [0.25, 0.25, 0.75, 0.75], "width": 80}
    assert control_from_parameters("roi=none") == {"roi": None}
    fleet.put("rov", "rov/camera", JPEG, encoding="image/jpeg", at=10.5)
    settings = images.steer("camera/control", asked, fleet.now)
    assert settings["roi"] == (0.25, 0.25, 0.75, 0.75) and settings["width"] == 80
    try:
        images.steer("camera/control", {"request": "later"}, fleet.now)
    except ValueError as exc:
        assert "request 'later'" in str(exc)
    else:
        raise AssertionError("a bad control was taken")
    assert fleet.cores["operator"].stats.payloads_dropped["camera/control"] == 1
    fleet.run_until(60.0)
    assert pictures(fleet)[-1][2].shape == (60, 80)  # (the picture keeps its proportions)


@pytest.mark.parametrize("control, why", [
    ({"budget_bytes": 100_000}, "budget_bytes 100000 is outside 37..6400"),
    ({"budget_bytes": 10}, "budget_bytes 10 is below one picture's smallest stream"),
    ({"budget_bytes": 36}, "budget_bytes 36 is below one picture's smallest stream, a "
                           "37-byte fragment"),
    ({"width": 0}, "width 0 is outside 8..2048"),
    ({"height": 4096}, "height 4096 is outside 8..2048"),
    ({"width": "abc"}, "width 'abc' is not a whole number"),
    ({"roi": [0.1, 0.1, 0.2]}, "roi [0.1, 0.1, 0.2] is not [x0, y0, x1, y1]"),
    ({"roi": [0.5, 0.5, 0.505, 0.505]}, "narrower than 1/64"),
    ({"width": 160.5}, "width 160.5 is not a whole number"),
    ({"height": True}, "height True is not a whole number"),
    ({"budget_bytes": 800.25}, "budget_bytes 800.25 is not a whole number"),
    ({"budget_bytes": "800"}, "budget_bytes '800' is not a whole number"),
    ({"roi": [0, 0, True, True]}, "roi [0, 0, True, True]: a corner is not a number"),
    ({"roi": [0, 0, "1", 1]}, "roi [0, 0, '1', 1]: a corner is not a number"),
])
def test_a_control_the_camera_would_not_follow_is_refused_not_clamped(
        control: dict, why: str) -> None:
    """The settings a control answers are those the camera applies: a value its control
    channel would clamp (or the ROI's 64ths lose) is refused and counted, nothing crosses."""
    fleet = FastFleet(load_mission(MISSIONS / "bluerov_images.yaml"), seed=6)
    images = fleet.cores["operator"].images
    assert images is not None
    sent = fleet.cores["operator"].stats.sent_per_channel["camera.control"]
    with pytest.raises(ValueError, match=re.escape(why)):
        images.steer("camera/control", {**control, "request": "now"}, 0.0)
    assert fleet.cores["operator"].stats.payloads_dropped["camera/control"] == 1
    assert images.steer("camera/control", {}, 0.0) == {
        "width": 160, "height": 120, "budget_bytes": 1600, "roi": None, "request": "none"}
    fleet.run_until(5.0)
    assert fleet.cores["operator"].stats.sent_per_channel["camera.control"] == sent
    edge = {"width": 8, "height": 2048, "budget_bytes": 6400, "roi": [0.5, 0.5, 0.52, 0.52]}
    assert images.steer("camera/control", edge, 5.0) == {**edge, "roi": (0.5, 0.5, 0.515625,
                                                                  0.515625), "request": "none"}


def test_a_fractional_or_boolean_size_put_by_an_operator_is_a_counted_drop() -> None:
    """A width of 160.5 is not 160 (nor is ``true`` a 1, or an ROI corner of ``true`` a
    1.0): the put is refused as a whole, nothing crosses, the settings stay; a whole number
    written as a float (160.0, as some JSON writers do) is that number."""
    fleet = FastFleet(load_mission(MISSIONS / "bluerov_images.yaml"), seed=6)
    sent = fleet.cores["operator"].stats.sent_per_channel["camera.control"]
    for value in ({"width": 80.5}, {"budget_bytes": True}, {"roi": [0, 0, True, True]}):
        fleet.put("operator", "camera/control", value, at=fleet.now + 0.5)
    fleet.run_until(10.0)
    assert fleet.cores["operator"].stats.payloads_dropped["camera/control"] == 3
    assert fleet.cores["operator"].stats.sent_per_channel["camera.control"] == sent
    images = fleet.cores["operator"].images
    assert images is not None
    assert images.steer("camera/control", {"width": 80.0}, fleet.now)["width"] == 80
    assert images.steer("camera/control", {}, fleet.now)["roi"] is None


def test_a_refused_size_names_its_own_bound() -> None:
    """Only a budget over the channel's max_budget_bytes is said to be over it: a width over
    the control channel's 2048 is not, even when max_budget_bytes is 2048 too."""
    spec = dataclasses.replace(_camera_spec(), largest_budget=2048, fragment_bytes=37)
    with pytest.raises(ValueError) as refused:
        merge_control({}, {"width": 3000}, spec)
    assert str(refused.value) == "width 3000 is outside 8..2048"
    with pytest.raises(ValueError) as refused:
        merge_control({}, {"budget_bytes": 3000}, spec)
    assert str(refused.value) == \
        "budget_bytes 3000 is outside 37..2048 (the channel's max_budget_bytes)"
    with pytest.raises(ValueError) as refused:  # (a corner past a float's range)
        merge_control({}, {"roi": [0, 0, 10 ** 400, 1]}, spec)
    assert str(refused.value).endswith("is not [x0, y0, x1, y1] inside 0..1")


def _camera_spec() -> ImageSpec:
    """bluerov_images' camera channel as both ends see it."""
    table = load_mission(MISSIONS / "bluerov_images.yaml").table
    return next(c.image for c in table.channels if c.image and not c.image.control)


@pytest.mark.parametrize(("control", "out"), [
    ("rov/camera", "rov/camera"),  # the operator's control on the pictures' own key
    ("'{src}/camera'", "'{src}/camera'"),  # the same once each camera's key is filled in
])
def test_a_control_key_that_is_the_pictures_output_is_refused(control: str, out: str) -> None:
    """A viewer on the pictures' key would get the operator's settings among them."""
    text = (MISSIONS / "bluerov_images.yaml").read_text()
    assert "control: camera/control" in text and "out: rov/camera" in text
    text = text.replace("control: camera/control", f"control: {control}").replace(
        "out: rov/camera", f"out: {out}")
    with pytest.raises(MissionProblems) as refused:
        parse_mission(text, "bad.yaml")
    assert "images[0].control: 'rov/camera' at operator is both the pictures' output and the " \
        "operator's control" in str(refused.value)
    parse_mission(text.replace(f"control: {control}", "control: rov/camera/settings"),
                  "good.yaml")


@pytest.mark.parametrize(("out_topic", "error"), [
    ("/{vehicle}/camera", "images[0].ros2.out_topic: unknown template {vehicle} in "
                          "'/{vehicle}/camera'; allowed here: {dst}, {node}, {src}"),
    ("operator/camera", "images[0].ros2.out_topic: 'operator/camera': a ROS 2 topic here "
                        "is absolute"),
    ("/{dst}/1camera", "images[0].ros2.out_topic: with node 'operator': "),
])
def test_a_ros2_pictures_topic_is_checked_with_its_place(out_topic: str, error: str) -> None:
    text = (MISSIONS / "bluerov_images.yaml").read_text().replace(
        "    in: rov/camera\n",
        f"    ros2: {{topic: /rov/camera, out_topic: '{out_topic}'}}\n")
    with pytest.raises(MissionProblems) as refused:
        parse_mission(text, "bad.yaml")
    assert error in str(refused.value)
    parse_mission(text.replace(out_topic, "/{dst}/{src}_camera/compressed"), "good.yaml")


def test_a_zenoh_camera_s_pictures_come_out_on_a_ros2_topic_too() -> None:
    """A camera putting JPEGs on Zenoh, a surface running ROS 2 tools: ``ros2: {out_topic}``
    beside ``in`` publishes each picture as a CompressedImage too, the same file."""
    from rosbags.typesys import Stores, get_typestore

    text = (MISSIONS / "bluerov_images.yaml").read_text().replace(
        "    in: rov/camera\n",
        "    in: rov/camera\n    ros2: {out_topic: /rov/camera/zab/compressed}\n").replace(
        "budget_bytes: 1600", "budget_bytes: 400")
    fleet = FastFleet(parse_mission(text), seed=2)
    fleet.put("rov", "rov/camera", JPEG, encoding="image/jpeg", at=1.0)
    fleet.run_until(60.0)
    files = [p.value for _, p in fleet.published("operator", "rov/camera")]
    ros2 = [(t, p) for t, p in fleet.published("operator") if p.ros2 is not None]
    assert len(files) >= 3 and len(ros2) == len(files)
    assert {p.key for _, p in ros2} == {
        "0/rov/camera/zab/compressed/sensor_msgs::msg::dds_::CompressedImage_/"
        + ros2[0][1].ros2.type_hash}  # type: ignore[union-attr]
    typestore = get_typestore(Stores.ROS2_JAZZY)
    for file, (t, p) in zip(files, ros2, strict=True):
        assert p.ros2 is not None
        message = typestore.deserialize_cdr(p.ros2.encode(p.value, t),
                                            "sensor_msgs/msg/CompressedImage")
        assert bytes(message.data) == file and message.format == "mono8; png compressed mono8"


@pytest.mark.parametrize(("ros2", "error"), [
    ("{topic: /rov/camera, out_topic: /rov/pictures}",
     "give the pictures' input: either `in` or `ros2.topic`"),
    ("{frame_id: camera}", "ros2 needs topic (a camera to read), out_topic (a topic to "
                           "publish the pictures on) or both"),
])
def test_a_camera_has_one_input_and_a_ros2_block_a_use(ros2: str, error: str) -> None:
    text = (MISSIONS / "bluerov_images.yaml").read_text().replace(
        "    in: rov/camera\n", f"    in: rov/camera\n    ros2: {ros2}\n")
    with pytest.raises(MissionProblems) as refused:
        parse_mission(text, "bad.yaml")
    assert error in str(refused.value)


def test_fragments_shorter_than_an_roi_s_header_are_no_malformed_stream() -> None:
    """12-byte fragments: the first holds part of the ROI's 13-byte header (it was counted
    as a malformed frame and logged)."""
    text = (MISSIONS / "bluerov_images.yaml").read_text().replace(
        "modem: {frame_bytes: 57}", "modem: {frame_bytes: 24}").replace(
        "    budget_bytes: 1600\n", "    budget_bytes: 400\n    roi: [0.25, 0.25, 0.75, 0.75]\n")
    loaded = parse_mission(text)
    assert next(c for c in loaded.table.channels if c.name == "camera").chunk_bytes < 13
    fleet = FastFleet(loaded, seed=1)
    fleet.put("rov", "rov/camera", JPEG, encoding="image/jpeg", at=1.0)
    fleet.run_until(200.0)
    assert pictures(fleet)[-1][1]["zab:final"] == "true"
    assert not fleet.cores["operator"].stats.frames_dropped


TWO_CAMERAS = (MISSIONS / "bluerov_images.yaml").read_text().replace(
    "    modem: {frame_bytes: 57}\n",
    "    modem: {frame_bytes: 57}\n  rov2:\n    address: 3\n"
    "    zenoh: {listen: [tcp/127.0.0.1:7663]}\n    position: {x: 1, y: 1, depth: 0.8}\n"
    "    modem: {frame_bytes: 57}\n").replace(
    "    from: rov\n    to: operator\n    in: rov/camera\n    out: rov/camera\n"
    "    control: camera/control\n",
    "    from: [rov, rov2]\n    to: operator\n    in: '{node}/camera'\n    out: '{src}/camera'\n"
    "%s").replace("    budget_bytes: 1600\n", "    budget_bytes: 400\n")


@pytest.mark.parametrize(("control", "key", "steered"), [
    ("", "rov2/camera/control", {"rov2"}),  # default <out>/control: a key per camera
    ("    control: cameras/control\n", "cameras/control", {"rov", "rov2"}),  # every camera
])
def test_several_cameras_are_steered_one_by_one_or_all_at_once(
        control: str, key: str, steered: set[str]) -> None:
    fleet = FastFleet(parse_mission(TWO_CAMERAS % control), seed=8)
    images = fleet.cores["operator"].images
    assert images is not None and key in images.controls
    fleet.put("operator", key, {"roi": [0.5, 0.5, 1.0, 1.0]}, at=1.0)
    for camera in ("rov", "rov2"):
        fleet.put(camera, f"{camera}/camera", JPEG, encoding="image/jpeg", at=10.0)
    fleet.run_until(120.0)
    for camera in ("rov", "rov2"):
        finals = [Image.open(io.BytesIO(p.value)).text for _, p in  # type: ignore[attr-defined]
                  fleet.published("operator", f"{camera}/camera")]
        assert finals and finals[-1]["zab:final"] == "true", camera
        assert finals[-1]["zab:roi"] == ("[0.5, 0.5, 1.0, 1.0]" if camera in steered
                                         else "null"), camera


def test_a_camera_s_own_control_key_under_its_keyspace_is_answered_at_the_operator() -> None:
    """``rov2/camera/control`` lies under rov2's keyspace: the operator's bridge, which
    answers gets on it, must not also reply that nothing maps the key."""
    core = NodeCore(parse_mission(TWO_CAMERAS % ""), "operator")
    assert core.outbound.keyspace.unanswered("rov2/camera/control") is None
    assert core.outbound.keyspace.maps("rov2/camera/control")
    assert core.outbound.keyspace.unanswered("rov2/camera/elsewhere") is not None


def test_a_get_on_a_picture_s_key_has_no_error_beside_the_picture() -> None:
    """The receiver's pictures are latched (a late viewer's get has the latest): the key,
    under the camera's keyspace, is not also answered with "nothing maps this key"."""
    for text, camera in ((MISSIONS / "bluerov_images.yaml").read_text(), "rov"), \
            (TWO_CAMERAS % "", "rov2"):
        keyspace = NodeCore(parse_mission(text), "operator").outbound.keyspace
        assert keyspace.unanswered(f"{camera}/camera") is None
        assert keyspace.unanswered(f"{camera}/camera/**") is None


@pytest.mark.parametrize("priority", [None, 2])
def test_two_cameras_of_one_priority_share_the_water_a_higher_one_goes_first(
        priority: int | None) -> None:
    """A forward and a down camera on one ROV: at one priority their fragments take turns,
    so each shows a first picture within seconds; at a higher priority the down camera's
    picture crosses whole first."""
    text = (MISSIONS / "bluerov_images.yaml").read_text() + (
        "  - name: down\n    from: rov\n    to: operator\n    in: rov/down\n    out: rov/down\n"
        "    width: 160\n    height: 120\n    budget_bytes: 800\n"
        + (f"    priority: {priority}\n" if priority else ""))
    fleet = FastFleet(parse_mission(text), seed=3)
    fleet.put("rov", "rov/camera", JPEG, encoding="image/jpeg", at=1.0)
    fleet.put("rov", "rov/down", JPEG, encoding="image/jpeg", at=1.0)
    fleet.run_until(80.0)
    times = {key: [t for t, _ in fleet.published("operator", key)]
             for key in ("rov/camera", "rov/down")}
    finals = {key: [t for t, p in fleet.published("operator", key)
                    if Image.open(io.BytesIO(p.value)).text["zab:final"] == "true"]  # type: ignore[attr-defined]
              for key in times}
    assert all(finals.values())
    if priority is None:
        assert max(times["rov/camera"][0], times["rov/down"][0]) < 1.0 + 5.0
        assert finals["rov/camera"][0] > finals["rov/down"][0]  # (twice the bytes)
    else:
        assert finals["rov/down"][0] < times["rov/camera"][0]
    from bridge.report.check import check_mission  # zab check's bound holds, turns shared

    bound = {i["name"]: i for i in check_mission(parse_mission(text)).data["images"]}
    assert bound["camera"]["shares_turns_with"] == ["down"]
    assert bound["down"]["shares_turns_with"] == ([] if priority else ["camera"])
    for name, key in (("camera", "rov/camera"), ("down", "rov/down")):
        assert finals[key][0] - 1.0 <= bound[name]["seconds_per_picture"]


def test_an_operator_s_control_lost_in_the_water_is_sent_again_within_a_few_polls() -> None:
    """Seed 002's link polls the ROV every 640 ms: a control (here a budget) lost on the way,
    or whose acknowledgement is, goes again a couple of polls later, not after ten seconds."""
    fleet = FastFleet(load_mission(MISSIONS / "bluerov_images.yaml"), seed=4, loss=0.2)
    puts = [2.0 + 6.0 * i for i in range(30)]
    for i, at in enumerate(puts):
        fleet.put("operator", "camera/control", {"budget_bytes": 400 + 40 * (i % 2)}, at=at)
    fleet.run_until(puts[-1] + 30.0)
    reports = [o.output.payload for o in fleet.outputs if o.node == "operator"
               and isinstance(o.output, Status) and o.output.topic == "delivery/camera.control"]
    delivered = {r["id"]: r["time"] for r in reports if r["state"] == "delivered"}
    assert sorted(delivered) == list(range(len(puts)))
    waits = sorted(delivered[i] - at for i, at in enumerate(puts))
    assert waits[len(waits) // 2] < 1.5  # most at once
    assert max(waits) > 1.5  # some were lost, and repaired
    assert waits[int(0.9 * len(waits))] < 6.0  # (10.6 s when the first retry waited 10 s)


def test_an_operator_s_control_put_while_the_link_is_down_arrives_when_it_comes_back() -> None:
    """Settings are state, not a command: the control is sent again until it arrives, over a
    ten-minute outage too, however fast the link retries."""
    fleet = FastFleet(load_mission(MISSIONS / "bluerov_images.yaml"), seed=5)
    fleet.call_at(5.0, lambda: setattr(fleet.ocean, "loss", 1.0))
    fleet.call_at(605.0, lambda: setattr(fleet.ocean, "loss", 0.0))
    fleet.put("operator", "camera/control", {"roi": [0.5, 0.5, 1.0, 1.0]}, at=10.0)
    fleet.put("rov", "rov/camera", JPEG, encoding="image/jpeg", at=620.0)
    fleet.run_until(660.0)
    reports = [o.output.payload for o in fleet.outputs if o.node == "operator"
               and isinstance(o.output, Status) and o.output.topic == "delivery/camera.control"]
    assert reports[-1]["state"] == "delivered" and 605.0 < reports[-1]["time"] < 615.0
    got = pictures(fleet)
    assert got and json.loads(got[-1][1]["zab:roi"]) == [0.5, 0.5, 1.0, 1.0]


def test_a_refinement_held_back_by_the_publish_interval_shows_when_the_link_pauses() -> None:
    """At most one picture every 5 s, and the link lost 11.5 s in, after a fragment that came
    too soon to be shown (at 11.3 s, the last shown at 6.8 s): it is published once the
    interval is over, not when (if ever) the next fragment comes."""
    text = (MISSIONS / "bluerov_images.yaml").read_text().replace(
        "publish_interval_s: 1.0", "publish_interval_s: 5.0")
    fleet = FastFleet(parse_mission(text), seed=6)
    fleet.put("rov", "rov/camera", JPEG, encoding="image/jpeg", at=1.0)
    fleet.call_at(11.5, lambda: setattr(fleet.ocean, "loss", 1.0))
    fleet.run_until(40.0)
    came = [(o.time, o.output.payload["bytes"]) for o in fleet.outputs if o.node == "operator"
            and isinstance(o.output, Status) and o.output.topic == "transfer/camera"]
    got = pictures(fleet)
    assert int(got[-1][1]["zab:bytes"]) == came[-1][1] and got[-1][1]["zab:final"] == "false"
    assert came[-1][0] - got[-2][0] < 5.0 <= got[-1][0] - got[-2][0] < 5.0 + 1.0
    assert all(b - a >= 5.0 for (a, _, _), (b, _, _) in itertools.pairwise(got))


def test_a_camera_s_log_lines_name_its_own_input_key_not_the_mission_s_template(
        caplog: pytest.LogCaptureFixture) -> None:
    """Where the mission's input key is a template ('{node}/camera'), the camera's lines
    name the key its application puts on (rov2/camera): a request before any picture, and a
    picture kept across a restart (saved without its key) that does not decode."""
    caplog.set_level(logging.WARNING)
    fleet = FastFleet(parse_mission(TWO_CAMERAS % ""), seed=8)
    fleet.put("operator", "rov2/camera/control", {"request": "now"}, at=1.0)
    fleet.run_until(20.0)
    asked = [r.getMessage() for r in caplog.records if "since this bridge started" in
             r.getMessage()]
    assert asked and all("rov2/camera" in m and "{node}" not in m for m in asked)
    images = fleet.cores["rov2"].images
    assert images is not None
    camera = images.inputs["rov2/camera"]
    camera.restore({**camera.state(), "latest": [JPEG[:len(JPEG) // 2], "image/jpeg", None,
                                                  None]})
    fleet.put("operator", "rov2/camera/control", {"request": "now"}, at=21.0)
    fleet.run_until(40.0)
    assert fleet.cores["rov2"].outbound.drops.by_cause == {("rov2/camera", "undecodable"): 1}


def test_sixteen_pictures_in_a_burst_do_not_reuse_the_sequence_the_operator_holds() -> None:
    """Sequence numbers wrap at 16: with policy cancel, the last of a burst of 16 pictures
    took the number of the picture the operator had finished, and the operator took its
    fragments for that picture's (ignored) while the camera reported it delivered. The
    camera skips the number each receiver last acknowledged."""
    text = (MISSIONS / "bluerov_images.yaml").read_text().replace(
        "policy: finish", "policy: cancel")
    fleet = FastFleet(parse_mission(text), seed=7)
    fleet.put("rov", "rov/camera", JPEG, encoding="image/jpeg", at=1.0)
    fleet.run_until(40.0)
    first = [t for _, t, _ in pictures(fleet) if t["zab:final"] == "true"]
    assert len(first) == 1
    shots = [seabed(240, 320, seed=100 + i, colour=False) for i in range(16)]
    for shot in shots:
        fleet.put("rov", "rov/camera", write_image(shot, "jpeg", quality=92),
                  encoding="image/jpeg", at=41.0)
    fleet.run_until(100.0)
    got = [(t, pixels) for _, t, pixels in pictures(fleet) if t["zab:final"] == "true"]
    assert len(got) == 2, [t["zab:sequence"] for t, _ in got]
    assert got[1][0]["zab:sequence"] != first[0]["zab:sequence"]
    newest = np.asarray(Image.fromarray(shots[-1]).resize((160, 120), Image.Resampling.LANCZOS))
    assert psnr(newest, got[1][1]) > 30
    delivered = [r for r in delivery(fleet) if r["state"] == "delivered"]
    assert len(delivered) == 2 and delivered[1]["sequence"] == int(got[1][0]["zab:sequence"])


def test_a_budget_is_honoured_or_refused_never_exceeded() -> None:
    """A budget of 16 bytes cannot be kept (a picture crosses in whole fragments, 37 bytes
    here): it is refused saying what the least is, not answered with a 37-byte picture; a
    budget between fragments gets the whole fragments it holds (100: two, 74 bytes)."""
    fleet = FastFleet(load_mission(MISSIONS / "bluerov_images.yaml"), seed=6)
    images = fleet.cores["operator"].images
    assert images is not None
    fleet.put("operator", "camera/control", {"budget_bytes": 16}, at=0.5)
    fleet.put("rov", "rov/camera", JPEG, encoding="image/jpeg", at=1.0)
    fleet.run_until(2.0)
    assert fleet.cores["operator"].stats.payloads_dropped["camera/control"] == 1
    assert images.steer("camera/control", {}, fleet.now)["budget_bytes"] == 1600
    fleet.put("operator", "camera/control", {"budget_bytes": 100, "request": "cancel"},
              at=3.0)
    fleet.put("operator", "camera/control", {"request": "now"}, at=4.0)
    fleet.run_until(60.0)
    last = pictures(fleet)[-1][1]
    assert last["zab:final"] == "true" and int(last["zab:budget"]) == 74


def test_a_mission_budget_below_one_fragment_is_refused_saying_why() -> None:
    text = (MISSIONS / "bluerov_images.yaml").read_text().replace(
        "budget_bytes: 1600", "budget_bytes: 16")
    with pytest.raises(MissionProblems, match="budget_bytes 16 is below one picture's "
                                              "smallest stream, a 37-byte fragment"):
        parse_mission(text)


def test_the_wire_knows_the_stream_header_the_codec_writes() -> None:
    from bridge.image.codec import header_bytes
    from bridge.wire.images import STREAM_HEADER_BYTES

    assert header_bytes(True) == STREAM_HEADER_BYTES
