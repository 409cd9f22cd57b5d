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
from bridge.wire.images import ImageSpec, merge_control

__all__ = ["ImageBoard", "ImageControlError"]

Item = dict[str, Any]


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
        value = {name: message[name] for name in ("request", "width", "height",
                                                  "budget_bytes", "roi") if name in message}
        value.setdefault("request", "none")
        roi = value.get("roi")
        if isinstance(roi, list) and all(type(v) in (int, float) for v in roi):
            value["roi"] = [min(1.0, max(0.0, v)) for v in roi]  # (drawn with the mouse, it
            # may reach past the picture's edge)
        merged: dict[str, Any] = {}
        try:  # (the bridge's own check, so that the page hears at once what it would refuse)
            merge_control(merged, value, spec)
        except ValueError as exc:
            raise ImageControlError(str(exc)) from None
        if merged.get("roi"):
            value["roi"] = list(merged["roi"])  # (the 64ths the camera applies)
        key = spec.control_key
        if "{src}" in key:  # one key per camera: the card's
            camera = message.get("camera")
            if (spec.name, camera) not in self.keys.values():
                raise ImageControlError(f"no camera {camera!r} on image channel {spec.name!r}")
            key = key.replace("{src}", str(camera))
        return key.format(node=self.node, dst=self.node), value
