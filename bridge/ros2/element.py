"""A channel element that carries a ROS 2 topic: compiled once, used by the core and the adapter.

Input: samples on ``<domain>/<topic>/*/*`` (any type, so that a publisher of another type or
definition is seen and counted as a dropped payload, not silently missed), CDR decoded to plain
data for the element's layout. Output: the layout's values laid over the element's defaults,
serialised as a complete CDR message for ``<domain>/<out topic>/<dds type>/<RIHS01 hash>``.
An image channel's camera topic and pictures (as CompressedImages) likewise: :func:`compile_camera`.
"""

from __future__ import annotations

import string
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from bridge.codec import Layout
from bridge.errors import DecodeError, EncodeError
from bridge.mission.images import Ros2Pictures
from bridge.mission.ros2 import NameError_, Ros2Topic, check_topic, dds_type_name
from bridge.ros2 import messages
from bridge.ros2.names import (
    Qos,
    parse_topic_key,
    topic_key,
    topic_listen_key,
)

SENDER_TEMPLATES = frozenset({"node", "src"})
RECEIVER_TEMPLATES = frozenset({"node", "src", "dst"})
# Which ``type`` of a field fits which plain-data kind of a ROS 2 field.
_FITS = {"float": {"number"}, "int": {"number"}, "bool": {"bool"}, "string": {"string"},
         "enum": {"string"}, "bytes": {"bytes"}}


class Ros2Error(ValueError):
    """A ``ros2`` element that cannot be compiled; ``loc`` is relative to the element."""

    def __init__(self, message: str, loc: tuple[str | int, ...]) -> None:
        super().__init__(message)
        self.loc = loc


@dataclass(frozen=True, eq=False)
class Ros2Element:
    """One element's ROS 2 side: keys, type, defaults; CDR in and out."""

    msgtype: str
    distro: str
    type_hash: str
    domain: int
    in_topic: str
    out_topic: str
    qos: Qos
    defaults: dict[str, Any] = field(default_factory=dict)
    stamp_now: tuple[str, ...] = ()

    @property
    def in_key(self) -> str:
        """Subscription key expression (template): every type on the input topic."""
        return topic_listen_key(self.domain, self.in_topic)

    @property
    def out_key(self) -> str:
        """Publication key (template) on the output topic."""
        return topic_key(self.domain, self.out_topic, self.msgtype, self.type_hash)

    def publisher_key(self, node: str) -> str:
        """The exact key a ROS 2 publisher of the input topic uses at ``node``."""
        topic = self.in_topic.format(node=node, src=node)
        return topic_key(self.domain, topic, self.msgtype, self.type_hash)

    @property
    def dds_type(self) -> str:
        return dds_type_name(self.msgtype)

    def decode(self, data: bytes, key: str) -> dict[str, Any]:
        """Plain data of a sample that arrived on ``key``; ``DecodeError`` names why not."""
        try:
            got = parse_topic_key(key)
        except NameError_ as exc:
            raise DecodeError(str(exc)) from None
        if got.dds_type != self.dds_type:
            name = got.msgtype or got.dds_type
            raise DecodeError(f"unknown ROS 2 type {name} on {got.topic}: this element "
                              f"carries {self.msgtype}")
        if got.type_hash != self.type_hash:
            raise DecodeError(f"{self.msgtype} with type hash {got.type_hash} is not the ROS 2 "
                              f"{self.distro} definition ({self.type_hash}): another "
                              "distribution or a modified message")
        return messages.decode_cdr(self.distro, self.msgtype, data)

    def message(self, value: Any, now: float) -> dict[str, Any]:
        """The plain message published for ``value``: defaults, then ``stamp_now``, then the
        values that crossed."""
        tree = dict(self.defaults)
        stamp = time_message(now)
        for path in self.stamp_now:
            messages.set_path(tree, path, stamp)
        if not isinstance(value, dict):
            raise EncodeError(f"{self.msgtype}: expected the element's fields, got "
                              f"{type(value).__name__}")
        return messages.merge(tree, value)

    def encode(self, value: Any, now: float) -> bytes:
        """A complete CDR message for ``value`` at time ``now`` (Unix seconds)."""
        return messages.encode_cdr(self.distro, self.msgtype, self.message(value, now))


def _templates(topic: str, allowed: frozenset[str], loc: tuple[str | int, ...],
               names: dict[str, Sequence[str]]) -> None:
    used = {n for _, n, _, _ in string.Formatter().parse(topic) if n}
    bad = used - allowed
    if bad:
        raise Ros2Error(f"unknown template {{{sorted(bad)[0]}}} in {topic!r}; allowed here: "
                        f"{', '.join('{' + a + '}' for a in sorted(allowed))}", loc)
    for node in {n for values in names.values() for n in values}:
        try:
            check_topic(topic.format(node=node, src=node, dst=node))
        except NameError_ as exc:
            raise Ros2Error(f"with node {node!r}: {exc}", loc) from None


def _check_fields(spec: Ros2Topic, layout: Layout, fields: Sequence[Any]) -> None:
    for codec in layout.fields:
        index = next((i for i, f in enumerate(fields)
                      if codec.path == f.field or codec.path.startswith(f.field + ".")), 0)
        loc: tuple[str | int, ...] = ("fields", index, "field")
        if not codec.path:
            raise Ros2Error("a ROS 2 element picks fields by path (e.g. pose.pose.position.x), "
                            "not the whole message", loc)
        try:
            leaf = messages.resolve(spec.distro, spec.type, codec.path)
        except KeyError as exc:
            raise Ros2Error(f"{codec.path}: {exc.args[0]}", loc) from None
        kind, count = codec.spec.type, codec.spec.count
        if count is not None:
            if leaf.plain not in ("list", "bytes") or leaf.message is not None:
                raise Ros2Error(f"{codec.path} is not an array of numbers in {spec.type}", loc)
            if leaf.count is not None and leaf.count != count:
                raise Ros2Error(f"{codec.path} holds exactly {leaf.count} values in "
                                f"{spec.type}, not count {count}", loc)
            continue
        if kind is not None and leaf.plain not in _FITS[kind]:
            base = leaf.message or (f"{leaf.base}[]" if leaf.array else leaf.base)
            raise Ros2Error(f"{codec.path} is a {base} in {spec.type}; a {kind} field cannot "
                            "carry it", loc)


def compile_ros2(spec: Ros2Topic, layout: Layout, fields: Sequence[Any],
                 senders: Sequence[str], receivers: Sequence[str]) -> Ros2Element:
    """Check ``spec`` against its distribution's definitions and the element's layout."""
    try:
        messages.check_type(spec.distro, spec.type)
    except messages.UnknownType as exc:
        raise Ros2Error(str(exc), ("ros2", "type")) from None
    out_topic = spec.out_topic or spec.topic
    _templates(spec.topic, SENDER_TEMPLATES, ("ros2", "topic"), {"n": senders})
    _templates(out_topic, RECEIVER_TEMPLATES,
               ("ros2", "out_topic" if spec.out_topic else "topic"), {"n": receivers})
    _check_fields(spec, layout, fields)
    defaults: dict[str, Any] = {}
    for path, value in spec.defaults.items():
        try:
            messages.resolve(spec.distro, spec.type, path)
        except KeyError as exc:
            raise Ros2Error(f"{path}: {exc.args[0]}", ("ros2", "defaults", path)) from None
        messages.set_path(defaults, path, value)
        try:
            messages.encode_cdr(spec.distro, spec.type, defaults)
        except EncodeError as exc:
            raise Ros2Error(str(exc), ("ros2", "defaults", path)) from None
    for i, path in enumerate(spec.stamp_now):
        try:
            leaf = messages.resolve(spec.distro, spec.type, path)
        except KeyError as exc:
            raise Ros2Error(f"{path}: {exc.args[0]}", ("ros2", "stamp_now", i)) from None
        if leaf.message != "builtin_interfaces/msg/Time" or leaf.array:
            raise Ros2Error(f"{path} is not a builtin_interfaces/msg/Time", ("ros2", "stamp_now",
                                                                             i))
    qos = Qos(reliability=spec.qos.reliability, history=spec.qos.history, depth=spec.qos.depth)
    return Ros2Element(msgtype=spec.type, distro=spec.distro,
                       type_hash=messages.type_hash(spec.distro, spec.type), domain=spec.domain,
                       in_topic=spec.topic, out_topic=out_topic, qos=qos, defaults=defaults,
                       stamp_now=tuple(spec.stamp_now))


PICTURE_TYPE = "sensor_msgs/msg/CompressedImage"


def compile_camera(spec: Ros2Pictures, senders: Sequence[str], receivers: Sequence[str]
                   ) -> tuple[Ros2Element | None, Ros2Element | None]:
    """An image channel's ROS 2 sides: with ``topic``, the camera read at senders (its
    subscription announced best effort, which any publisher matches); with ``out_topic``,
    the pictures receivers publish, each a CompressedImage (:func:`picture_message`)."""
    camera = out = None
    if spec.topic is not None:
        _templates(spec.topic, SENDER_TEMPLATES, ("ros2", "topic"), {"n": senders})
        camera = Ros2Element(msgtype=spec.type, distro=spec.distro,
                             type_hash=messages.type_hash(spec.distro, spec.type),
                             domain=spec.domain, in_topic=spec.topic, out_topic=spec.topic,
                             qos=Qos(reliability="best_effort"))
    if spec.out_topic is not None:
        _templates(spec.out_topic, RECEIVER_TEMPLATES, ("ros2", "out_topic"), {"n": receivers})
        out = Ros2Element(msgtype=PICTURE_TYPE, distro=spec.distro,
                          type_hash=messages.type_hash(spec.distro, PICTURE_TYPE),
                          domain=spec.domain, in_topic=spec.topic or spec.out_topic,
                          out_topic=spec.out_topic, qos=Qos(),
                          defaults={"header": {"frame_id": spec.frame_id}})
    return camera, out


DECODED = {"mono8": "mono8", "mono16": "mono16", "rgb8": "bgr8", "rgba8": "bgra8"}
"""The pixel encodings a CompressedImage's file may hold, with what OpenCV decodes each to."""
FILE_PIXELS = {"L": "mono8", "I;16B": "mono16", "RGB": "rgb8", "RGBA": "rgba8"}
"""The pixel encoding of a JPEG or PNG by its layout (Pillow's raw mode,
:attr:`~bridge.image.formats.InputImage.layout`); other files are made anew to be shown."""


def picture_message(data: bytes, kind: str, pixels: str, stamp: float) -> dict[str, Any]:
    """A CompressedImage's fields for a ``kind`` (PNG or JPEG) file of ``pixels`` (a key of
    :data:`DECODED`) made at ``stamp`` (Unix seconds: its ``zab:time``), ``format`` as
    compressed_image_transport writes it (``rgb8; png compressed bgr8``: the pixels'
    encoding, the file's type, and what OpenCV decodes it to), so its subscribers give the
    right colours."""
    return {"header": {"stamp": time_message(stamp)},
            "format": f"{pixels}; {kind} compressed {DECODED[pixels]}",
            "data": data}


def time_message(t: float) -> dict[str, int]:
    """A ``builtin_interfaces/msg/Time`` of ``t`` (Unix seconds)."""
    sec = int(t // 1)
    return {"sec": sec, "nanosec": min(round((t - sec) * 1e9), 999_999_999)}
