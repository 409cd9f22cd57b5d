"""The acoustic frame (wire version 2), pure.

Layout, most significant bit first::

    [DLBL]   dlbl missions only: 24 bits per foreign node of the SENDER, in mission order:
             µs from the sender's last reception from that node to this frame's start;
             0xFFFFFF = no data.
    [epoch]  missions with reliable or fragmented channels: 8 bits, the sender's stream epoch
             (it changes only when a node starts without its saved state; see bridge.core)
    count    ceil(log2(C + 1)) bits: how many entries follow (C = channels in the mission,
             plus ``@want`` in demand missions); 6 bits when entries may repeat
    count ×  index   ceil(log2 W) bits (0 bits when W == 1), W = C plus the ``@ack`` entry
                     when the mission has reliable or fragmented channels
             entry   plain channel: its fixed number of bits (its elements' layouts, in order);
                     reliable: seq (8) + lag (4) + the value; fragment: transfer id (4) +
                     index + count + a chunk of the packed value; ``@ack``: see AckCodec;
                     key family: member index (ceil(log2 n) bits) + the value; ``@key``
                     (learned families): see bridge.wire.families.NameCodec; ``@want``
                     (demand missions): see bridge.wire.interest.InterestCodec; query
                     request ``?name`` / reply ``!name``: see bridge.wire.queries;
                     ``@mark`` (authenticated missions): see bridge.wire.marks.
             Only reliable, fragmented, keyed and system entries may repeat in a frame.
    pad      zero bits up to the next byte
    [auth]   authenticated missions only: 32-bit counter + truncated HMAC tag (bridge.wire.auth);
             with wire.auth.encrypt the frame is sealed instead: everything after the DLBL
             delays encrypted, the counter before it and the cipher's tag after it
             (bridge.wire.seal)
    check    16 bits: CRC-16/CCITT (init 0xFFFF) of every byte before the check, XOR the first
             two bytes of the mission fingerprint. A receiver XORs them back: its own
             fingerprint means a whole frame; the same other value from one sender, frame
             after frame, means that sender runs another mission file (a corrupt frame gives
             a random value instead).

:class:`FrameCodec` builds and parses frames for one :class:`~bridge.wire.channels.ChannelTable`;
:meth:`FrameCodec.decode` raises :class:`~bridge.errors.FrameError` and nothing else.
"""

from __future__ import annotations

import binascii
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

from bridge.errors import DecodeError, FrameError
from bridge.frozen import direct_init
from bridge.wire.auth import COUNTER_BYTES, Authenticator
from bridge.wire.channels import (
    COUNT_BITS_REPEATABLE,
    EPOCH_BITS,
    LAG_BITS,
    AckCodec,
    ChannelCodec,
    ChannelTable,
    Values,
)
from bridge.wire.families import NameCodec
from bridge.wire.interest import InterestCodec
from bridge.wire.marks import MarkCodec
from bridge.wire.queries import QueryCodec, ReplyStatus

DELAY_BYTES = 3
DELAY_MAX_US = (1 << 24) - 2  # largest delay sent; a longer one wraps (see ranging)
NO_DELAY = (1 << 24) - 1  # "no reception from that node yet"
CHECK_BYTES = 2


WireCodec = ChannelCodec | AckCodec | NameCodec | InterestCodec | QueryCodec | MarkCodec
"""Anything with an index on the wire: a channel or a system entry."""


def _runs_past() -> FrameError:
    return FrameError("truncated frame: a channel runs past the end")


@direct_init
@dataclass(frozen=True)
class Entry:
    """One entry of a frame.

    ``values``: the element values (plain and reliable channels). ``header``: reliable
    ``(seq, lag)``; fragment ``(tid, index, count)``; ``@ack`` ``(peer, stream, epoch, tid,
    base, bitmap)``; query ``(qid, node, status, index, reason)`` (``reason``: a failed
    reply's :class:`~bridge.wire.queries.FailReason` code, else 0). ``chunk``: a fragment's
    bytes.
    """

    channel: WireCodec
    values: Values | None = None
    header: tuple[Any, ...] = ()
    chunk: bytes = b""


@direct_init
@dataclass(frozen=True)
class DecodedFrame:
    """What a frame carried: DLBL delays (µs or None), its entries in order, and the sender's
    stream epoch (None in missions without streams)."""

    delays: tuple[int | None, ...]
    entries: tuple[Entry, ...]
    epoch: int | None = None

    @property
    def channels(self) -> tuple[tuple[ChannelCodec, Values], ...]:
        """The plain (latest-value) channels and their element values."""
        return tuple((e.channel, e.values) for e in self.entries
                     if isinstance(e.channel, ChannelCodec) and not e.channel.stream
                     and e.values is not None)


def check_value(body: bytes, fingerprint: bytes) -> bytes:
    """The check a frame of ``body`` ends with: CRC-16/CCITT XOR the fingerprint's first two
    bytes."""
    crc = binascii.crc_hqx(body, 0xFFFF) ^ int.from_bytes(fingerprint[:2], "big")
    return crc.to_bytes(CHECK_BYTES, "big")


class FrameCodec:
    """Encode and decode frames of one mission."""

    empty_frames: ClassVar[bool] = True
    """A frame without entries is a frame of this format (zab's: its header, count and check,
    a heartbeat). A format without one (Goby's) sends nothing when nothing is due."""

    def __init__(self, table: ChannelTable, auth: Authenticator | None = None) -> None:
        self.table = table
        self.auth = auth
        self.auth_bytes = (COUNTER_BYTES + table.auth_tag_bytes) if table.auth_tag_bytes else 0
        self.wire = table.wire
        n = len(self.wire)
        self.repeats = any(w.repeatable for w in self.wire)
        # count: ceil(log2(n + 1)) bits, or room for repeated entries
        self.count_bits = (COUNT_BITS_REPEATABLE if self.repeats
                           else len(self.wire).bit_length())
        self.index_bits = (n - 1).bit_length() if n > 1 else 0
        self.delay_count = len(table.nodes) - 1 if table.dlbl else 0
        self.delay_bytes = DELAY_BYTES * self.delay_count
        self.epoch_bits = EPOCH_BITS if table.streams else 0
        self.fingerprint16 = int.from_bytes(table.fingerprint[:2], "big")
        self.min_frame_bytes = self.overhead_bytes() + (
            self.epoch_bits + self.count_bits + 7) // 8
        """The shortest frame: no entry."""

    # -- sizes ---------------------------------------------------------------------------------

    def overhead_bytes(self) -> int:
        """Bytes every frame spends outside channel data, not counting the count field."""
        return self.delay_bytes + self.auth_bytes + CHECK_BYTES

    def body_capacity_bits(self, frame_bytes: int) -> int:
        """Bits left for the count field and channels in a frame of ``frame_bytes``."""
        return max(0, (frame_bytes - self.overhead_bytes()) * 8 - self.epoch_bits)

    def channel_cost_bits(self, channel: WireCodec) -> int:
        """Bits one entry takes in a frame: its index plus its payload."""
        return self.index_bits + channel.wire_bits

    def frame_bytes_for(self, channels: Sequence[WireCodec]) -> int:
        """Size of a frame carrying exactly ``channels``."""
        body = self.epoch_bits + self.count_bits + sum(self.channel_cost_bits(c)
                                                       for c in channels)
        return self.overhead_bytes() + (body + 7) // 8

    # -- encode --------------------------------------------------------------------------------

    def encode(
        self,
        items: Sequence[tuple[WireCodec, int]],
        delays: Sequence[int | None] = (),
        epoch: int = 0,
        now: float | None = None,
        prefix: bytes = b"",
    ) -> bytes:
        """A frame carrying ``(channel, entry bits)`` items, for DLBL the delays, and in
        missions with streams the sender's ``epoch``; ``now``: the sender's clock (sealed
        frames choose their key by it); ``prefix`` (a network header, bridge.wire.network)
        goes before it, covered by the check but not sealed."""
        if len(delays) != self.delay_count:
            raise ValueError(f"expected {self.delay_count} DLBL delays, got {len(delays)}")
        acc, nbits = 0, 0
        for delay in delays:
            value = NO_DELAY if delay is None else min(max(int(delay), 0), DELAY_MAX_US)
            acc, nbits = (acc << 24) | value, nbits + 24
        if self.epoch_bits:
            acc, nbits = (acc << EPOCH_BITS) | (epoch & ((1 << EPOCH_BITS) - 1)), nbits + 8
        if len(items) >= 1 << self.count_bits:
            raise ValueError(f"{len(items)} entries exceed the frame's count field")
        acc, nbits = (acc << self.count_bits) | len(items), nbits + self.count_bits
        seen: set[int] = set()
        for channel, payload in items:
            if channel.index in seen and not channel.repeatable:
                raise ValueError(f"channel {channel.name!r} twice in one frame")
            seen.add(channel.index)
            acc = (((acc << self.index_bits) | channel.index) << channel.wire_bits) | payload
            nbits += self.index_bits + channel.wire_bits
        pad = -nbits % 8
        data = (acc << pad).to_bytes((nbits + pad) // 8, "big")
        if self.table.auth_tag_bytes:
            if self.auth is None:
                raise ValueError("this mission authenticates frames: no Authenticator given")
            data = self.auth.seal(data, now)
        data = prefix + data
        return data + check_value(data, self.table.fingerprint)

    # -- decode --------------------------------------------------------------------------------

    def sender_fingerprint(self, frame: bytes) -> int | None:
        """The 16-bit fingerprint ``frame`` was sent with (ours: a whole frame of this mission
        file; another: corrupt, or another mission file), or None if too short to tell."""
        if len(frame) <= CHECK_BYTES:
            return None
        body, check = frame[:-CHECK_BYTES], frame[-CHECK_BYTES:]
        return binascii.crc_hqx(body, 0xFFFF) ^ int.from_bytes(check, "big")

    def vouch(self, frame: bytes, src: int, fingerprint: int) -> int | None:
        """The counter ``frame`` was sealed with by a holder of the key, ``src``, under another
        mission file whose 16-bit fingerprint is ``fingerprint``; None if it was not (corrupt,
        forged) or this mission does not authenticate."""
        if self.auth is None or len(frame) < CHECK_BYTES + self.auth_bytes:
            return None
        return self.auth.vouch(frame[:-CHECK_BYTES], src, fingerprint)

    def decode(self, frame: bytes, src: int | None = None, now: float | None = None,
               start: int = 0) -> DecodedFrame:
        """Parse untrusted bytes; raise :class:`FrameError` for anything but a valid frame.

        Authenticated missions need ``src``, the sender's modem address (and sealed ones the
        receiver's clock, ``now``, to choose the key); ``start``: bytes of network header
        before the frame (the check covers them too).
        """
        if frame.__class__ is not bytes:
            if not isinstance(frame, bytes | bytearray | memoryview):
                raise FrameError(f"a frame is bytes, not {type(frame).__name__}")
            frame = bytes(frame)
        if len(frame) - start < self.min_frame_bytes:
            raise FrameError(f"truncated frame: {len(frame) - start} bytes, at least "
                             f"{self.min_frame_bytes} needed")
        body, check = frame[:-CHECK_BYTES], frame[-CHECK_BYTES:]
        fingerprint = binascii.crc_hqx(body, 0xFFFF) ^ int.from_bytes(check, "big")
        if fingerprint != self.fingerprint16:
            raise FrameError("check failed: corrupt frame, or sent with another mission file "
                             f"(fingerprint {fingerprint:04x})", "check", fingerprint)
        if start:
            body = body[start:]
        if self.auth_bytes:
            if self.auth is None or src is None:
                raise FrameError("cannot authenticate: no key or no sender address", "forged")
            body = self.auth.open(body, src, now)
        acc = int.from_bytes(body, "big")
        left = len(body) * 8  # bits not read yet; each field is read from the top down
        if self.delay_count:
            if left < 24 * self.delay_count:
                raise _runs_past()
            raw = []
            for _ in range(self.delay_count):
                left -= 24
                raw.append((acc >> left) & 0xFFFFFF)
            delays = tuple(None if d == NO_DELAY else d for d in raw)
        else:
            delays = ()
        epoch = None
        if self.epoch_bits:
            if left < EPOCH_BITS:
                raise _runs_past()
            left -= EPOCH_BITS
            epoch = (acc >> left) & ((1 << EPOCH_BITS) - 1)
        if left < self.count_bits:
            raise _runs_past()
        left -= self.count_bits
        count = (acc >> left) & ((1 << self.count_bits) - 1)
        wire = self.wire
        if not self.repeats and count > len(wire):
            raise FrameError(f"frame claims {count} channels, the mission has {len(wire)}")
        entries: list[Entry] = []
        seen: set[int] = set()
        index_bits, index_mask = self.index_bits, (1 << self.index_bits) - 1
        for _ in range(count):
            if left < index_bits:
                raise _runs_past()
            left -= index_bits
            index = (acc >> left) & index_mask
            if index >= len(wire) or (index in seen and not wire[index].repeatable):
                raise FrameError(f"bad or repeated channel index {index}")
            seen.add(index)
            channel = wire[index]
            bits = channel.wire_bits
            if left < bits:
                raise _runs_past()
            left -= bits
            payload = (acc >> left) & ((1 << bits) - 1)
            try:
                entries.append(Entry(channel, channel.unpack(payload))  # the usual entry
                               if channel.__class__ is ChannelCodec and channel.plain
                               else self._entry(channel, payload))
            except DecodeError as exc:
                raise FrameError(f"channel {channel.name!r}: {exc}") from None
        if left >= 8 or acc & ((1 << left) - 1):
            raise FrameError("trailing data after the last channel")
        return DecodedFrame(delays, tuple(entries), epoch)

    def _entry(self, channel: WireCodec, payload: int) -> Entry:
        """One entry's fields, checked (but a plain channel's: :meth:`decode` unpacks those
        itself); raises :class:`DecodeError` when malformed."""
        if isinstance(channel, QueryCodec):
            qid, node, status, index, packed = channel.unpack(payload)
            if node >= len(self.table.nodes):
                raise DecodeError(f"names unknown node {node}")
            if index >= channel.spec.max_replies:
                raise DecodeError(f"reply index {index} beyond max_replies")
            carries = not channel.reply or status <= ReplyStatus.LAST
            reason = packed if status == ReplyStatus.FAILED else 0  # (a FailReason, or other)
            return Entry(channel, [channel.layout.unpack(packed)] if carries else None,
                         (qid, node, status, index, reason))
        if isinstance(channel, MarkCodec):
            peer, mark = channel.unpack(payload)
            if peer >= len(self.table.nodes):
                raise DecodeError(f"names unknown node {peer}")
            return Entry(channel, header=(peer, mark))
        if isinstance(channel, InterestCodec):
            return Entry(channel, header=tuple(sorted(channel.unpack(payload))))
        if isinstance(channel, NameCodec):
            try:
                return Entry(channel, header=channel.unpack(payload))
            except ValueError as exc:
                raise DecodeError(str(exc)) from None
        if isinstance(channel, AckCodec):
            header = channel.unpack(payload)
            peer, stream = header[:2]
            if peer >= len(self.table.nodes) or stream >= len(self.table.streams):
                raise DecodeError(f"acknowledges unknown node {peer} or stream {stream}")
            return Entry(channel, header=header)
        if channel.fragmented:
            data_bits = 8 * channel.chunk_bytes
            chunk = (payload & ((1 << data_bits) - 1)).to_bytes(channel.chunk_bytes, "big")
            head = payload >> data_bits
            fbits = channel.fragment_bits
            count = head & ((1 << fbits) - 1)
            index = (head >> fbits) & ((1 << fbits) - 1)
            tid = head >> (2 * fbits)
            most = -(-channel.value_bytes // channel.chunk_bytes)
            if not 0 <= index < count <= most:
                raise DecodeError(f"fragment {index} of {count} (at most {most})")
            return Entry(channel, header=(tid, index, count), chunk=chunk)
        values = channel.unpack(payload & ((1 << channel.bits) - 1))
        if channel.family is not None:
            member = payload >> channel.bits
            if member >= channel.family.bound:
                raise DecodeError(f"member {member} of {channel.family.bound}")
            return Entry(channel, values, (member,))
        if channel.reliable:
            head = payload >> channel.bits
            seq, lag = head >> LAG_BITS, head & ((1 << LAG_BITS) - 1)
            return Entry(channel, values, (seq, lag))
        return Entry(channel, values)
