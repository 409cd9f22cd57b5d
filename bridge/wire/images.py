"""Image channels as the wire sees them: each is two channels after the mission's own.

- the *stream* (``<name>``): the progressive picture's bytes as a fragmented transfer from
  the camera node, one transfer per picture (its transfer id is the picture's sequence
  number), fragments of at most ``share`` of a frame;
- the *control* (``<name>.control``): the operator's settings and requests from each
  receiving node back to the camera, a reliable channel of :data:`CONTROL_FIELDS` (and,
  with several cameras, the one it steers).

:class:`ImageSpec` is what both ends need of the mission's
:class:`~bridge.mission.images.ImageChannel`; :func:`control_layout` the control's fields.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from bridge.codec import Layout
from bridge.mission.fields import FieldSpec
from bridge.mission.images import ImageChannel, roi_applied

if TYPE_CHECKING:
    from bridge.ros2.element import Ros2Element

__all__ = ["CONTROL_BOUNDS", "CONTROL_FIELDS", "CONTROL_TTL_S", "PICTURE_METADATA", "REQUESTS",
           "STREAM_HEADER_BYTES", "ImageSpec", "control_layout", "control_payload", "merge_control"]

STREAM_HEADER_BYTES = 13
"""Bytes of a progressive stream's header with a region of interest (``bridge.image.codec``'s
``header_bytes(True)``): a picture's smallest stream is the whole fragments that hold it."""

REQUESTS = ("none", "now", "cancel")
"""What an operator's control asks besides settings: nothing more, a picture now, or that the
picture in flight be cancelled."""

CONTROL_FIELDS: tuple[dict[str, Any], ...] = (
    {"field": "request", "type": "enum", "values": list(REQUESTS)},
    {"field": "width", "type": "int", "min": 8, "max": 2048},
    {"field": "height", "type": "int", "min": 8, "max": 2048},
    {"field": "budget_bytes", "type": "int", "min": 16, "max": 65536},
    {"field": "roi_on", "type": "bool"},
    *({"field": f, "type": "int", "min": 0, "max": 64} for f in ("x0", "y0", "x1", "y1")),
)

CONTROL_TTL_S = 3600.0
"""How long an operator's control is sent again until it arrives: settings are state, so they
cross when the link comes back (retries are not counted: a fast link, retrying every second or
so, would use them up in a minute's outage); older than this, it is reported failed."""

CONTROL_BOUNDS = {f["field"]: (f["min"], f["max"]) for f in CONTROL_FIELDS if "min" in f}
"""The settings' bounds on the control channel (a control outside them is refused)."""

PICTURE_METADATA = {
    "channel": "the image channel's name",
    "src": "the camera's node",
    "sequence": "the picture's sequence number (its transfer id, 0-15)",
    "bytes": "bytes of the picture's stream received so far",
    "budget": "bytes of its whole stream",
    "final": "the last picture of this stream (true once)",
    "width": "width in pixels",
    "height": "height in pixels",
    "psnr_estimate": "the stream's own estimate of its luma PSNR, dB",
    "roi": "the region of interest [x0, y0, x1, y1] in fractions, or null",
    "time": "when the receiving bridge published it (s, its clock)",
}
"""What a receiving bridge writes in each picture it publishes (PNG text, a JPEG's JSON
comment), each as ``zab:<key>``, JSON but for text (and on its ``images/<name>/<src>``
status)."""


@dataclass(frozen=True)
class ImageSpec:
    """One image channel's settings, as compiled for the wire (``control``: this channel is
    its control, not its stream)."""

    name: str
    in_key: str
    out_key: str
    control_key: str
    width: int
    height: int
    colour: bool
    budget_bytes: int
    largest_budget: int
    roi: tuple[float, float, float, float] | None
    policy: str
    send: str
    publish_interval_s: float
    format: str
    jpeg_quality: int
    accept: tuple[str, ...]
    max_input_pixels: int
    ros2: Ros2Element | None = None  # a ROS 2 camera topic, instead of in_key's bytes
    ros2_out: Ros2Element | None = None  # the pictures as CompressedImages too, at receivers
    control: bool = False
    fragment_bytes: int = 0
    """The stream's fragment size (set once the frames' sizes give it)."""

    @property
    def smallest_budget(self) -> int:
        """The least budget a picture keeps: the whole fragments its header takes (a
        fragment crosses whole, so a budget below it would be exceeded)."""
        chunk = self.fragment_bytes
        return chunk * -(-STREAM_HEADER_BYTES // chunk) if chunk else 1

    def smallest_stream(self) -> str:
        """:attr:`smallest_budget` in words."""
        chunk = self.fragment_bytes
        fragments = self.smallest_budget // chunk if chunk else 0
        return (f"a {chunk}-byte fragment" if fragments == 1 else
                f"{fragments} fragments of {chunk} bytes")

    @classmethod
    def from_mission(cls, image: ImageChannel,
                     ros2: tuple[Ros2Element | None, Ros2Element | None] = (None, None)
                     ) -> ImageSpec:
        """``ros2``: the channel's ROS 2 camera and pictures' topic, compiled
        (:func:`~bridge.ros2.element.compile_camera`), where it has them."""
        in_key = image.in_ if ros2[0] is None else ros2[0].in_key
        assert in_key is not None
        return cls(image.name, in_key, image.out, image.control_key, image.width,
                   image.height, image.colour, image.budget_bytes, image.largest_budget,
                   image.roi, image.policy, image.send, image.publish_interval_s, image.format,
                   image.jpeg_quality, tuple(image.accept), image.max_input_pixels,
                   *ros2)

    def input_key(self, camera: str) -> str:
        """The key ``camera`` takes its pictures on."""
        return self.in_key.format(node=camera, src=camera)

    def output_key(self, src: str, dst: str) -> str:
        """The key ``dst`` publishes ``src``'s pictures on."""
        return self.out_key.format(node=dst, src=src, dst=dst)

    def ros2_output_key(self, src: str, dst: str) -> str | None:
        """The ROS 2 topic's key ``dst`` publishes ``src``'s pictures on too, if any."""
        if self.ros2_out is None:
            return None
        return self.ros2_out.out_key.format(node=dst, src=src, dst=dst)

    def describe(self) -> list[Any]:
        """What both ends must agree on (the fingerprint): the stream's format."""
        return [self.colour, self.largest_budget, "control" if self.control else "stream"]


def control_layout(cameras: int = 1) -> Layout:
    """The control's fields; with several ``cameras``, which one it steers (``camera``: its
    number in the channel's ``from`` order, 1 first; 0: every camera)."""
    fields = [*CONTROL_FIELDS, *([{"field": "camera", "type": "int", "min": 0,
                                   "max": cameras}] if cameras > 1 else [])]
    return Layout.from_fields([FieldSpec.model_validate(f) for f in fields],
                              on_out_of_range="clamp")


def control_payload(settings: dict[str, Any], request: str,
                    camera: int | None = None) -> dict[str, Any]:
    """The control channel's value for ``settings`` (width, height, budget_bytes, roi as
    fractions or None) and ``request``, to ``camera`` (see :func:`control_layout`; None: a
    channel of one camera)."""
    roi = settings.get("roi")
    corners = [round(v * 64) for v in roi] if roi else [0, 0, 64, 64]
    return {"request": request, "width": settings["width"], "height": settings["height"],
            "budget_bytes": settings["budget_bytes"], "roi_on": roi is not None,
            **dict(zip(("x0", "y0", "x1", "y1"), corners, strict=True)),
            **({"camera": camera} if camera is not None else {})}


def merge_control(settings: dict[str, Any], value: Any, spec: ImageSpec) -> str:
    """Merge an operator's control (any subset of request, width, height, budget_bytes, roi)
    into ``settings``, as the camera of ``spec`` applies it; returns its request. A value the
    camera would not follow as given (its control channel would clamp it, an ROI narrower
    than its 64ths, a budget below a picture's fewest fragments, which would exceed it) is a
    :class:`ValueError` and ``settings`` stay; an ROI's corners are kept as the 64ths the
    camera applies. The one check of a control: the bridge's and the GUI's."""
    if not isinstance(value, dict):
        raise ValueError("a control is a map: {request, width, height, budget_bytes, roi}")
    unknown = set(value) - {"request", "width", "height", "budget_bytes", "roi"}
    if unknown:
        raise ValueError(f"unknown control {', '.join(sorted(map(str, unknown)))}")
    request = value.get("request", "none")
    if request not in REQUESTS:
        raise ValueError(f"request {request!r} is none of {', '.join(REQUESTS)}")
    new: dict[str, Any] = {name: _size(name, value[name], spec)
                           for name in ("width", "height", "budget_bytes") if name in value}
    if "roi" in value:
        new["roi"] = roi_applied(value["roi"])
    settings.update(new)
    return str(request)


def _size(name: str, value: Any, spec: ImageSpec) -> int:
    """A control's width, height or budget_bytes, checked against the control channel's
    bounds (and a budget against ``spec``'s)."""
    low, high = CONTROL_BOUNDS[name]
    number = _whole(value)
    if number is None:
        raise ValueError(f"{name} {value!r} is not a whole number")
    bounded = ""
    if name == "budget_bytes":
        if number < spec.smallest_budget:
            raise ValueError(f"budget_bytes {number} is below one picture's smallest stream, "
                             f"{spec.smallest_stream()} (a fragment crosses whole)")
        low = max(low, spec.smallest_budget)
        if spec.largest_budget <= high:
            high, bounded = spec.largest_budget, " (the channel's max_budget_bytes)"
    if not low <= number <= high:
        raise ValueError(f"{name} {number} is outside {low}..{high}{bounded}")
    return number


def _whole(value: Any) -> int | None:
    """``value`` as a whole number: an int, or a float without a fraction (160.0, as some
    JSON writers put it); None for anything else (160.5 is not 160, nor ``true`` a 1, nor
    the text "160" a number)."""
    if isinstance(value, bool):
        return None
    if isinstance(value, int):
        return value
    if isinstance(value, float) and value.is_integer():
        return int(value)
    return None
