"""Image channels in the mission file: pictures recoded into progressive streams (pure data).

An application on the sending vehicle puts JPEG or PNG bytes on ``in``; the bridge recodes each
picture into an embedded stream of ``budget_bytes`` (:mod:`bridge.image`) and sends it in
fragments beside the other channels; every receiving bridge publishes a standard picture on
``out`` after each fragment that sharpens it. Operators steer the sender from a receiving
node with puts on ``control`` (see docs/mission-file.md, "Image channels").
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import ConfigDict, Field, field_validator, model_validator

from bridge.mission.base import MissionModel
from bridge.mission.keyexpr import AnyTemplateKey

__all__ = ["ROI_STEPS", "ImageChannel", "Ros2Pictures", "roi_applied"]

Fraction = Annotated[float, Field(ge=0.0, le=1.0)]


ROI_STEPS = 64
"""An ROI's corners are whole 64ths of the picture (the stream's header carries them so)."""


def roi_applied(roi: Any) -> tuple[float, float, float, float] | None:
    """An ROI (``[x0, y0, x1, y1]`` fractions, or None) as the 64ths the camera applies, each
    corner taken to its nearest; a :class:`ValueError` saying why for one it cannot apply
    (not four numbers inside 0..1, empty, narrower than a 64th). The one rule of an ROI: the
    mission's and an operator's control's."""
    if roi is None:
        return None
    shown = list(roi) if isinstance(roi, tuple) else roi
    if not isinstance(roi, (list, tuple)) or len(roi) != 4:
        raise ValueError(f"roi {shown!r} is not [x0, y0, x1, y1] inside 0..1")
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in roi):
        raise ValueError(f"roi {shown!r}: a corner is not a number")  # (true is no 1.0)
    try:
        x0, y0, x1, y1 = (float(v) for v in roi)
    except OverflowError:  # (an integer past a float's range)
        raise ValueError(f"roi {shown!r} is not [x0, y0, x1, y1] inside 0..1") from None
    if not all(0 <= v <= 1 for v in (x0, y0, x1, y1)):
        raise ValueError(f"roi {shown!r} is not [x0, y0, x1, y1] inside 0..1")
    if not (x0 < x1 and y0 < y1):
        raise ValueError(f"roi {shown!r} is empty (x1 must be > x0 and y1 > y0)")
    corners = tuple(round(v * ROI_STEPS) for v in (x0, y0, x1, y1))
    if corners[0] >= corners[2] or corners[1] >= corners[3]:
        raise ValueError(f"roi {shown!r} is narrower than 1/{ROI_STEPS} of the picture (each "
                         f"corner is taken to its nearest 1/{ROI_STEPS})")
    a, b, c, d = (v / ROI_STEPS for v in corners)
    return a, b, c, d


class Ros2Pictures(MissionModel):
    """An image channel's ROS 2 sides over rmw_zenoh's keys: a camera topic read instead of
    ``in``, pictures published on a topic beside ``out``, or both."""

    model_config = ConfigDict(extra="forbid")

    topic: str | None = Field(None, description="Camera topic read at the sender instead of "
                              "in, absolute (/rov/camera/image_raw/compressed); may use {node}.")
    type: Literal["sensor_msgs/msg/CompressedImage", "sensor_msgs/msg/Image"] = Field(
        "sensor_msgs/msg/CompressedImage", description="CompressedImage (JPEG or PNG, as its "
        "format says) or Image (mono8, mono16, rgb8, bgr8, rgba8, bgra8, rgb16, bgr16, rgba16, "
        "bgra16, 8UC1, 8UC3, 16UC1).")
    distro: Literal["jazzy", "kilted"] = "jazzy"
    domain: int = Field(0, ge=0, le=232, description="ROS_DOMAIN_ID, the first key chunk.")
    out_topic: str | None = Field(None, description="Topic receivers also publish each picture "
                                  "on ({src}, {dst}, {node}), as a sensor_msgs/msg/"
                                  "CompressedImage, for rqt_image_view and rviz (name it "
                                  "<base>/compressed for image_transport); default: none.")
    frame_id: str = Field("", description="header.frame_id of the pictures on out_topic.")

    @field_validator("topic", "out_topic")
    @classmethod
    def _absolute(cls, v: str | None) -> str | None:
        if v is not None and (not v.startswith("/") or "//" in v or v.endswith("/")):
            raise ValueError(f"{v!r}: a ROS 2 topic here is absolute, like /rov/camera")
        return v


class ImageChannel(MissionModel):
    """A camera across the water: progressive pictures from ``from`` to ``to``."""

    model_config = ConfigDict(extra="forbid", populate_by_name=True)

    name: str = Field(pattern=r"^[A-Za-z][A-Za-z0-9_-]*$", max_length=32)
    from_: str | list[str] = Field(alias="from", description="The node(s) with the camera.")
    to: str | list[str] = Field(description="The node(s) that receive the pictures.")
    in_: AnyTemplateKey | None = Field(None, alias="in", description="Input key at the "
                                       "sender ({node}): JPEG or PNG bytes, the Zenoh encoding "
                                       "(image/jpeg, image/png) saying which.")
    ros2: Ros2Pictures | None = Field(None, description="A ROS 2 camera topic instead of in, "
                                      "and/or a ROS 2 topic for the pictures beside out.")
    out: AnyTemplateKey = Field(description="Output key at receivers ({src}, {dst}, {node}): "
                                "a PNG (or JPEG) after each fragment that sharpens the picture.")
    control: AnyTemplateKey | None = Field(None, description="Key at receivers ({node}, {dst}; "
                                "{src}: one key per camera, each steering its own) where operators "
                                "put {request: now|cancel, width, height, budget_bytes, roi: "
                                "[x0, y0, x1, y1] or null} (msgpack or JSON; any subset); "
                                "default: <out>/control; never the out key itself.")
    width: int = Field(160, ge=8, le=2048, description="Largest width sent, pixels (pictures "
                       "are scaled to fit, keeping their proportions).")
    height: int = Field(120, ge=8, le=2048, description="Largest height sent, pixels.")
    colour: bool = Field(False, description="Send colour (YCbCr, chroma at half resolution); "
                         "else grey.")
    budget_bytes: int = Field(1600, ge=16, le=65536, description="Bytes of each picture's "
                              "stream (whole fragments, at least one: a fragment crosses "
                              "whole), until an operator sets another.")
    max_budget_bytes: int | None = Field(None, ge=16, le=65536, description="Largest budget "
                                         "an operator may set; default: budget_bytes.")
    roi: tuple[Fraction, Fraction, Fraction, Fraction] | None = Field(
        None, description="Region of interest [x0, y0, x1, y1] in fractions of the picture, "
        "sharpened first; operators may move it.")
    priority: int = Field(-1, description="Fragments go in frames at this channel priority "
                          "(below telemetry's 0 by default: telemetry is never starved).")
    share: float = Field(0.75, gt=0.0, le=1.0, description="Largest share of a frame one "
                         "fragment takes (the stream's budget per frame).")
    policy: Literal["finish", "cancel"] = Field(
        "finish", description="A newer picture waits for the one in flight to finish "
        "(finish) or replaces it at once (cancel).")
    send: Literal["each", "on_request"] = Field(
        "each", description="Send each new picture (as the policy allows), or only the "
        "newest when an operator asks (request: now).")
    publish_interval_s: float = Field(0.0, ge=0.0, description="Least time between two "
                                      "refinements published at a receiver (the final picture "
                                      "always goes; one held back goes when it is over).")
    format: Literal["png", "jpeg"] = Field("png", description="What receivers publish.")
    jpeg_quality: int = Field(90, ge=1, le=100, description="Quality of published JPEGs.")
    accept: list[Literal["jpeg", "png"]] = Field(
        default_factory=lambda: ["jpeg", "png"],  # type: ignore[arg-type]
        description="Input types taken; others are "
        "dropped (counted).")
    max_input_pixels: int = Field(8_000_000, ge=64, description="Larger inputs are dropped "
                                  "(counted) before decoding.")
    retry_s: float | None = Field(None, gt=0, description="Wait before a fragment is sent "
                                  "again (a gap the receiver reports is filled at once).")
    ttl_s: float | None = Field(None, gt=0, description="A picture still unfinished this long "
                                "after it started is given up.")

    @model_validator(mode="after")
    def _budgets(self) -> ImageChannel:
        camera = self.ros2 is not None and self.ros2.topic is not None
        if (self.in_ is None) == (not camera):
            raise ValueError("give the pictures' input: either `in` or `ros2.topic`")
        if self.ros2 is not None and self.ros2.topic is None and self.ros2.out_topic is None:
            raise ValueError("ros2 needs topic (a camera to read), out_topic (a topic to "
                             "publish the pictures on) or both")
        if self.max_budget_bytes is not None and self.max_budget_bytes < self.budget_bytes:
            raise ValueError("max_budget_bytes is below budget_bytes")
        return self

    @field_validator("roi")
    @classmethod
    def _roi(cls, roi: tuple[float, float, float, float] | None
             ) -> tuple[float, float, float, float] | None:
        """The 64ths the camera applies, as an operator's control is taken."""
        return roi_applied(roi)

    @property
    def largest_budget(self) -> int:
        return self.max_budget_bytes or self.budget_bytes

    @property
    def control_key(self) -> str:
        return self.control or f"{self.out}/control"
