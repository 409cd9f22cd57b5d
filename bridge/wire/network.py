"""The network header (wire version 2, network version 1): what a frame of a mission with
several links or routes carries before the frame itself, and bundles of such frames (pure).

Layout, most significant bit first, padded with zeros to a whole byte::

    kind     2 bits  0: a frame of its sender for its neighbours; 1: a frame that relays
                     carry (its sender's own, or one it forwards), the fields in [] follow;
                     2: a bundle (below)
    for      N bits  bit i (first bit: the mission's first node) set: the frame carries
                     channel entries for that node. A node takes a frame's channel entries
                     only when its bit is set (so a frame overheard on a link that is not the
                     one chosen for it is not taken twice); relays forward it for the nodes
                     whose route from its sender goes through them.
    [origin  ceil(log2 N) bits  the node that built the frame
     hops    3 bits  relays it has crossed (the mission's max_hops, at most 8, bounds it)
     seq     8 bits  the origin's routed-frame number: a node takes each (origin, seq) once
     life    8 bits  seconds the frame may still spend at relays (255: no limit): the
                     shortest ttl_s of what it carries, less its age; a relay drops it after
     age     8 bits  seconds since the origin built it (saturating at 255), grown by each relay
     rank    ceil(log2 P) bits  how urgent it is: the place of its highest channel priority
                     among the mission's P channel priorities (relays send higher first)
     via     ceil(log2 N) bits  only in missions whose routes list several hops: the next
                     hop its sender chose among them (a relay carries on a destination its
                     sender lists several hops for only when it is the one named here)]

The frame follows, exactly as the origin built it (its DLBL delays, epoch, entries and
authentication), and the check value covers the header and the frame: a relay rewrites the
header's ``for``, ``hops``, ``life`` and ``age`` and the check, never the frame, whose
authentication (when the mission has it) is the origin's: a relay cannot forge or replay what
it carries (bridge.wire.auth).

A *bundle* puts several such frames in one transmission (a relay's own frame beside frames it
carries, each whole, with its own check)::

    kind     2 bits  2
    count    6 bits  frames in the bundle, less one
    count ×  length  8 bits  bytes of the next frame (1 to 255)
             frame   a network header and a frame, as above
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from bridge.errors import FrameError
from bridge.frozen import direct_init

__all__ = ["BUNDLE_MAX", "NET_VERSION", "NO_LIMIT", "NetCodec", "NetHeader"]

NET_VERSION = 1
KIND_BITS = 2
PLAIN, ROUTED, BUNDLE = 0, 1, 2
HOPS_BITS = 3
SEQ_BITS = 8
TIME_BITS = 8
NO_LIMIT = (1 << TIME_BITS) - 1
"""``life`` of a frame without a TTL."""
SEQ_MOD = 1 << SEQ_BITS
BUNDLE_MAX = 64
"""Frames in one bundle at most (its count field)."""
SEGMENT_MAX = 255
"""Bytes of one frame in a bundle at most (its length field)."""


@direct_init
@dataclass(frozen=True)
class NetHeader:
    """A frame's network header: the nodes it serves (indices in the mission) and, when
    relays carry it, its origin, hops, number, life and age (seconds) and rank."""

    serves: frozenset[int]
    origin: int | None = None
    hops: int = 0
    seq: int = 0
    life: int = NO_LIMIT
    age: int = 0
    rank: int = 0
    via: int = 0

    @property
    def routed(self) -> bool:
        return self.origin is not None


class NetCodec:
    """Encode and decode the network header of one mission (``nodes`` nodes, ``ranks``
    channel priorities, ``via``: routes list several hops), and bundles."""

    def __init__(self, nodes: int, ranks: int, via: bool = False) -> None:
        self.nodes = nodes
        self.origin_bits = (nodes - 1).bit_length()
        self.rank_bits = (max(ranks, 1) - 1).bit_length()
        self.via_bits = self.origin_bits if via else 0
        self.plain_bits = KIND_BITS + nodes
        self.routed_bits = (self.plain_bits + self.origin_bits + HOPS_BITS + SEQ_BITS
                            + 2 * TIME_BITS + self.rank_bits + self.via_bits)
        self.plain_bytes = (self.plain_bits + 7) // 8
        self.routed_bytes = (self.routed_bits + 7) // 8

    def describe(self) -> str:
        """What both ends must agree on (part of the mission fingerprint)."""
        return f"net{NET_VERSION}:{self.nodes}:{self.rank_bits}" + (":via" if self.via_bits
                                                                     else "")

    def bitmap(self, nodes: Iterable[int]) -> int:
        """The ``for`` field of ``nodes``: the first node is the most significant bit."""
        n = 0
        for i in nodes:
            n |= 1 << (self.nodes - 1 - i)
        return n

    # -- one frame -----------------------------------------------------------------------------

    def encode(self, header: NetHeader) -> bytes:
        acc = ((ROUTED if header.routed else PLAIN) << self.nodes) | self.bitmap(header.serves)
        nbits = self.plain_bits
        if header.origin is not None:
            for value, bits in ((header.origin, self.origin_bits), (header.hops, HOPS_BITS),
                                (header.seq, SEQ_BITS), (header.life, TIME_BITS),
                                (header.age, TIME_BITS), (header.rank, self.rank_bits),
                                (header.via, self.via_bits)):
                if not 0 <= value < 1 << bits:
                    raise ValueError(f"network header field {value} does not fit {bits} bits")
                acc = (acc << bits) | value
            nbits = self.routed_bits
        pad = -nbits % 8
        return (acc << pad).to_bytes((nbits + pad) // 8, "big")

    def decode(self, frame: bytes) -> tuple[NetHeader, int]:
        """The header at the start of ``frame`` and its length in bytes; FrameError when the
        frame is too short, a bundle, or names an unknown node."""
        if not frame:
            raise FrameError("truncated frame: no network header")
        kind = frame[0] >> (8 - KIND_BITS)
        if kind not in (PLAIN, ROUTED):
            raise FrameError(f"network header of kind {kind} where a frame was expected")
        routed = kind == ROUTED
        bits = self.routed_bits if routed else self.plain_bits
        size = (bits + 7) // 8
        if len(frame) < size:
            raise FrameError("truncated frame: the network header runs past the end")
        acc = int.from_bytes(frame[:size], "big") >> (-bits % 8)
        fields = []
        if routed:
            for width in (self.via_bits, self.rank_bits, TIME_BITS, TIME_BITS, SEQ_BITS,
                          HOPS_BITS, self.origin_bits):
                fields.append(acc & ((1 << width) - 1))
                acc >>= width
        bitmap = acc & ((1 << self.nodes) - 1)
        serves = frozenset(i for i in range(self.nodes) if bitmap >> (self.nodes - 1 - i) & 1)
        if not routed:
            return NetHeader(serves), size
        via, rank, age, life, seq, hops, origin = fields
        if origin >= self.nodes or via >= self.nodes:
            raise FrameError(f"network header names unknown node {max(origin, via)}")
        return NetHeader(serves, origin, hops, seq, life, age, rank, via), size

    # -- bundles -------------------------------------------------------------------------------

    @staticmethod
    def bundle_bytes(sizes: Iterable[int]) -> int:
        """Bytes of a bundle of frames of ``sizes`` bytes."""
        return 1 + sum(1 + n for n in sizes)

    @staticmethod
    def bundle(frames: Sequence[bytes]) -> bytes:
        """One transmission carrying ``frames`` (each a network header and frame)."""
        if not 1 <= len(frames) <= BUNDLE_MAX:
            raise ValueError(f"a bundle holds 1 to {BUNDLE_MAX} frames, not {len(frames)}")
        out = bytearray([(BUNDLE << (8 - KIND_BITS)) | (len(frames) - 1)])
        for frame in frames:
            if not 1 <= len(frame) <= SEGMENT_MAX:
                raise ValueError(f"a bundled frame has 1 to {SEGMENT_MAX} bytes")
            out.append(len(frame))
            out += frame
        return bytes(out)

    @staticmethod
    def unbundle(data: bytes) -> list[bytes] | None:
        """The frames of a bundle (None: ``data`` is one frame); FrameError when the lengths
        do not add up."""
        if not data or data[0] >> (8 - KIND_BITS) != BUNDLE:
            return None
        count = (data[0] & ((1 << (8 - KIND_BITS)) - 1)) + 1
        frames, at = [], 1
        for _ in range(count):
            if at >= len(data):
                raise FrameError("truncated bundle: a frame's length is missing")
            size = data[at]
            frame = data[at + 1:at + 1 + size]
            if size == 0 or len(frame) < size:
                raise FrameError("truncated bundle: a frame runs past the end")
            frames.append(frame)
            at += 1 + size
        if at != len(data):
            raise FrameError("trailing data after the bundle's last frame")
        return frames
