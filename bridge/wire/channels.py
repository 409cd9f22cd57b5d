"""Channels as the wire sees them: resolved senders/receivers, compiled layouts, fingerprint.

Built once from a validated :class:`~bridge.mission.model.Mission`. The channel index is its place
in the mission's ``channels`` list; every node derives the same table from the same file.
"""

from __future__ import annotations

import hashlib
import json
import re
import string
from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import cached_property
from typing import TYPE_CHECKING, Any

from bridge.codec import Layout
from bridge.errors import LayoutError
from bridge.mission.fields import OutOfRange
from bridge.mission.model import (
    Channel,
    Element,
    LearnedKeys,
    Mission,
    NodeKeys,
    listed_routes,
    route_text,
)
from bridge.wire.auth import AUTH_VERSION
from bridge.wire.families import KEY, FamilySpec, NameCodec, family_template, name_codec
from bridge.wire.images import CONTROL_TTL_S, ImageSpec, control_layout
from bridge.wire.interest import InterestCodec
from bridge.wire.marks import MarkCodec
from bridge.wire.network import NetCodec
from bridge.wire.payloads import encode_payload
from bridge.wire.queries import QueryCodec, QuerySpec, compile_query, query_codecs
from bridge.wire.sample_meta import SampleMeta

Values = list[dict[str, Any]]
"""One value of a channel: each element's fields, in element order."""

if TYPE_CHECKING:
    from bridge.mission.images import Ros2Pictures
    from bridge.ros2.element import Ros2Element

WIRE_VERSION = 2  # 2: the check reveals the fingerprint; epochs in stream missions
SEAL_VERSION = 1  # encrypted frames (bridge.wire.seal), in their missions' fingerprint

# Reliable channels and fragmented transfers (see bridge.core.reliable and bridge.core.transfer).
SEQ_BITS = 8  # a reliable value's sequence number, modulo 256
LAG_BITS = 4  # how far behind the sender's oldest unfinished value is (< WINDOW)
WINDOW = 16  # values (or fragments) in flight past the first unacknowledged one
TID_BITS = 4  # a transfer's id, modulo 16
COUNT_BITS_REPEATABLE = 6  # entries per frame (up to 63) once channels may repeat in a frame
EPOCH_BITS = 8  # a node's stream epoch, in every frame of missions with streams
MAX_TRANSFER_BYTES = 1 << 20

SENDER_TEMPLATES = frozenset({"node", "src"})
RECEIVER_TEMPLATES = frozenset({"node", "src", "dst"})


class PatternError(ValueError):
    """A ``from``/``to`` pattern names no node or is not a valid regular expression."""


def match_nodes(pattern: str | Sequence[str], nodes: Sequence[str]) -> tuple[str, ...]:
    """Nodes named by ``pattern``: an exact name, a list of them, or a regex (full match)."""
    items = [pattern] if isinstance(pattern, str) else list(pattern)
    if not items:
        raise PatternError(f"an empty list names no node: give at least one node name "
                           f"(nodes: {', '.join(nodes)})")
    found: list[str] = []
    for item in items:
        if item in nodes:
            hits = [item]
        else:
            try:
                rx = re.compile(item)
            except re.error as exc:
                raise PatternError(
                    f"{item!r} is neither a node name nor a valid regex: {exc}"
                ) from None
            hits = [n for n in nodes if rx.fullmatch(n)]
            if not hits:
                raise PatternError(f"{item!r} matches no node (nodes: {', '.join(nodes)})")
        found.extend(h for h in hits if h not in found)
    return tuple(found)


def template_names(key: str) -> set[str]:
    """The ``{name}`` placeholders used in a key template."""
    return {name for _, name, _, _ in string.Formatter().parse(key) if name}


@dataclass(frozen=True)
class ElementCodec:
    """An element with its compiled layout."""

    in_key: str
    out_key: str
    encoding: str
    layout: Layout
    ros2: Ros2Element | None = None  # a ROS 2 topic: CDR payloads on rmw_zenoh keys
    meta: SampleMeta | None = None  # fields carried beside the value (bridge.wire.sample_meta)

    def input_key(self, node: str, key: str = "*") -> str:
        """The key read at ``node``; a family member's, or with ``*`` all members'."""
        return self.in_key.format(node=node, src=node, key=key)

    def put_key(self, node: str) -> str:
        """The key a program at ``node`` puts a value on: the input key, or for a ROS 2 topic
        the exact key its publisher uses there (the input key is an expression, which no put
        may use)."""
        return self.input_key(node) if self.ros2 is None else self.ros2.publisher_key(node)

    def sample(self, node: str, value: Any, now: float, key: str | None = None
               ) -> tuple[str, bytes, str]:
        """What a program at ``node`` puts for ``value`` at time ``now`` (a ROS 2 message's
        stamp): (key, payload, encoding), msgpack on :meth:`put_key` (or a family member's
        ``key``), a ROS 2 topic's CDR message with no encoding (as rmw_zenoh's).
        ``EncodeError`` when a ROS 2 value does not fit its message."""
        if self.ros2 is None:
            return (key or self.put_key(node), *encode_payload(value))
        return self.put_key(node), self.ros2.encode(value, now), ""

    def output_key(self, src: str, dst: str, key: str = "*") -> str:
        """The key published at ``dst``; a family member's, or with ``*`` all members'."""
        if key != "*":  # a member's (names may be learned: not kept)
            return self.out_key.format(node=dst, src=src, dst=dst, key=key)
        found = self._output_keys.get((src, dst))
        if found is None:
            found = self._output_keys[(src, dst)] = self.out_key.format(
                node=dst, src=src, dst=dst, key=key)
        return found

    @cached_property
    def _output_keys(self) -> dict[tuple[str, str], str]:
        """:meth:`output_key` by (sender, receiver), filled as asked (once per received
        value)."""
        return {}


@dataclass(frozen=True)
class ChannelCodec:
    """A channel ready for the wire: index, endpoints, policy and element layouts."""

    index: int
    name: str
    senders: tuple[str, ...]
    receivers: tuple[str, ...]
    interval_s: float
    latching: bool
    priority: int
    elements: tuple[ElementCodec, ...]
    ack: bool = False
    reliable: bool = False
    ttl_s: float | None = None
    queue: int = 32
    overflow: str = "reject"
    retries: int | None = 10
    retry_s: float | None = None
    chunk_bytes: int = 0  # > 0: values are too big for a frame and travel in fragments
    fragment_bits: int = 0  # bits of a fragment index / count
    family: FamilySpec | None = None  # a key family: each entry starts with a member index
    always: bool = False  # with demand: sent even while no destination wants it
    image: ImageSpec | None = None  # an image channel's stream or control (bridge.wire.images)
    prefer: tuple[str, ...] = ()  # with several links: the links it takes, best first

    @cached_property
    def bits(self) -> int:
        """Bits of one whole value (every element's layout; an image stream's largest)."""
        if self.image is not None and not self.image.control:
            return 8 * self.image.largest_budget
        return sum(e.layout.bits for e in self.elements)

    @property
    def fragmented(self) -> bool:
        return self.chunk_bytes > 0

    @property
    def repeatable(self) -> bool:
        """May appear several times in one frame (queued values, fragments, members)."""
        return self.stream or self.family is not None

    @property
    def stream(self) -> bool:
        """Acknowledged by receivers: reliable values or fragmented transfers."""
        return self.reliable or self.fragmented

    @cached_property
    def plain(self) -> bool:
        """Not :attr:`repeatable`: its entry is the value alone, with no header (cached: asked
        for every entry received)."""
        return not self.repeatable

    @cached_property
    def header_bits(self) -> int:
        """Bits before the data of each entry: seq + lag, or transfer id + index + count."""
        if self.fragmented:
            return TID_BITS + 2 * self.fragment_bits
        if self.family is not None:
            return self.family.index_bits
        return SEQ_BITS + LAG_BITS if self.reliable else 0

    @cached_property
    def wire_bits(self) -> int:
        """Bits of one entry in a frame, after its index."""
        data = 8 * self.chunk_bytes if self.fragmented else self.bits
        return self.header_bits + data

    @property
    def value_bytes(self) -> int:
        """Bytes of a whole value packed (what a transfer carries, before trimming)."""
        return (self.bits + 7) // 8

    def sent_by(self, node: str) -> bool:
        return node in self.senders

    def destinations(self, sender: str) -> tuple[str, ...]:
        """Receivers of this channel when ``sender`` sends it (never the sender itself)."""
        cached = self._destinations.get(sender)
        if cached is None:
            cached = self._destinations[sender] = tuple(r for r in self.receivers if r != sender)
        return cached

    @cached_property
    def _destinations(self) -> dict[str, tuple[str, ...]]:
        """:meth:`destinations` by sender, filled as asked (a frame names them per entry)."""
        return {}

    def reaches(self, sender: str, node: str) -> bool:
        """Whether ``node`` is a destination when ``sender`` sends this channel (asked per
        received entry: a set, not a scan of every receiver)."""
        return node != sender and node in self._receiver_set

    @cached_property
    def _receiver_set(self) -> frozenset[str]:
        return frozenset(self.receivers)

    def pack(self, values: Sequence[object]) -> int:
        """All element values as one integer of ``bits`` bits, first element most significant."""
        n = 0
        for element, value in zip(self.elements, values, strict=True):
            n = (n << element.layout.bits) | element.layout.pack(value)
        return n

    def fields_described(self) -> list[list[str]]:
        """Each element's fields as ``path:description``: what its packed value means (the
        mission fingerprint's, and a saved latched value's shape)."""
        return [[f"{f.path}:{f.describe()}" for f in e.layout.fields] for e in self.elements]

    def unpack(self, n: int) -> Values:
        out: Values = []
        for element in reversed(self.elements):
            bits = element.layout.bits
            out.append(element.layout.unpack(n & ((1 << bits) - 1)))
            n >>= bits
        out.reverse()
        return out


def compile_element(element: Element, on_out_of_range: OutOfRange,
                    meta: SampleMeta | None = None) -> ElementCodec:
    """``meta``: the fields carried beside the value, appended to the layout."""
    if element.dccl:  # a DCCL message: the element's bytes are libdccl's
        from bridge.dccl.layout import DcclLayout

        dccl = DcclLayout.from_reference(element.dccl, strict=on_out_of_range == "reject",
                                         options=element.dccl_options)
        return ElementCodec(element.in_, element.out, element.encoding, dccl)  # type: ignore[arg-type]
    fields: list[Any] = [*element.fields, *(meta.fields() if meta is not None else ())]
    layout = Layout.from_fields(fields, on_out_of_range=on_out_of_range)
    assert element.in_ is not None and element.out is not None
    return ElementCodec(element.in_, element.out, element.encoding, layout, meta=meta)


def sample_meta(channel: Channel, element: Element) -> SampleMeta | None:
    """What ``element`` of ``channel`` carries beside its value, if anything."""
    age = channel.age
    meta = SampleMeta(deletes=channel.deletes, as_sent=element.encoding == "as_sent",
                      attachment_bytes=channel.attachment_bytes,
                      age_step_s=age.step_s if age is not None else None,
                      age_max_s=age.max_s if age is not None else 0.0)
    return meta if meta.fields() else None


def compile_ros2_element(element: Element, on_out_of_range: OutOfRange, senders: Sequence[str],
                         receivers: Sequence[str]) -> ElementCodec:
    """An element carrying a ROS 2 topic (see :mod:`bridge.ros2`); keys from its topics."""
    from bridge.ros2.element import compile_ros2  # rosbags loads only for ROS 2 missions

    assert element.ros2 is not None
    layout = Layout.from_fields(element.fields, on_out_of_range=on_out_of_range)
    ros2 = compile_ros2(element.ros2, layout, element.fields, senders, receivers)
    return ElementCodec(ros2.in_key, ros2.out_key, "cdr", layout, ros2)


class ChannelTableError(ValueError):
    """A channel cannot be compiled; ``loc`` points into the mission document."""

    def __init__(self, message: str, loc: tuple[str | int, ...]) -> None:
        super().__init__(message)
        self.loc = loc


def compile_channel(index: int, channel: Channel, nodes: Sequence[str]) -> ChannelCodec:
    """Resolve patterns and compile layouts, raising :class:`ChannelTableError` with a location."""
    loc: tuple[str | int, ...] = ("channels", index)
    try:
        senders = match_nodes(channel.from_, nodes)
    except PatternError as exc:
        raise ChannelTableError(str(exc), (*loc, "from")) from None
    try:
        receivers = match_nodes(channel.to, nodes)
    except PatternError as exc:
        raise ChannelTableError(str(exc), (*loc, "to")) from None
    if not any(set(receivers) - {sender} for sender in senders):
        raise ChannelTableError("a channel must reach a node other than its sender", (*loc, "to"))
    family = compile_family(channel, nodes, loc)
    extra = {KEY} if family is not None else set()
    elements = []
    for i, element in enumerate(channel.elements):
        eloc = (*loc, "elements", i)
        if element.ros2 is not None:
            elements.append(_ros2_element(element, channel.on_out_of_range, senders, receivers,
                                          eloc))
            continue
        assert element.in_ is not None and element.out is not None
        out_key = element.out
        if family is not None:
            try:
                element = element.model_copy(update={"in_": family_template(element.in_)})
            except ValueError as exc:
                raise ChannelTableError(str(exc), (*eloc, "in")) from None
            if KEY not in template_names(out_key):
                raise ChannelTableError(f"a keyed channel's output {element.out!r} needs {{key}}"
                                        ": each member is published on its own key",
                                        (*eloc, "out"))
        assert element.in_ is not None and element.out is not None
        templates: tuple[tuple[str, frozenset[str], str], ...] = (
            (element.in_, SENDER_TEMPLATES | extra, "in"),
            (element.out, RECEIVER_TEMPLATES | extra, "out"))
        for key, allowed, where in templates:
            bad = template_names(key) - allowed
            if bad:
                raise ChannelTableError(
                    f"unknown template {{{sorted(bad)[0]}}} in {key!r}; "
                    f"allowed here: {', '.join('{' + a + '}' for a in sorted(allowed))}",
                    (*eloc, where),
                )
        try:
            elements.append(compile_element(element, channel.on_out_of_range,
                                            sample_meta(channel, element)))
        except LayoutError as exc:
            inside = ("dccl",) if element.dccl else ("fields", *exc.loc)
            raise ChannelTableError(str(exc), (*eloc, *inside)) from None
    return ChannelCodec(
        index=index,
        name=channel.name,
        senders=senders,
        receivers=receivers,
        interval_s=channel.interval_s,
        latching=channel.latching,
        priority=channel.priority,
        elements=tuple(elements),
        ack=channel.ack,
        reliable=channel.reliable,
        ttl_s=channel.ttl_s,
        queue=channel.queue,
        overflow=channel.overflow,
        retries=channel.retries,
        retry_s=channel.retry_s,
        family=family,
        always=channel.always,
        prefer=tuple(channel.prefer or ()),
    )


def compile_family(channel: Channel, nodes: Sequence[str],
                   loc: tuple[str | int, ...]) -> FamilySpec | None:
    """The members of a keyed channel (None for a plain channel)."""
    keys = channel.keys
    if keys is None:
        return None
    if isinstance(keys, LearnedKeys):
        return FamilySpec((), keys.learn, learned=True, name_bytes=keys.name_bytes)
    if isinstance(keys, NodeKeys):
        try:
            members = match_nodes(keys.nodes, nodes)
        except PatternError as exc:
            raise ChannelTableError(str(exc), (*loc, "keys", "nodes")) from None
    else:
        members = tuple(keys)
    return FamilySpec(tuple(members), len(members))


def compile_queries(mission: Mission) -> tuple[QuerySpec, ...]:
    """Every query of the mission, raising :class:`ChannelTableError` with a location."""
    out = []
    for i, query in enumerate(mission.queries):
        loc: tuple[str | int, ...] = ("queries", i)
        for key, where in ((query.key, "key"), (query.local_key or "", "local_key")):
            bad = template_names(key) - {"node"}
            if bad:
                raise ChannelTableError(f"unknown template {{{sorted(bad)[0]}}} in {key!r}; "
                                        "allowed here: {node}", (*loc, where))
        try:
            spec = compile_query(i, query, mission, match_nodes)
        except PatternError as exc:
            raise ChannelTableError(str(exc), loc) from None
        except LayoutError as exc:
            raise ChannelTableError(str(exc), (*loc, *exc.loc)) from None
        if len(spec.servers) > 1 and "node" not in template_names(query.key):
            raise ChannelTableError("a query with several servers needs {node} in its key "
                                    "(the server asked)", (*loc, "key"))
        if not spec.askers:
            raise ChannelTableError("no node may ask this query", (*loc, "ask"))
        out.append(spec)
    names = [q.name for q in out]
    for i, name in enumerate(names):
        if name in names[:i]:
            raise ChannelTableError(f"query name {name!r} used twice", ("queries", i, "name"))
    return tuple(out)
def _network(mission: Mission) -> tuple[str, ...] | None:
    """What every node must agree on about the network (None: one link, no routes): each
    node's routes and the hop limit."""
    routes = [f"{name}:{dest}>{route_text(hop)}" for name, node in mission.nodes.items()
              for dest, hop in sorted(node.routes.items())]
    if mission.links is None and not routes:
        return None
    return (f"hops:{mission.max_hops}", *routes)


def _ros2_element(element: Element, on_out_of_range: OutOfRange, senders: Sequence[str],
                  receivers: Sequence[str], eloc: tuple[str | int, ...]) -> ElementCodec:
    from bridge.ros2.element import Ros2Error

    try:
        return compile_ros2_element(element, on_out_of_range, senders, receivers)
    except LayoutError as exc:
        raise ChannelTableError(str(exc), (*eloc, "fields", *exc.loc)) from None
    except Ros2Error as exc:
        raise ChannelTableError(str(exc), (*eloc, *exc.loc)) from None


def _ros2_camera(spec: Ros2Pictures, senders: Sequence[str], receivers: Sequence[str],
                 loc: tuple[str | int, ...]) -> tuple[Ros2Element | None, Ros2Element | None]:
    from bridge.ros2.element import Ros2Error, compile_camera

    try:
        return compile_camera(spec, senders, receivers)
    except Ros2Error as exc:
        raise ChannelTableError(str(exc), (*loc, *exc.loc)) from None


def entry_capacity_bits(mission: Mission, node: str, streams: bool) -> int:
    """Bits one entry (index included) can take in a frame of ``node``, after what the
    mission's wire options add: DLBL delays, authentication, check, count. ``streams``: the
    mission has reliable or fragmented channels (a longer count, one more index)."""
    n_nodes, n_channels = len(mission.nodes), len(mission.channels) + 2 * len(mission.images)
    overhead = 2 + (3 * (n_nodes - 1) if mission.wire.dlbl else 0)
    if _network(mission) is not None:  # the longest network header (bridge.wire.network)
        priorities = len({c.priority for c in mission.channels})
        overhead += NetCodec(n_nodes, priorities, listed_routes(mission)).routed_bytes
    if mission.wire.auth is not None:
        overhead += 4 + mission.wire.auth.tag_bytes
    if streams:
        count_bits, index_bits = COUNT_BITS_REPEATABLE + EPOCH_BITS, n_channels.bit_length()
    else:
        count_bits, index_bits = n_channels.bit_length(), (n_channels - 1).bit_length()
    return (mission.frame_bytes_of(node) - overhead) * 8 - count_bits - index_bits


def fragment_channel(channel: ChannelCodec, mission: Mission, streams: bool) -> ChannelCodec:
    """``channel`` as a fragmented transfer when a whole value does not fit in every sender's
    frame: a fragment fills about three quarters of a frame, so telemetry still fits beside
    it. A latching channel is refused then (like a reliable one, a transfer is sent until
    acknowledged, once, so it cannot latch)."""
    if channel.fragmented or channel.family is not None:
        return channel  # a family member never fragments: `zab check` says if it cannot fit
    capacity = min(entry_capacity_bits(mission, s, streams or channel.reliable)
                   for s in channel.senders)
    if channel.bits + channel.header_bits <= capacity:
        return channel
    loc = ("channels", channel.index)
    if channel.value_bytes > MAX_TRANSFER_BYTES:
        raise ChannelTableError(f"a value of {channel.value_bytes} bytes exceeds the "
                                f"{MAX_TRANSFER_BYTES}-byte transfer limit", loc)
    fragment_bits = 1
    for _ in range(4):  # the header size depends on the number of fragments: settle it
        chunk = 3 * (capacity - TID_BITS - 2 * fragment_bits) // 32
        if chunk < 1:
            return channel  # frames too small for anything: the frame checks say so
        fragments = -(-channel.value_bytes // chunk)
        fragment_bits = fragments.bit_length()
    if channel.latching:  # (a transfer is acknowledged and ends: there is nothing to re-send)
        raise ChannelTableError(
            f"a latching channel's value must fit in one frame: this one ({channel.bits} bits) "
            f"needs {fragments} fragments of {chunk} B, which travel once, until acknowledged; "
            "set latching: false, or make a value fit a frame (fewer or coarser fields, or a "
            "larger modem.frame_bytes)", (*loc, "latching"))
    return replace(channel, chunk_bytes=chunk, fragment_bits=fragment_bits)


def compile_images(mission: Mission) -> tuple[ChannelCodec, ...]:
    """Each image channel as its stream and its control channel, after the mission's
    channels (see :mod:`bridge.wire.images`)."""
    out: list[ChannelCodec] = []
    nodes = tuple(mission.nodes)
    for i, image in enumerate(mission.images):
        loc: tuple[str | int, ...] = ("images", i)
        ends = []
        for where in ("from", "to"):
            try:
                ends.append(match_nodes(getattr(image, "from_" if where == "from" else "to"),
                                        nodes))
            except PatternError as exc:
                raise ChannelTableError(str(exc), (*loc, where)) from None
        senders, receivers = ends
        if not any(set(receivers) - {s} for s in senders):
            raise ChannelTableError("an image channel must reach a node other than its "
                                    "sender", (*loc, "to"))
        spec = ImageSpec.from_mission(image, (None, None) if image.ros2 is None else
                                      _ros2_camera(image.ros2, senders, receivers, loc))
        for key, allowed, where in ((spec.in_key, SENDER_TEMPLATES, "in"),
                                    (image.out, RECEIVER_TEMPLATES, "out"),
                                    (image.control_key, RECEIVER_TEMPLATES, "control")):
            bad = template_names(key) - allowed
            if bad:
                raise ChannelTableError(f"unknown template {{{sorted(bad)[0]}}} in {key!r}",
                                        (*loc, where))
        for src in senders:
            for dst in (d for d in receivers if d != src):
                out_key = spec.output_key(src, dst)
                if image.control_key.format(node=dst, dst=dst, src=src) == out_key:
                    raise ChannelTableError(
                        f"{out_key!r} at {dst} is both the pictures' output and the operator's "
                        "control: a viewer there would get settings among the pictures (give "
                        "control a key of its own; by default <out>/control)", (*loc, "control"))
        capacity = min(entry_capacity_bits(mission, s, True) for s in senders)
        fragment_bits, chunk = 1, 0
        for _ in range(4):  # the header size depends on the number of fragments: settle it
            chunk = int(image.share * (capacity - TID_BITS - 2 * fragment_bits)) // 8
            if chunk < 1:
                raise ChannelTableError("frames too small for an image fragment", loc)
            fragment_bits = (-(-image.largest_budget // chunk)).bit_length()
        spec = replace(spec, fragment_bytes=chunk)
        if image.budget_bytes < spec.smallest_budget:
            raise ChannelTableError(
                f"budget_bytes {image.budget_bytes} is below one picture's smallest stream, "
                f"{spec.smallest_stream()} (a fragment crosses whole)", (*loc, "budget_bytes"))
        index = len(mission.channels) + 2 * i
        out.append(ChannelCodec(index, image.name, senders, receivers, 0.0, False,
                                image.priority, (), retry_s=image.retry_s, ttl_s=image.ttl_s,
                                queue=1, chunk_bytes=chunk, fragment_bits=fragment_bits,
                                image=spec))
        control = ElementCodec(image.control_key, image.control_key, "msgpack",
                               control_layout(len(senders)))
        out.append(ChannelCodec(index + 1, f"{image.name}.control", receivers, senders, 0.0,
                                False, image.priority + 1, (control,), reliable=True,
                                retries=None, ttl_s=CONTROL_TTL_S, queue=4,
                                overflow="drop_oldest",
                                image=replace(spec, control=True)))
    return tuple(out)


@dataclass(frozen=True)
class AckCodec:
    """The system entry acknowledging a stream (``ack`` in frames), after the mission channels.

    Fields: the node acknowledged (``peer``, its place in the mission), the stream (its place
    among reliable/fragmented channels), the ``epoch`` of that node's streams this receiver's
    window belongs to, the transfer id, ``base`` (next sequence number expected, or first
    fragment missing) and ``bitmap`` (bit i: ``base + 1 + i`` arrived).
    """

    index: int
    peer_bits: int
    stream_bits: int
    base_bits: int
    name: str = "@ack"
    repeatable: bool = True

    @property
    def wire_bits(self) -> int:
        return (self.peer_bits + self.stream_bits + EPOCH_BITS + TID_BITS + self.base_bits
                + WINDOW)

    def pack(self, peer: int, stream: int, epoch: int, tid: int, base: int,
             bitmap: int) -> int:
        n = peer
        for value, bits in ((stream, self.stream_bits), (epoch, EPOCH_BITS), (tid, TID_BITS),
                            (base, self.base_bits), (bitmap, WINDOW)):
            n = (n << bits) | (value & ((1 << bits) - 1))
        return n

    def unpack(self, n: int) -> tuple[int, int, int, int, int, int]:
        """``(peer, stream, epoch, tid, base, bitmap)``."""
        out = []
        for bits in (WINDOW, self.base_bits, TID_BITS, EPOCH_BITS, self.stream_bits):
            out.append(n & ((1 << bits) - 1))
            n >>= bits
        bitmap, base, tid, epoch, stream = out
        return n, stream, epoch, tid, base, bitmap


@dataclass(frozen=True)
class ChannelTable:
    """Every channel of a mission, plus what both ends of a link must agree on."""

    channels: tuple[ChannelCodec, ...]
    nodes: tuple[str, ...]
    dlbl: bool
    auth_tag_bytes: int = 0  # 0: frames are not authenticated
    sealed: bool = False  # frames are encrypted (bridge.wire.seal)
    demand: bool = False  # frames may carry the @want interest bitmap
    queries: tuple[QuerySpec, ...] = ()  # queries across the water
    wire_format: str = "zab"  # or "goby": DCCL messages back to back (bridge.wire.goby)
    network: tuple[str, ...] | None = None  # several links or routes: the network header's
    # description and every node's routes (bridge.wire.network), None: no network header
    listed: bool = False  # some route lists several hops: routed frames name the hop chosen

    @classmethod
    def from_mission(cls, mission: Mission) -> ChannelTable:
        nodes = tuple(mission.nodes)
        seen: dict[str, int] = {}
        for i, channel in enumerate(mission.channels):
            if channel.name in seen:
                raise ChannelTableError(
                    f"channel name {channel.name!r} already used by channel {seen[channel.name]}",
                    ("channels", i, "name"),
                )
            seen[channel.name] = i
        compiled = tuple(compile_channel(i, c, nodes) for i, c in enumerate(mission.channels))
        for i, image in enumerate(mission.images):
            if image.name in seen or f"{image.name}.control" in seen:
                raise ChannelTableError(f"channel name {image.name!r} already used",
                                        ("images", i, "name"))
            seen[image.name] = i
        streams = any(c.reliable or c.family is not None for c in compiled) or bool(
            mission.images)
        compiled = tuple(fragment_channel(c, mission, streams) for c in compiled)
        if not streams and any(c.fragmented for c in compiled):  # the count field grows
            compiled = tuple(fragment_channel(c, mission, True) for c in compiled)
        compiled += compile_images(mission)
        auth = mission.wire.auth
        return cls(channels=compiled, nodes=nodes, dlbl=mission.wire.dlbl,
                   auth_tag_bytes=auth.tag_bytes if auth else 0,
                   sealed=auth is not None and auth.encrypt,
                   wire_format=mission.wire.format,
                   demand=mission.demand is not None, queries=compile_queries(mission),
                   network=_network(mission), listed=listed_routes(mission))

    def __len__(self) -> int:
        return len(self.channels)

    @cached_property
    def streams(self) -> tuple[ChannelCodec, ...]:
        """Channels whose receivers acknowledge (reliable or fragmented), in index order."""
        return tuple(c for c in self.channels if c.stream)

    @cached_property
    def ack(self) -> AckCodec | None:
        """The acknowledgement entry, present when the mission has streams."""
        if not self.streams:
            return None
        fragment_bits = max((c.fragment_bits for c in self.streams), default=0)
        return AckCodec(index=len(self.channels),
                        peer_bits=(len(self.nodes) - 1).bit_length(),
                        stream_bits=(len(self.streams) - 1).bit_length(),
                        base_bits=max(SEQ_BITS, fragment_bits))

    @cached_property
    def names(self) -> NameCodec | None:
        """The ``@key`` entry naming learned family members, present when there are some."""
        learned = [(c.index, c.family) for c in self.channels
                   if c.family is not None and c.family.learned]
        return name_codec(len(self.channels) + (self.ack is not None), learned)

    @cached_property
    def interest(self) -> InterestCodec | None:
        """The ``@want`` entry, present in missions with ``demand``."""
        if not self.demand:
            return None
        return InterestCodec(len(self.channels) + (self.ack is not None)
                             + (self.names is not None), len(self.channels))

    @cached_property
    def query_codecs(self) -> tuple[QueryCodec, ...]:
        """Request and reply entries of every query, after the other system entries."""
        first = len(self.channels) + sum(s is not None
                                         for s in (self.ack, self.names, self.interest))
        return query_codecs(first, self.queries, len(self.nodes))

    @cached_property
    def marks(self) -> MarkCodec | None:
        """The ``@mark`` entry, present in authenticated missions (after every other)."""
        if not self.auth_tag_bytes or self.wire_format != "zab":
            return None
        return MarkCodec(len(self.channels) + sum(s is not None for s in (
            self.ack, self.names, self.interest)) + len(self.query_codecs),
            (len(self.nodes) - 1).bit_length())

    @property
    def wire(self) -> tuple[ChannelCodec | AckCodec | NameCodec | InterestCodec | QueryCodec
                            | MarkCodec, ...]:
        """Every kind of entry a frame may hold: the mission's channels, then system ones."""
        system = tuple(s for s in (self.ack, self.names, self.interest) if s is not None)
        marks = () if self.marks is None else (self.marks,)
        return (*self.channels, *system, *self.query_codecs, *marks)

    def by_name(self, name: str) -> ChannelCodec:
        return next(c for c in self.channels if c.name == name)

    def foreign_nodes(self, node: str) -> tuple[str, ...]:
        """The nodes whose DLBL delays ``node`` reports, in mission order."""
        return tuple(n for n in self.nodes if n != node)

    @cached_property
    def net(self) -> NetCodec | None:
        """The network header's codec, in missions with several links or routes."""
        if self.network is None:
            return None
        return NetCodec(len(self.nodes), len(self.priorities), self.listed)

    @cached_property
    def priorities(self) -> tuple[int, ...]:
        """The channels' priorities, lowest first: a frame's rank is its highest one's place."""
        return tuple(sorted({c.priority for c in self.channels}))

    @property
    def net_header_bytes(self) -> int:
        """The longest network header a frame of this mission carries (0: none)."""
        return 0 if self.net is None else self.net.routed_bytes

    @cached_property
    def fingerprint(self) -> bytes:
        """8 bytes that differ when two mission files would disagree about the wire."""
        description: dict[str, object] = {
            "wire": WIRE_VERSION,
            "dlbl": self.dlbl,
            "auth": [self.auth_tag_bytes, AUTH_VERSION] if self.auth_tag_bytes else 0,
            "nodes": self.nodes,
            "channels": [
                [c.name, c.fields_described()]
                + ([["reliable"]] if c.reliable else [])
                + ([["fragments", c.chunk_bytes, c.fragment_bits]] if c.fragmented else [])
                + ([["keys", c.family.describe()]] if c.family is not None else [])
                + ([["image", c.image.describe()]] if c.image is not None else [])
                for c in self.channels
            ],
        }
        if self.sealed:
            description["sealed"] = SEAL_VERSION
        if self.demand:
            description["demand"] = [c.name for c in self.channels if c.always]
        if self.queries:
            description["queries"] = [q.describe() for q in self.queries]
        if self.net is not None and self.network is not None:
            description["network"] = [self.net.describe(), *self.network]
        blob = json.dumps(description, sort_keys=True, separators=(",", ":")).encode()
        return hashlib.sha256(blob).digest()[:8]
