"""The pictures the GUI shows: the latest of each image channel and camera, and the
operator's controls back (pure, but for Pillow reading the PNG's metadata).

The GUI's node publishes each picture (PNG or JPEG) on the image channel's output key; the
board keeps the latest bytes per (channel, camera) for the page to load from
``/image/<channel>/<camera>`` and emits an ``image`` item with the picture's metadata (bytes
received of the budget, sequence, final, the stream's PSNR estimate, ROI; for the camera's
own picture, put over IP while it is surfaced, ``whole`` and its size). A page's
``image_control`` message (a request, a budget, a size, an ROI drawn on the picture) becomes a put
on the channel's control key at the GUI's node.
"""

from __future__ import annotations

import io
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from bridge.core.loaded import LoadedMission
from bridge.wire.images import CONTROL_FIELDS, REQUESTS, ImageSpec

__all__ = ["ImageBoard", "ImageControlError"]

Item = dict[str, Any]
MIN_SIDE, MAX_SIDE = (next(f for f in CONTROL_FIELDS if f["field"] == "width")[k]
                      for k in ("min", "max"))


class ImageControlError(ValueError):
    """A page's image control that cannot be sent (the message says why)."""


@dataclass
class Picture:
    data: bytes
    encoding: str
    item: Item


def _meta(data: bytes) -> dict[str, Any]:
    """The ``zab:`` metadata of a published picture (PNG text chunks or JPEG comment)."""
    from PIL import Image, UnidentifiedImageError

    from bridge.image.formats import orientation, read_text

    try:
        image = Image.open(io.BytesIO(data))
        text = read_text(image)
    except (OSError, UnidentifiedImageError, ValueError):
        return {}
    out = {str(key)[4:]: value for key, value in text.items() if str(key).startswith("zab:")}
    if not out:  # the camera's picture itself, put over IP while it is surfaced
        width, height = image.size
        if orientation(image) in (5, 6, 7, 8):  # shown turned a quarter
            width, height = height, width
        out = {"whole": True, "final": True, "bytes": len(data), "budget": len(data),
               "width": width, "height": height}
    return out


class ImageBoard:
    """The image channels seen at the GUI's node."""

    def __init__(self, loaded: LoadedMission, node: str) -> None:
        self.node = node
        self.keys: dict[str, tuple[str, str]] = {}  # output key -> (channel, camera)
        self.specs: dict[str, ImageSpec] = {}
        for channel in loaded.table.channels:
            spec = channel.image
            if spec is None or spec.control:
                continue
            for src in channel.senders:
                if node in channel.destinations(src):
                    self.specs[spec.name] = spec
                    key = spec.output_key(src, node)
                    self.keys[key] = (spec.name, src)
        self.pictures: dict[tuple[str, str], Picture] = {}
        self.version = 0

    def describe(self) -> list[dict[str, Any]]:
        """The page's static part: each channel, its cameras and its settings."""
        return [{"channel": name, "cameras": sorted({s for c, s in self.keys.values()
                                                     if c == name}),
                 "width": spec.width, "height": spec.height, "budget_bytes": spec.budget_bytes,
                 "min_budget_bytes": spec.smallest_budget,
                 "max_budget_bytes": spec.largest_budget, "roi": spec.roi}
                for name, spec in self.specs.items()]

    def ingest(self, key: str, data: bytes, encoding: str, now: float) -> Item | None:
        """A sample on an image output key: the ``image`` item for the pages (None for any
        other key)."""
        found = self.keys.get(key)
        if found is None:
            return None
        channel, src = found
        self.version += 1
        item = {"kind": "image", "channel": channel, "node": src, "time": now,
                "version": self.version, "url": f"/image/{channel}/{src}?v={self.version}",
                "meta": _meta(data)}
        self.pictures[(channel, src)] = Picture(data, encoding, item)
        return item

    def items(self) -> list[Item]:
        return [p.item for p in self.pictures.values()]

    def picture(self, channel: str, src: str) -> Picture | None:
        return self.pictures.get((channel, src))

    def control(self, message: Mapping[str, Any]) -> tuple[str, dict[str, Any]]:
        """A page's image control: the control key and the value to put there (with a key
        per camera, the ``camera`` the page names)."""
        spec = self.specs.get(str(message.get("channel")))
        if spec is None:
            raise ImageControlError(f"no image channel {message.get('channel')!r} here")
        value: dict[str, Any] = {}
        request = message.get("request", "none")
        if request not in REQUESTS:
            raise ImageControlError(f"request {request!r} is none of {', '.join(REQUESTS)}")
        value["request"] = request
        for name in ("width", "height"):
            if name in message:
                side = message[name]
                if isinstance(side, bool) or not isinstance(side, int) \
                        or not MIN_SIDE <= side <= MAX_SIDE:
                    raise ImageControlError(f"{name} {side!r} is not {MIN_SIDE}..{MAX_SIDE}")
                value[name] = side
        if "budget_bytes" in message:
            budget = message["budget_bytes"]
            if isinstance(budget, bool) or not isinstance(budget, int) \
                    or not spec.smallest_budget <= budget <= spec.largest_budget:
                raise ImageControlError(f"budget {budget!r} is not {spec.smallest_budget}.."
                                        f"{spec.largest_budget} (whole fragments of "
                                        f"{spec.fragment_bytes} bytes)")
            value["budget_bytes"] = budget
        if "roi" in message:
            roi = message["roi"]
            if roi is not None:
                if not (isinstance(roi, list) and len(roi) == 4
                        and all(isinstance(v, int | float) and not isinstance(v, bool)
                                for v in roi)):
                    raise ImageControlError("roi is [x0, y0, x1, y1] in fractions, or null")
                try:
                    x0, y0, x1, y1 = (min(1.0, max(0.0, float(v))) for v in roi)
                except OverflowError:  # (an integer past a float's range)
                    raise ImageControlError("roi is [x0, y0, x1, y1] in fractions") from None
                if not (x0 < x1 and y0 < y1):
                    raise ImageControlError("roi needs x0 < x1 and y0 < y1")
                roi = [round(v, 4) for v in (x0, y0, x1, y1)]
            value["roi"] = roi
        key = spec.control_key
        if "{src}" in key:  # one key per camera: the card's
            camera = message.get("camera")
            if (spec.name, camera) not in self.keys.values():
                raise ImageControlError(f"no camera {camera!r} on image channel {spec.name!r}")
            key = key.replace("{src}", str(camera))
        return key.format(node=self.node, dst=self.node), value
