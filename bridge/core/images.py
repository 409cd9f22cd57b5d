"""Image channels in a node's core: pictures in, progressive streams out; fragments in,
sharper pictures out (pure: the maths is :mod:`bridge.image`, no clock, no I/O).

At the camera node, :class:`ImageSender` (a :class:`~bridge.core.transfer.TransferSender`)
recodes each picture into a stream of the operator's budget, size and region of interest and
sends it as one transfer; the mission's policy says whether a newer picture waits for the one
in flight (``finish``) or replaces it (``cancel``). A receiver's acknowledgement that shows a
gap (a later fragment held, an earlier one not) has the missing fragment sent again at the
next opportunity, not after ``retry_s``: seed 002's requested trunk. Only where the gap's last
copy is known lost: the held fragment went out first after it (as SACK's loss detection
decides). A copy still on its way (a relay's queue holds minutes of them) is not sent again
at each acknowledgement that predates it.

At a receiving node, :class:`Images` decodes the stream's unbroken prefix after each fragment
and publishes a standard picture (PNG, or JPEG) on the output key with its metadata in the
file and on ``@zab/<mission>/<node>/images/<channel>/<src>``, at most every
``publish_interval_s`` but always the final one. Operators' puts on the control key are
merged into the channel's settings and carried to the camera by the control channel.

A restart of either bridge keeps the settings in force at its end and, at the camera, the
picture waiting to go and the last one sent (what ``request: now`` sends again), each as the
sample it came in when it is at most :data:`STATE_PICTURE_BYTES` (read again when its turn
comes).

While a receiver is reachable over IP (``surfacing``), the camera's pictures reach it whole,
as they came: put on its output key over IP (:class:`~bridge.core.surfacing.Relay`, where
that key is not the input key itself, which the receiver's applications see anyway), and not
sent acoustically while every receiver is so reached (the picture is kept as the last one).
``request: now`` then puts that picture over IP again where it can (an output key that is
the input key cannot show it again: there it crosses the water). A picture already crossing
when the receiver surfaced goes on crossing, and is shown to its end: it came before the IP
path. Where the camera puts its pictures over IP, a receiver does not publish the refinements
of a picture that began to cross once the camera was reachable over IP (a camera that has not
noticed yet): counted as ``surfaced_duplicates``, they would overwrite the whole picture with
coarser ones. With ``ros2.out_topic``, the camera also publishes the picture whole on each such
receiver's ROS 2 topic, and the receiver none of its refinements there. (A ROS 2 camera's
pictures cross acoustically as ever: its messages are not pictures for the output key, and its
topic reaches the surface's ROS 2 over IP anyway.)
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

from bridge.core.events import Delivery, PicturePublished
from bridge.core.outputs import Outbox
from bridge.core.receivers import Receivers
from bridge.core.surfacing import Relay, Surfacing
from bridge.core.transfer import Transfer, TransferReceiver, TransferSender
from bridge.errors import DecodeError, EncodeError
from bridge.wire.channels import ChannelCodec, ChannelTable
from bridge.wire.frame import Entry
from bridge.wire.images import ImageSpec, control_payload, merge_control
from bridge.wire.payloads import decode_payload

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray

    from bridge.image.formats import InputImage

    Pixels = NDArray[np.uint8]

__all__ = ["ImageSender", "Images", "control_keys", "fit_control", "picture_file",
           "pixel_encoding", "ros2_picture", "settings_of"]

log = logging.getLogger("zab.core")

MAX_PICTURE_BYTES = 64 << 20
"""A picture sample longer than this is dropped unread (the pixel limit is the channel's)."""
STATE_PICTURE_BYTES = 256 << 10
"""A picture sample longer than this is not in the camera's saved state: the node saves its
state as fragments go, and a restart before such a picture is sent loses it (a 640 × 480
JPEG is about 60 kB, a PNG of it about 250 kB)."""
KEEP_PICTURE_S = 1.0
"""A picture that only waits has the node save its state at most this often (the others wait
for the node's next save): a 30 Hz camera does not cost 30 saves a second."""

# bridge.image (numpy, Pillow) loads with a mission's first picture, not with every bridge
Drop = Callable[..., None]  # (key, reason, now[, cause]): a counted drop


def _unread(key: str, reason: str, now: float, cause: str = "undecodable") -> None:
    log.warning("%s: %s", key, reason)


def _spec(channel: ChannelCodec) -> ImageSpec:
    assert channel.image is not None
    return channel.image


def read_picture(spec: ImageSpec, data: bytes, encoding: str) -> InputImage:
    """The picture of a sample on ``spec``'s input, its header checked (pixels decoded when
    first asked for): a JPEG or PNG, or a ROS 2 CompressedImage or Image (CDR). Raises
    :class:`~bridge.image.formats.ImageInputError` for one the channel does not take."""
    from bridge.image.formats import ImageInputError, open_image, open_raw

    if len(data) > MAX_PICTURE_BYTES:
        raise ImageInputError(f"{len(data)} bytes, over {MAX_PICTURE_BYTES}", "too_large")
    if spec.ros2 is None:
        return open_image(data, encoding, spec.accept, spec.max_input_pixels, spec.colour)
    from bridge.ros2.messages import decode_cdr

    msgtype = spec.ros2.msgtype
    try:
        message = decode_cdr(spec.ros2.distro, msgtype, data)
    except DecodeError as exc:
        raise ImageInputError(str(exc)) from None
    if msgtype.endswith("/Image"):
        return open_raw(message, spec.max_input_pixels, spec.colour)
    said = str(message.get("format", "")).lower()  # "jpeg", "png", "bgr8; jpeg compressed …"
    kind = "image/png" if "png" in said else "image/jpeg" if "jp" in said else ""
    return open_image(bytes(message.get("data", b"")), kind, spec.accept,
                      spec.max_input_pixels, spec.colour)


@dataclass
class Picture:
    """A picture sample as it came (what a restart reads again) and, once read, its image."""

    data: bytes
    encoding: str
    key: str | None = None
    ref: str | None = None
    image: InputImage | None = None

    def opened(self, spec: ImageSpec) -> InputImage:
        """Its image, its header read the first time (a picture kept across a restart comes
        back unread); raises :class:`~bridge.image.formats.ImageInputError`."""
        if self.image is None:
            self.image = read_picture(spec, self.data, self.encoding)
        return self.image

    def state(self) -> list[Any] | None:
        """As saved state; None if it is too long to be saved (:data:`STATE_PICTURE_BYTES`)."""
        if len(self.data) > STATE_PICTURE_BYTES:
            return None
        return [self.data, self.encoding, self.key, self.ref]

    @classmethod
    def from_state(cls, state: list[Any] | None) -> Picture | None:
        if not state:
            return None
        data, encoding, key, ref = state
        return cls(bytes(data), str(encoding), key, ref)


def settings_of(saved: Mapping[str, Any], spec: ImageSpec) -> dict[str, Any]:
    """A channel's settings as saved (the mission's where a restart finds none, or where
    ``saved`` is empty)."""
    roi = saved.get("roi", spec.roi)
    return {"width": int(saved.get("width", spec.width)),
            "height": int(saved.get("height", spec.height)),
            "budget_bytes": int(saved.get("budget_bytes", spec.budget_bytes)),
            "roi": tuple(float(v) for v in roi) if roi else None}


def fit_control(channel: ChannelCodec, camera: int, settings: Mapping[str, Any], value: Any
                ) -> tuple[dict[str, Any], str, int]:
    """An operator's control ``value`` on the control ``channel`` (steering ``camera``, as
    :func:`control_keys` numbers it) merged into ``settings``: the settings then, its request
    and the channel's packed value. A :class:`ValueError` saying why for a control the
    camera would not follow: the one check of a put, a get and ``zab put --mission``."""
    spec = _spec(channel)
    merged = dict(settings)
    try:
        request = merge_control(merged, value, spec)
        payload = channel.pack([control_payload(
            merged, request, camera if len(channel.receivers) > 1 else None)])
    except (EncodeError, TypeError, ValueError) as exc:
        raise ValueError(f"image control {spec.name!r}: {exc}") from None
    return merged, request, payload


def control_keys(table: ChannelTable, node: str) -> dict[str, tuple[ChannelCodec, int]]:
    """Where operators at ``node`` steer the cameras whose pictures come here: each image
    channel's control key, with its control channel and the camera it steers (its number in
    the channel's ``from`` order, 1 first; 0: every camera of the channel). A key with
    ``{src}`` is one key per camera."""
    out: dict[str, tuple[ChannelCodec, int]] = {}
    for channel in table.channels:
        spec = channel.image
        if spec is None or not spec.control or not channel.sent_by(node):
            continue
        if "{src}" not in spec.control_key:
            out[spec.control_key.format(node=node, dst=node)] = (channel, 0)
            continue
        for camera in channel.destinations(node):
            key = spec.control_key.format(node=node, src=camera, dst=node)
            out[key] = (channel, channel.receivers.index(camera) + 1)
    return out


class ImageSender(TransferSender):
    """The camera's side of one image channel: the newest picture, the operator's settings
    and the mission's policy."""

    def __init__(self, channel: ChannelCodec, dests: Iterable[str], retry_s: float,
                 first_seq: int = 0) -> None:
        super().__init__(channel, dests, retry_s, first_seq)
        spec = self.spec = _spec(channel)
        self.settings: dict[str, Any] = settings_of({}, spec)
        self.latest: Picture | None = None  # not sent yet
        self.last: Picture | None = None  # sent last
        self.drop: Drop = _unread  # (set by :class:`Images`: a picture that does not decode)
        self.in_key = spec.in_key
        """The camera's input key, as its application puts pictures there (set by
        :class:`Images`: the mission's may be a template, ``{node}/camera``)."""
        self.kept_at = -math.inf  # when a picture that only waits last asked for a save

    def state(self) -> dict[str, Any]:
        """The transfers', the settings in force and the pictures kept."""
        latest, last = self.latest, self.last
        return {**super().state(), "settings": dict(self.settings),
                "latest": latest.state() if latest else None,
                "last": last.state() if last else None}

    def restore(self, state: dict[str, Any]) -> None:
        super().restore(state)
        self.settings = settings_of(state.get("settings") or {}, self.spec)
        self.latest = Picture.from_state(state.get("latest"))
        self.last = Picture.from_state(state.get("last"))

    def picture(self, picture: Picture, now: float) -> list[Delivery]:
        """A new picture (decoded when it is sent): sent now, or kept until the policy or a
        request lets it go."""
        self.latest = picture
        if self.spec.send == "on_request" or (self.current is not None
                                             and self.spec.policy == "finish"):
            return []
        return self._begin(now)

    def _begin(self, now: float, again: bool = False) -> list[Delivery]:
        """Send the newest picture (replacing any in flight); ``again``: an operator's
        request, which sends the last one sent where the newest does not decode. A picture
        that does not decode is a counted drop that leaves the one in flight going and the
        last one sent as it was (what a request sends again)."""
        from bridge.image.formats import ImageInputError

        for taken in [p for p in (self.latest, self.last) if p is not None]:
            if taken is self.latest:
                self.latest = None
            else:
                self.last = None  # (sent again: it becomes the last one below)
            try:
                pixels = taken.opened(self.spec).pixels()
            except ImageInputError as exc:
                self.drop(taken.key or self.in_key,
                          f"image channel {self.spec.name!r}: {exc}", now, exc.cause)
                if again:
                    continue
                return []
            self.last = taken
            return self.offer_bytes(self.recode(pixels), now, taken.key, taken.ref)
        return []

    def recode(self, pixels: Pixels) -> bytes:
        """``pixels`` as a progressive stream of the current settings: fitted to the size,
        a budget of whole fragments, the ROI raised."""
        from bridge.image.codec import encode, header_bytes
        from bridge.image.formats import fit
        from bridge.image.geometry import Roi

        s = self.settings
        chunk = self.channel.chunk_bytes
        roi = Roi.from_fractions(*s["roi"]) if s["roi"] else None
        budget = min(int(s["budget_bytes"]), self.spec.largest_budget)
        budget = max(budget - budget % chunk, chunk * -(-header_bytes(True) // chunk))
        return encode(fit(pixels, int(s["width"]), int(s["height"])), budget, roi)

    def control(self, value: Mapping[str, Any], now: float) -> list[Delivery]:
        """The operator's control value arrived: new settings, and a request."""
        self.settings = {"width": int(value["width"]), "height": int(value["height"]),
                         "budget_bytes": int(value["budget_bytes"]),
                         "roi": (tuple(v / 64 for v in (value["x0"], value["y0"], value["x1"],
                                                        value["y1"]))
                                 if value["roi_on"] and value["x0"] < value["x1"]
                                 and value["y0"] < value["y1"] else None)}
        request = value["request"]
        if request == "cancel" and self.current is not None:
            item, self.current = self.current, None
            self.latest = None if self.spec.send == "on_request" else self.latest
            return self._report(item, "failed", now, "cancelled by the operator")
        if request == "now":
            if self.latest is None and self.last is None:
                log.warning("image channel %r: an operator asked for a picture, and none has "
                            "come on %s since this bridge started", self.spec.name,
                            self.in_key)
            return self._begin(now, again=True)
        return []

    def on_ack(self, dst: str, tid: int, base: int, bitmap: int, now: float) -> list[Delivery]:
        reports = super().on_ack(dst, tid, base, bitmap, now)
        item = self.current
        if item is not None and item.tid == tid and dst in item.dests:
            held = item.held.get(dst, set())
            # a copy of a held one left after the gap's last copy: that copy is lost
            after = max((item.first_sent[i] for i in held if i in item.first_sent),
                        default=-math.inf)
            for i in range(item.done_by(dst), max(held, default=0)):
                if i not in held and item.last_sent.get(i, math.inf) < after:
                    item.next_send[i] = min(item.next_send.get(i, now), now)
        return reports + self._next(now)

    def expire(self, now: float) -> list[Delivery]:
        return super().expire(now) + self._next(now)

    def _one(self, item: Transfer, dst: str, state: str, now: float,
             reason: str | None = None) -> Delivery:
        """A picture's delivery report names its sequence number, as its pictures do."""
        return replace(super()._one(item, dst, state, now, reason), sequence=item.tid)

    def _next(self, now: float) -> list[Delivery]:
        """The picture in flight ended: the newest one waiting goes (policy ``finish``)."""
        if self.current is None and self.latest is not None and self.spec.send == "each":
            return self._begin(now)
        return []


@dataclass
class Control:
    """One control key at a receiving node: the camera(s) it steers and its settings."""

    channel: ChannelCodec  # the image channel's control
    sender: Any  # the control channel's sender here
    camera: int  # see control_keys
    settings: dict[str, Any]


def picture_file(pixels: Any, spec: ImageSpec, meta: dict[str, Any]) -> bytes:
    """The file a receiver publishes of a decoded picture: a PNG or JPEG as ``spec`` says,
    ``meta`` in it as ``zab:<key>`` (JSON but for text)."""
    from bridge.image.formats import write_image

    return write_image(pixels, spec.format, spec.jpeg_quality, {
        f"zab:{k}": v if isinstance(v, str) else json.dumps(v) for k, v in meta.items()})


def pixel_encoding(pixels: Pixels) -> str:
    """The ROS 2 encoding of decoded pixels: ``mono8`` or ``rgb8``."""
    return "rgb8" if pixels.ndim == 3 else "mono8"


def ros2_picture(spec: ImageSpec, src: str, dst: str, file: bytes, pixels: str, at: float,
                 kind: str | None = None) -> tuple[str, dict[str, Any]] | None:
    """The key and CompressedImage with which ``dst`` publishes ``src``'s picture ``file``
    (of ``pixels``: ``mono8``, ``rgb8`` …; made at ``at``; a ``kind`` file, by default the
    channel's format) on the channel's ROS 2 topic; None where it has no ``out_topic``."""
    key = spec.ros2_output_key(src, dst)
    if key is None:
        return None
    from bridge.ros2.element import picture_message

    return key, picture_message(file, kind or spec.format, pixels, at)


@dataclass
class Shown:
    """What a receiver last published of one sender's image channel."""

    tid: int | None = None
    bytes: int = 0
    at: float = -math.inf
    begun: float = -math.inf  # when its first fragment came
    logged: int = 0  # bytes of its stream the PicturePublished events have carried
    held: bool = False
    """A sharper picture came too soon after the last one: published once the interval is
    over, if nothing sharper has come by then (:meth:`Images.tick`)."""


class Images:
    """A node's image channels: pictures and operators' controls in, refinements out."""

    def __init__(self, table: ChannelTable, node: str, outbox: Outbox, receivers: Receivers,
                 senders: Mapping[int, Any], drop: Drop, bindings: dict[str, Any],
                 saved: Mapping[str, Any] | None = None,
                 surfacing: Surfacing | None = None) -> None:
        """``bindings``: the sending side's input keys, which gain the pictures' (the runtime
        subscribes to them); ``saved``: what :meth:`state` returned before a restart;
        ``surfacing``: the peers reachable over IP, when the mission surfaces."""
        self.node = node
        self.outbox = outbox
        self.surfacing = surfacing
        self.receivers = receivers
        self.drop = drop
        self.inputs: dict[str, ImageSender] = {}
        self.cameras: dict[int, ImageSender] = {}  # by the control channel's index
        for channel in table.channels:
            sender = senders.get(channel.index)
            if channel.image is not None and isinstance(sender, ImageSender):
                sender.drop = drop
                sender.in_key = channel.image.input_key(node)
                self.inputs[channel.image.input_key(node)] = sender
                self.cameras[channel.index + 1] = sender
        self.controls: dict[str, Control] = {
            key: Control(channel, senders[channel.index], camera, settings_of(
                (saved or {}).get(key) or {}, _spec(channel)))
            for key, (channel, camera) in control_keys(table, node).items()}
        """This node's steering of cameras, by control key."""
        self.shown: dict[tuple[str, int], Shown] = {}
        for key in [*self.inputs, *self.controls]:
            bindings.setdefault(key, [])

    def state(self) -> dict[str, Any]:
        """The settings this node steers its cameras with, by control key (a restart keeps
        them: a control merges into them and carries them whole)."""
        return {key: dict(control.settings) for key, control in self.controls.items()}

    # -- samples in ------------------------------------------------------------------------

    def ingest(self, key: str, data: bytes, encoding: str, now: float,
               ref: str | None) -> bool:
        """A sample on an image input or a control key (True), or on neither (False)."""
        camera = self.inputs.get(key)
        if camera is not None:
            from bridge.image.formats import ImageInputError

            try:
                image = read_picture(camera.spec, data, encoding)
            except ImageInputError as exc:
                self.drop(key, f"image channel {camera.spec.name!r}: {exc}", now, exc.cause)
                return True
            picture = Picture(data, encoding, key, ref, image)
            if self._over_ip(camera, picture, now):
                camera.latest, camera.last = None, picture  # (every receiver has it whole)
            else:
                self.outbox.reports(camera.picture(picture, now))
            if now - camera.kept_at >= KEEP_PICTURE_S:  # (a transfer that began: saved anyway)
                camera.kept_at = now
                self.outbox.unsaved = True
            return True
        if key not in self.controls:
            return False
        try:
            self.steer(key, decode_payload(data, encoding), now, ref)
        except DecodeError as exc:
            self.drop(key, f"image control {key!r}: {exc}", now, "undecodable")
        except ValueError:
            pass  # (counted by steer)
        return True

    def _over_ip(self, camera: ImageSender, picture: Picture, now: float,
                 asked: bool = False) -> bool:
        """Put ``picture`` as it came on the output keys of the camera's receivers reachable
        over IP; whether it need not cross the water: every receiver is reachable and, for a
        picture ``asked`` for again, each got it so (an output key that is the input key
        itself showed the picture as it came, but cannot show it again)."""
        surfacing = self.surfacing
        if surfacing is None or not surfacing.reachable or camera.spec.ros2 is not None:
            return False
        key = camera.spec.input_key(self.node)
        outs = [(d, camera.spec.output_key(self.node, d)) for d in camera.dests]
        self.outbox.items.extend(surfacing.relays(key, outs, Relay(
            key, picture.data, picture.encoding, taken=now)))
        if camera.spec.ros2_out is not None and surfacing.republish:
            self._ros2_over_ip(camera, picture, now)
        return not surfacing.acoustic(camera.dests) and (
            not asked or all(surfacing.republishes(key, out) for _, out in outs))

    def _ros2_over_ip(self, camera: ImageSender, picture: Picture, now: float) -> None:
        """Publish ``picture`` on the ROS 2 topic of each receiver reachable over IP, as the
        receiver would were it to come across the water: the file as it came where a ROS 2
        viewer shows it so, else made anew in the channel's format (a palette PNG, or an
        EXIF orientation OpenCV would not follow)."""
        from bridge.image.formats import ImageInputError, write_image
        from bridge.ros2.element import FILE_PIXELS

        spec = camera.spec
        assert self.surfacing is not None
        dests = [d for d in camera.dests if d in self.surfacing.reachable]
        if not dests:
            return
        try:
            image = picture.opened(spec)
            file, kind, pixels = picture.data, image.kind, FILE_PIXELS.get(image.layout or "")
            if pixels is None or kind is None:
                decoded = image.pixels()
                file, kind = write_image(decoded, spec.format, spec.jpeg_quality), spec.format
                pixels = pixel_encoding(decoded)
        except ImageInputError as exc:
            self.drop(picture.key or camera.in_key, f"image channel {spec.name!r}: {exc}", now,
                      exc.cause)
            return
        keys = set()
        for dest in dests:  # (a topic without {dst} is one topic for them all: once)
            ros2 = ros2_picture(spec, self.node, dest, file, pixels, now, kind)
            if ros2 is not None and ros2[0] not in keys:
                keys.add(ros2[0])
                self.outbox.publish(*ros2, "cdr", False, ros2=spec.ros2_out, taken=now)
                self.surfacing.relayed += 1

    def steer(self, key: str, value: Any, now: float, ref: str | None = None
              ) -> dict[str, Any]:
        """An operator's control (a put's value, or a query's) on the control ``key`` of a
        channel this node steers: merged into its settings and sent to the camera; returns
        the settings now in force. A control that does not fit is a counted drop and a
        :class:`ValueError` saying why."""
        control = self.controls[key]
        channel, settings = control.channel, control.settings
        try:
            merged, request, payload = fit_control(channel, control.camera, settings, value)
        except ValueError as exc:
            self.drop(key, str(exc), now, "unfit")
            raise
        if merged != settings or request != "none":  # (else the operator only asks)
            settings.update(merged)
            self.outbox.reports(control.sender.offer(payload, now, key, ref))
            self.outbox.unsaved = True
        return {**settings, "request": request}

    # -- entries in ------------------------------------------------------------------------

    def entry(self, src: str, channel: ChannelCodec, entry: Entry, now: float) -> int:
        """An entry of an image channel from ``src``: a control for our camera, or a
        fragment of a picture for us. Returns the values it delivered here: the controls
        our camera took (none for one sent again, its first copy taken), or 1 for a
        fragment."""
        if _spec(channel).control:
            camera = self.cameras.get(channel.index)
            mine = channel.receivers.index(self.node) + 1 if camera is not None else -1
            taken = 0
            for values in self.receivers.entry(src, channel, entry.header, entry.values):
                if camera is not None and values[0].get("camera", 0) in (0, mine):
                    taken += 1
                    value = values[0]
                    picture = camera.latest or camera.last
                    if value["request"] == "now" and picture is not None and self._over_ip(
                            camera, picture, now, asked=True):
                        value = {**value, "request": "none"}  # (it went over IP)
                    self.outbox.reports(camera.control(value, now))
                    self.outbox.unsaved = True  # (its settings)
            return taken
        data, progress = self.receivers.fragment(src, channel, entry.header, entry.chunk)
        receiver = self.receivers.by_key[(src, channel.index)]
        assert isinstance(receiver, TransferReceiver)
        stream = data if data is not None else receiver.prefix()
        self.outbox.status(f"transfer/{channel.name}", {**progress, "peer": src, "time": now,
                                                        "bytes": len(stream)})
        self._show(src, channel, receiver, stream, data is not None, now)
        return 1

    def tick(self, now: float) -> None:
        """Publish the pictures held back by ``publish_interval_s`` whose interval is over
        (the last fragments before a pause show then, not at the next fragment)."""
        for key, shown in self.shown.items():
            if not shown.held:
                continue
            receiver = self.receivers.by_key[key]
            assert isinstance(receiver, TransferReceiver)
            if receiver.tid != shown.tid:  # (another picture since: it shows itself)
                shown.held = False
            elif now - shown.at >= _spec(receiver.channel).publish_interval_s:
                self._show(key[0], receiver.channel, receiver, receiver.prefix(), False, now)

    def _show(self, src: str, channel: ChannelCodec, receiver: TransferReceiver,
              stream: bytes, final: bool, now: float) -> None:
        """Publish the picture ``stream`` holds, if it is sharper and it is time."""
        from bridge.image.codec import ImageStreamError, decode, header_bytes

        spec = _spec(channel)
        shown = self.shown.setdefault((src, channel.index), Shown())
        shown.held = False
        if receiver.tid != shown.tid:
            shown.tid, shown.bytes, shown.begun, shown.logged = receiver.tid, 0, now, 0
        surfacing = self.surfacing
        over_ip = surfacing is not None and src in surfacing.reachable \
            and spec.ros2 is None and shown.begun >= surfacing.since[src] \
            and surfacing.republish  # (a picture the camera put since reaches us over IP)
        if over_ip and surfacing is not None \
                and surfacing.republishes(spec.input_key(src), spec.output_key(src, self.node)):
            surfacing.duplicates += 1
            return
        if len(stream) <= shown.bytes or len(stream) < header_bytes(False):
            return
        if not final and now - shown.at < spec.publish_interval_s:
            shown.held = True
            return
        try:
            picture = decode(stream)
        except ImageStreamError as exc:
            self.outbox.stats.frames_dropped["malformed"] += 1
            log.warning("%s: image %r from %s: %s", self.node, spec.name, src, exc)
            shown.bytes = len(stream)
            return
        shown.bytes, shown.at = len(stream), now
        meta = {"channel": spec.name, "src": src, "sequence": receiver.tid,
                "bytes": len(stream), "budget": receiver.count * channel.chunk_bytes,
                "final": final, "width": int(picture.pixels.shape[1]),
                "height": int(picture.pixels.shape[0]),
                "psnr_estimate": round(picture.psnr_estimate, 2),
                "roi": list(picture.roi.fractions()) if picture.roi else None, "time": now}
        key = spec.output_key(src, self.node)
        file = picture_file(picture.pixels, spec, meta)
        self.outbox.publish(key, file, f"image/{spec.format}", True)
        ros2 = ros2_picture(spec, src, self.node, file, pixel_encoding(picture.pixels), now)
        if ros2 is not None and not over_ip:  # (there: the picture whole, over IP)
            self.outbox.publish(*ros2, "cdr", False, ros2=spec.ros2_out)
        self.outbox.status(f"images/{spec.name}/{src}", meta)
        self.outbox.event(PicturePublished(now, spec.name, src, key, shown.logged,
                                           stream[shown.logged:], meta))
        shown.logged = len(stream)
