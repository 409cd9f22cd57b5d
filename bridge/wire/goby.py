"""Goby-compatible frames (``wire: {format: goby}``): a frame is DCCL messages back to back.

What Goby3's queue does, read in GobySoft/goby3 ``src/acomms/queue/queue_manager.cpp`` and
``queue.cpp``: ``encode_repeated`` appends each message's ``dccl::Codec::encode`` output to the
frame with nothing between them (no count, no length, no checksum); a message joins the frame
only if its encoded size fits the bytes left (``get_priority_values``); ``decode_repeated``
decodes from the front, erases ``codec->size(msg)`` bytes and repeats until the frame is empty,
and when a message after the first fails to decode it keeps the ones already decoded (the
first failing raises). The DCCL id in each message's head says which message it is.

So in this format each channel carries one DCCL element, the channel is found by its DCCL id,
and the frame is exactly what a Goby3 node's QueueManager would produce from those messages.
zab's own frame features have no place in it: no DLBL delays, no authentication, no mission
check (a frame from another mission decodes if its ids are known), no reliable or fragmented
channels, and none of zab's own entries: no queries, no ``demand``, no learned key-family
members (the loader refuses each, saying where). Which messages go in a frame follows zab's
scheduler (priority, interval), not Goby's ``ttl``/``value_base`` priority.

A frame holds at least one message: a node with nothing due sends nothing, as Goby's
QueueManager, its queues empty, gives its MAC no data. So there are no heartbeats (a silent
peer is told from an absent one only by its data) and nothing a MAC would send empty: the
loader refuses ``link.heartbeat_s``, ``mac: polled`` (a master's polls ride on its frames)
and ``mac.ranging`` rounds. Since the frame names no channel, a DCCL message (its id) belongs
to one channel: two channels carrying one message are refused too.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

from bridge.dccl.layout import DcclLayout
from bridge.dccl.message import DcclMessage, peek_id
from bridge.errors import DecodeError, FrameError
from bridge.mission.model import AlohaMac, Mission, NoMac, PolledMac
from bridge.wire.channels import ChannelCodec, ChannelTable
from bridge.wire.frame import DecodedFrame, Entry, FrameCodec, WireCodec

#: At most 2**8 - 1 messages in one Goby frame (a frame of 1-byte messages is 255 bytes).
_COUNT_BITS = 8

__all__ = ["GobyFrameCodec", "decode_repeated", "encode_repeated", "frame_codec_for",
           "goby_problems"]


def encode_repeated(messages: Iterable[tuple[DcclMessage, dict[str, Any]]]) -> bytes:
    """Goby3's ``encode_repeated``: the DCCL encodings, concatenated."""
    return b"".join(msg.encode(value) for msg, value in messages)


def decode_repeated(data: bytes, by_id: dict[int, DcclMessage]
                    ) -> list[tuple[DcclMessage, dict[str, Any]]]:
    """Goby3's ``decode_repeated``: messages from the front until the bytes run out; a
    failure after the first message ends the list (``DecodeError`` only if the first fails)."""
    out: list[tuple[DcclMessage, dict[str, Any]]] = []
    rest = bytes(data)
    while rest:
        try:
            ident = peek_id(rest)
            msg = by_id.get(ident)
            if msg is None:
                raise DecodeError(f"no DCCL message with id {ident} in this mission")
            value, used = msg.decode_prefix(rest)
        except DecodeError:
            if not out:
                raise
            return out
        out.append((msg, value))
        rest = rest[used:]
    return out


def _dccl_of(channel: ChannelCodec) -> DcclLayout | None:
    if len(channel.elements) == 1 and isinstance(channel.elements[0].layout, DcclLayout):
        return channel.elements[0].layout
    return None


def goby_problems(table: ChannelTable, mission: Mission
                  ) -> Iterable[tuple[tuple[str | int, ...], str]]:
    """What a Goby-format mission cannot have, with where it is in the mission file."""
    wire = mission.wire
    if wire.dlbl:
        yield ("wire", "dlbl"), "wire.format goby frames have no DLBL delays"
    if wire.auth is not None:
        yield ("wire", "auth"), "wire.format goby frames cannot be authenticated"
    yield from _empty_frame_problems(mission)
    seen: dict[int, tuple[DcclMessage, str]] = {}  # each DCCL id's message and first channel
    for c in table.channels:
        loc: tuple[str | int, ...] = ("channels", c.index)
        layout = _dccl_of(c)
        if layout is None:
            yield (*loc, "elements"), ("wire.format goby: a channel carries exactly one element "
                                       "with a dccl message")
            continue
        if c.reliable or c.fragmented:
            what = "reliable" if c.reliable else f"larger than a frame ({layout.nbytes} B)"
            yield loc, f"wire.format goby: channel {c.name!r} cannot be {what}"
        m = layout.message
        if m.omit_id:
            yield (*loc, "elements", 0, "dccl"), f"{m.name} has omit_id: Goby frames need ids"
            continue
        if m.id not in seen:
            seen[m.id] = (m, c.name)
            continue
        first, name = seen[m.id]
        if first.name != m.name:
            yield (*loc, "elements", 0, "dccl"), f"DCCL id {m.id} is also {first.name}'s"
        else:
            yield (*loc, "elements", 0, "dccl"), (
                f"wire.format goby: channels {name!r} and {c.name!r} both carry DCCL message "
                f"{m.name} (id {m.id}); a Goby frame names no channel, so a receiver would "
                f"take both as {name!r}")
    # what zab says in entries of its own, which goby frames have no room for
    if table.names is not None:
        for c in table.channels:
            if c.family is not None and c.family.learned:
                yield ("channels", c.index), (f"wire.format goby: channel {c.name!r} cannot "
                                              "learn its key family's members (@key entries)")
    if table.interest is not None:
        yield ("demand",), "wire.format goby frames cannot say what is wanted (demand)"
    for i, query in enumerate(table.queries):
        yield ("queries", i), (f"wire.format goby: query {query.name!r} cannot cross (its "
                               "requests and replies are zab entries)")


def _empty_frame_problems(mission: Mission) -> Iterable[tuple[tuple[str | int, ...], str]]:
    """What would send a Goby frame with nothing in it (see the module docstring)."""
    if mission.link.heartbeat_s is not None:
        yield ("link", "heartbeat_s"), ("wire.format goby frames cannot be empty: a node with "
                                        "nothing to send sends nothing (no heartbeats)")
    mac = mission.mac
    if isinstance(mac, PolledMac):
        yield ("mac", "type"), ("wire.format goby frames cannot be empty: a polled master "
                                "with nothing to send could not poll")
    elif isinstance(mac, NoMac | AlohaMac) and mac.ranging is not None:
        yield ("mac", "ranging"), ("wire.format goby frames cannot be empty (nor carry DLBL "
                                   "delays): ranging rounds need frames of their own")


class GobyFrameCodec(FrameCodec):
    """:class:`FrameCodec`'s interface over Goby-format frames (see the module docstring)."""

    empty_frames = False

    def __init__(self, table: ChannelTable, auth: Any = None) -> None:
        super().__init__(table, None)
        # Not on the wire: the frame builder reserves count_bits from the capacity and allows
        # 2**count_bits - 1 entries; body_capacity_bits gives the reservation back.
        self.count_bits = _COUNT_BITS
        self.index_bits = 0
        self.delay_count = 0
        self.delay_bytes = 0
        self.auth_bytes = 0
        self.by_id: dict[int, tuple[ChannelCodec, DcclMessage]] = {}
        for c in table.channels:
            layout = _dccl_of(c)
            if layout is not None:
                self.by_id.setdefault(layout.message.id, (c, layout.message))
        self._messages = {i: m for i, (_, m) in self.by_id.items()}

    def overhead_bytes(self) -> int:
        return 0

    def body_capacity_bits(self, frame_bytes: int) -> int:
        return frame_bytes * 8 + self.count_bits

    def channel_cost_bits(self, channel: WireCodec) -> int:
        """Bits the channel's message may take: its maximum size in whole bytes."""
        return int(channel.wire_bits)

    def frame_bytes_for(self, channels: Sequence[WireCodec]) -> int:
        return sum(int(c.wire_bits) for c in channels) // 8

    def sender_fingerprint(self, frame: bytes) -> int | None:
        """Goby frames carry no check value: nothing tells another mission file apart."""
        return None

    def encode(self, items: Sequence[tuple[WireCodec, int]],
               delays: Sequence[int | None] = (), epoch: int = 0,
               now: float | None = None, prefix: bytes = b"") -> bytes:
        """The DCCL messages of ``items`` (payload ints as from ``ChannelCodec.pack``),
        concatenated without their padding (Goby frames have no network header: ``prefix``
        stays empty, the loader refuses goby with several links). A frame holds at least one
        message: ``ValueError`` without one (the frame builder sends nothing instead)."""
        if not items:
            raise ValueError("a Goby frame carries at least one DCCL message")
        out = []
        for channel, payload in items:
            layout = _dccl_of(channel) if isinstance(channel, ChannelCodec) else None
            if layout is None:
                raise ValueError(f"channel {channel.name!r} is not a DCCL channel")
            data = payload.to_bytes(layout.nbytes, "big")
            _, used = layout.message.decode_prefix(data)
            out.append(data[:used])
        return b"".join(out)

    def decode(self, frame: bytes, src: int | None = None, now: float | None = None,
               start: int = 0) -> DecodedFrame:
        """Messages as Goby3 decodes them; ``FrameError`` if not even the first decodes."""
        if not isinstance(frame, bytes | bytearray | memoryview):
            raise FrameError(f"a frame is bytes, not {type(frame).__name__}")
        try:
            found = decode_repeated(bytes(frame), self._messages)
        except DecodeError as exc:
            raise FrameError(f"no DCCL message decodes: {exc}") from None
        if not found:
            raise FrameError("empty frame")
        entries = tuple(Entry(self.by_id[m.id][0], [value]) for m, value in found)
        return DecodedFrame((), entries)


def frame_codec_class(wire_format: str) -> type[FrameCodec]:
    """The frame codec of a mission's ``wire.format``."""
    return GobyFrameCodec if wire_format == "goby" else FrameCodec


def frame_codec_for(table: ChannelTable, auth: Any = None) -> FrameCodec:
    """The frame codec of the mission's wire format."""
    return frame_codec_class(getattr(table, "wire_format", "zab"))(table, auth)
