"""Image channels across restarts (virtual clock, each node killed and started again from
its last saved state): the operator's settings hold at both ends, a picture waiting behind
the one in flight still goes, and ``request: now`` sends the last picture again."""

from __future__ import annotations

import io

import numpy as np
from PIL import Image

from bridge.core.images import KEEP_PICTURE_S, STATE_PICTURE_BYTES
from bridge.core.loaded import load_mission
from bridge.core.node import NodeCore
from bridge.image.formats import write_image
from bridge.image.synthetic import seabed
from bridge.runtime.virtual_fleet import FastFleet
from tests.conftest import MISSIONS

FIRST = seabed(240, 320, seed=5, colour=False)
SECOND = seabed(240, 320, seed=9, colour=False)
ROI = "[0.5, 0.5, 1.0, 1.0]"


def jpeg(pixels: np.ndarray) -> bytes:
    return write_image(pixels, "jpeg", quality=92)


def finals(fleet: FastFleet) -> list[tuple[dict[str, str], np.ndarray]]:
    """The final pictures the operator published: PNG text and pixels."""
    out = []
    for _, p in fleet.published("operator", "rov/camera"):
        image = Image.open(io.BytesIO(p.value))
        text = dict(image.text)  # type: ignore[attr-defined]
        if text["zab:final"] == "true":
            out.append((text, np.asarray(image)))
    return out


def like(pixels: np.ndarray, shown: np.ndarray) -> float:
    """PSNR (dB) of ``shown`` against ``pixels`` scaled to the channel's 160 × 120."""
    small = np.asarray(Image.fromarray(pixels).resize((160, 120), Image.Resampling.LANCZOS))
    mse = float(np.mean((small.astype(float) - shown.astype(float)) ** 2))
    return 10 * np.log10(255 ** 2 / max(mse, 1e-9))


def test_a_restarted_camera_keeps_the_operator_s_settings() -> None:
    fleet = FastFleet(load_mission(MISSIONS / "bluerov_images.yaml"), seed=11)
    fleet.put("operator", "camera/control", {"roi": [0.5, 0.5, 1.0, 1.0], "budget_bytes": 400},
              at=0.5)
    fleet.run_until(20.0)
    fleet.restart("rov")
    fleet.put("rov", "rov/camera", jpeg(FIRST), encoding="image/jpeg", at=21.0)
    fleet.run_until(60.0)
    (text, _), = finals(fleet)
    assert text["zab:roi"] == ROI and int(text["zab:budget"]) <= 400


def test_after_both_restart_a_request_sends_the_last_picture_with_the_settings_held() -> None:
    """The operator's bridge keeps its settings (a control merges into them: ``request: now``
    alone must not put the mission's back), the camera's the last picture it sent."""
    fleet = FastFleet(load_mission(MISSIONS / "bluerov_images.yaml"), seed=12)
    fleet.put("operator", "camera/control", {"roi": [0.5, 0.5, 1.0, 1.0], "budget_bytes": 400},
              at=0.5)
    fleet.put("rov", "rov/camera", jpeg(FIRST), encoding="image/jpeg", at=5.0)
    fleet.run_until(60.0)
    assert len(finals(fleet)) == 1
    fleet.restart("operator")
    fleet.restart("rov")
    fleet.put("operator", "camera/control", {"request": "now"}, at=61.0)
    fleet.run_until(120.0)
    first, again = finals(fleet)
    assert again[0]["zab:sequence"] != first[0]["zab:sequence"]
    assert again[0]["zab:roi"] == ROI and int(again[0]["zab:budget"]) <= 400
    assert like(FIRST, again[1]) > 20


def test_a_picture_waiting_behind_the_one_in_flight_survives_a_restart() -> None:
    fleet = FastFleet(load_mission(MISSIONS / "bluerov_images.yaml"), seed=13)  # finish
    fleet.put("rov", "rov/camera", jpeg(FIRST), encoding="image/jpeg", at=1.0)
    fleet.put("rov", "rov/camera", jpeg(SECOND), encoding="image/jpeg", at=3.0)
    fleet.run_until(8.0)
    fleet.restart("rov")
    fleet.run_until(150.0)
    shown = finals(fleet)
    assert len(shown) == 2
    assert like(FIRST, shown[0][1]) > 30 and like(SECOND, shown[1][1]) > 30


def test_a_picture_over_the_state_s_share_is_not_saved() -> None:
    """Saved state stays small: a picture longer than STATE_PICTURE_BYTES is not in it (a
    restart before it is sent loses it), a shorter one is."""
    core = NodeCore(load_mission(MISSIONS / "bluerov_images.yaml"), "rov")
    noise = np.random.default_rng(1).integers(0, 256, (600, 600), dtype=np.uint8)
    big = write_image(noise, "png")
    assert len(big) > STATE_PICTURE_BYTES
    core.ingest("rov/camera", big, "image/png", 1.0)
    assert core.state()["senders"]["camera"]["last"] is None
    core.ingest("rov/camera", jpeg(FIRST), "image/jpeg", 2.0)  # waits (policy finish)
    assert bytes(core.state()["senders"]["camera"]["latest"][0]) == jpeg(FIRST)


def test_a_fast_camera_asks_for_a_save_at_most_once_a_second() -> None:
    """Pictures that only wait (one in flight, policy finish) go with the node's next save;
    on their own they ask for one at most every KEEP_PICTURE_S."""
    core = NodeCore(load_mission(MISSIONS / "bluerov_images.yaml"), "rov")
    frames = [jpeg(seabed(120, 160, seed=s, colour=False)) for s in range(12)]
    asked = []
    for i, frame in enumerate(frames):
        core.saved()
        core.ingest("rov/camera", frame, "image/jpeg", 1.0 + i * KEEP_PICTURE_S / 8)
        asked.append(core.needs_save)
    assert asked == [True] + [False] * 7 + [True] + [False] * 3  # (0: the transfer began)
    assert bytes(core.state()["senders"]["camera"]["latest"][0]) == frames[-1]
