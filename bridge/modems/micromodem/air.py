"""What an emulated Micro-Modem puts in the simulated water besides the bytes (pure).

A real modem's receiver tells packets apart by their waveform (FSK or PSK, mini-packet, FM
probe, nav tone) and reads the cycle-init fields from the packet header; the emulators carry
what the waveform conveys in the water's ``dest`` metadata instead, as one integer
(:func:`pack_header`). A data packet goes as one transmission of all its frames
(:func:`pack_frames`).
"""

from __future__ import annotations

import dataclasses
import enum
from typing import Any

__all__ = ["AirKind", "Header", "pack_frames", "pack_header", "unpack_frames", "unpack_header"]


class AirKind(enum.IntEnum):
    """What an acoustic transmission is."""

    CYCLE_INIT = 1
    DATA = 2
    ACK = 3
    PING = 4
    PING_REPLY = 5
    MINI = 6
    FDP = 7
    NAV = 8  # an LBL interrogation ($CCPDT, $CCPNT)
    NAV_REPLY = 9  # a transponder's answer
    FDP_PING = 10  # $CCCMD,PNG
    FDP_PING_REPLY = 11
    MEC = 12  # $CCMEC to another modem
    MEC_REPLY = 13
    SWEEP = 14  # $CCRSP
    FDP_ACK = 15


# (field, width in bits), from the lowest bit up
_LAYOUT = (("kind", 5), ("src", 7), ("dest", 7), ("rate", 3), ("ack", 1), ("frame", 4),
           ("frames", 4), ("seq", 8), ("mini", 3))


@dataclasses.dataclass(frozen=True)
class Header:
    """The out-of-band header of one transmission. ``src`` is the cycle's source (it differs
    from the transmitter for a poll); ``frame`` is a kind's small number (a length-prefixed
    packet, a nav channel, a beacon); ``mini`` the rate of an FDP packet's mini-frames (0: none).
    """

    kind: AirKind
    src: int = 0
    dest: int = 0
    rate: int = 0
    ack: bool = False
    frame: int = 0
    frames: int = 0
    seq: int = 0
    mini: int = 0


def pack_header(h: Header) -> int:
    """The header as one integer for the water's ``dest`` field."""
    value, shift = 0, 0
    for name, width in _LAYOUT:
        field = int(getattr(h, name))
        if not 0 <= field < 1 << width:
            raise ValueError(f"header field {name}={field} does not fit {width} bits")
        value |= field << shift
        shift += width
    return value


def unpack_header(value: Any) -> Header | None:
    """The header from a reception's ``dest`` metadata; ``None`` if it is not one of ours."""
    if not isinstance(value, int) or isinstance(value, bool) or value < 0:
        return None
    fields: dict[str, int] = {}
    for name, width in _LAYOUT:
        fields[name] = value & ((1 << width) - 1)
        value >>= width
    try:
        kind = AirKind(fields.pop("kind"))
    except ValueError:
        return None
    ack = bool(fields.pop("ack"))
    return Header(kind, ack=ack, **fields)


def pack_frames(frames: list[bytes], frame_bytes: int) -> tuple[bytes, bool]:
    """A packet's frames as one water transmission, and whether it is length-prefixed: the
    frames joined when all but the last are full (``frame_bytes``), as the host fills them;
    else one byte per frame (its length - 1) first."""
    if all(len(f) == frame_bytes for f in frames[:-1]):
        return b"".join(frames), False
    return bytes(len(f) - 1 for f in frames) + b"".join(frames), True


def unpack_frames(body: bytes, count: int, frame_bytes: int, prefixed: bool) -> list[bytes]:
    """The frames of :func:`pack_frames`; ``ValueError`` if ``body`` does not hold them."""
    if not prefixed:
        frames = [body[i : i + frame_bytes] for i in range(0, len(body), frame_bytes)]
        if len(frames) != count:
            raise ValueError("not a packet of frames")
        return frames
    frames, pos = [], count
    for size in body[:count]:
        frames.append(body[pos : pos + size + 1])
        pos += size + 1
    if count < 1 or len(body) < count or pos != len(body):
        raise ValueError("not a packet of frames")
    return frames
