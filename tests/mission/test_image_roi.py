"""One ROI rule and one message everywhere: the mission's ``roi``, an operator's put and a get's
``roi=`` parameters. A get with ``roi=0.5,0.5,0.5,0.5`` was told it is not inside 0..1 (it
is: it is empty); the mission took ``roi: [0.5, 0.5, 0.505, 0.505]``, which a control refuses
as narrower than 1/64, and widened it at run time to 0.515625."""

from __future__ import annotations

import pytest

from bridge.core.loaded import load_mission, parse_mission
from bridge.errors import MissionError
from bridge.image.geometry import Roi
from bridge.runtime.image_queries import control_from_parameters
from bridge.wire.images import ImageSpec, merge_control
from tests.conftest import MISSIONS

TEXT = (MISSIONS / "bluerov_images.yaml").read_text()
CAMERA = "  - name: camera\n"
EMPTY = "is empty (x1 must be > x0 and y1 > y0)"
NARROW = "is narrower than 1/64 of the picture"


def with_roi(roi: str) -> str:
    assert TEXT.count(CAMERA) == 1
    return TEXT.replace(CAMERA, f"{CAMERA}    roi: {roi}\n")


def camera(text: str) -> ImageSpec:
    table = parse_mission(text, "m.yaml").table
    return next(c.image for c in table.channels if c.image and not c.image.control)


@pytest.mark.parametrize(("roi", "why"), [
    ("[0.5, 0.5, 0.5, 0.5]", EMPTY),
    ("[0.8, 0.2, 0.1, 0.9]", EMPTY),
    ("[0.5, 0.5, 0.505, 0.505]", NARROW),
    ("[0.2, 0.2, 0.9, 0.205]", NARROW),
])
def test_the_mission_s_roi_is_refused_where_a_control_s_is(roi: str, why: str) -> None:
    line = 1 + TEXT[:TEXT.index(CAMERA)].count("\n") + 1
    with pytest.raises(MissionError) as info:
        parse_mission(with_roi(roi), "m.yaml")
    first = str(info.value).splitlines()[0]
    assert first.startswith(f"m.yaml:{line}:") and ": images[0].roi: " in first, first
    assert first.endswith(f"roi {roi} {why}" + (
        " (each corner is taken to its nearest 1/64)" if why == NARROW else "")), first
    spec = load_mission(MISSIONS / "bluerov_images.yaml").table.by_name("camera").image
    assert spec is not None
    with pytest.raises(ValueError) as control:  # the same words for a put (or a get)
        merge_control({}, {"roi": [float(v) for v in roi.strip("[]").split(",")]}, spec)
    assert first.endswith(str(control.value)), (first, str(control.value))


@pytest.mark.parametrize(("parameters", "why"), [
    ("roi=0.5,0.5,0.5,0.5", f"roi [0.5, 0.5, 0.5, 0.5] {EMPTY}"),
    ("roi=0.5,0.5,0.505,0.505", f"roi [0.5, 0.5, 0.505, 0.505] {NARROW}"),
    ("roi=0.5,0.5,1.5,0.6", "roi [0.5, 0.5, 1.5, 0.6] is not [x0, y0, x1, y1] inside 0..1"),
])
def test_a_get_s_roi_is_told_what_is_wrong_with_it(parameters: str, why: str) -> None:
    spec = camera(TEXT)
    with pytest.raises(ValueError) as refused:
        merge_control({}, control_from_parameters(parameters), spec)
    assert str(refused.value).startswith(why), str(refused.value)


def test_the_mission_s_roi_is_the_64ths_a_control_would_set() -> None:
    """Corners taken to their nearest 64th, as a control's (the camera drew a wider ROI from
    the mission's, each corner widened outwards)."""
    spec = camera(with_roi("[0.1, 0.1, 0.3, 0.51]"))
    settings: dict = {}
    merge_control(settings, {"roi": [0.1, 0.1, 0.3, 0.51]}, spec)
    assert spec.roi == settings["roi"] == (6 / 64, 6 / 64, 19 / 64, 33 / 64)
    assert Roi.from_fractions(*spec.roi).fractions() == spec.roi  # applied as it says
