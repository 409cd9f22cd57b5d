"""The part of ``zab demo`` for issue 30: a picture across the water, refining.

A plain Zenoh application on a vehicle puts one JPEG (a synthetic seabed) on the camera's key
as the tour starts; at the surface, another watches the image channel's output key, where the
bridge publishes an ever sharper PNG after each fragment. The tour tells each refinement: when
it came, its bytes against the budget and the stream's own quality estimate.
"""

from __future__ import annotations

import io
import json
import threading
import time
from dataclasses import dataclass
from typing import Any

import zenoh

from bridge.core.loaded import LoadedMission

TOUR_PICTURE_BYTES = 112
"""The tour's picture budget: a few TDMA cycles' spare bytes of the MORPH fleet."""
TOUR_SHARE = 0.5
"""The largest share of a frame a fragment of the tour's picture takes: the camera's frames
carry its telemetry too, and a fragment that fits beside it goes at every turn. MORPH on the
virtual clock, 70 s, six seeds: with the default 0.75 (28 B fragments) the picture was whole
in one run of six; with 0.5 (19 B) in all six, after 34 to 56 s (synthetic telemetry
as :func:`~bridge.cli.sim_fast.feed` puts it)."""


def images_for_tour(data: dict[str, Any]) -> str | None:
    """Give a mission without image channels (raw YAML data, changed in place) a camera for
    the tour: a submerged vehicle's, seen at the surface node, 160×120 grey, below every
    channel's priority. Returns the change in words (None: it has image channels, or no
    surface node and vehicle)."""
    nodes = data.get("nodes") or {}
    surface = next((n for n, v in nodes.items() if v.get("role") == "surface"), None)
    anchors = set((data.get("ranging") or {}).get("anchors") or ())
    vehicles = [n for n, v in nodes.items() if v.get("role", "submerged") != "surface"]
    # not an anchor (it answers the tour's get), nor the last (it surfaces in the tour)
    vehicle = next((n for n in vehicles[:-1] if n not in anchors), None) or next(
        iter(vehicles), None)
    if data.get("images") or surface is None or vehicle is None:
        return None
    data["images"] = [{
        "name": "camera", "from": vehicle, "to": surface, "in": f"{vehicle}/camera",
        "out": f"{vehicle}/camera", "width": 160, "height": 120,
        "budget_bytes": TOUR_PICTURE_BYTES, "share": TOUR_SHARE, "publish_interval_s": 0.0}]
    return (f"{vehicle} has a camera seen at {surface} (a progressive picture of up to "
            f"{TOUR_PICTURE_BYTES} bytes, whole fragments of its frame, below every channel's "
            "priority)")


@dataclass(frozen=True)
class Refinement:
    """A picture the receiving bridge published: seconds after the put, and its metadata."""

    after_s: float
    bytes: int
    budget: int
    psnr_estimate: float
    final: bool
    width: int
    height: int


def camera_pair(loaded: LoadedMission) -> tuple[str, str, str, str, str] | None:
    """(camera node, its input key, receiving node, output key there, channel name) of the
    first image channel whose ends both have Zenoh endpoints; None if there is none."""
    nodes = loaded.mission.nodes
    for channel in loaded.table.channels:
        spec = channel.image
        if spec is None or spec.control or spec.ros2 is not None:
            continue
        for src in channel.senders:
            for dst in channel.destinations(src):
                if nodes[src].zenoh.listen and nodes[dst].zenoh.listen:
                    return (src, spec.input_key(src), dst,
                            spec.output_key(src, dst), channel.name)
    return None


class PictureWatch:
    """Puts the tour's picture on the camera's node and records what the receiver shows."""

    def __init__(self, camera: zenoh.Session, in_key: str, receiver: zenoh.Session,
                 out_key: str) -> None:
        self.camera = camera
        self.in_key = in_key
        self.refinements: list[Refinement] = []
        self.changed = threading.Event()
        self.put_at: float | None = None
        self._lock = threading.Lock()
        self._subscriber = receiver.declare_subscriber(out_key, self._shown)

    def put(self) -> None:
        """The camera application's picture: a JPEG of a synthetic seabed."""
        from bridge.image.formats import write_image
        from bridge.image.synthetic import seabed

        jpeg = write_image(seabed(240, 320, seed=11, colour=False), "jpeg", quality=90)
        self.put_at = time.time()
        self.camera.put(self.in_key, jpeg, encoding=zenoh.Encoding("image/jpeg"))

    def _shown(self, sample: zenoh.Sample) -> None:
        """Zenoh thread: a refinement arrived (its metadata is in the PNG)."""
        from PIL import Image, UnidentifiedImageError

        if self.put_at is None:
            return
        try:
            text = dict(getattr(Image.open(io.BytesIO(sample.payload.to_bytes())), "text", {}))
            meta = {k[4:]: json.loads(v) for k, v in text.items() if k.startswith("zab:")
                    and k != "zab:channel" and k != "zab:src"}
            refinement = Refinement(time.time() - self.put_at, int(meta["bytes"]),
                                    int(meta["budget"]), float(meta["psnr_estimate"]),
                                    bool(meta["final"]), int(meta["width"]),
                                    int(meta["height"]))
        except (OSError, UnidentifiedImageError, KeyError, TypeError, ValueError):
            return
        with self._lock:
            self.refinements.append(refinement)
        self.changed.set()

    def seen(self) -> list[Refinement]:
        with self._lock:
            return list(self.refinements)

    def close(self) -> None:
        self._subscriber.undeclare()
