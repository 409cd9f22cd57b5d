"""The attachment rmw_zenoh puts on every published sample (sans I/O).

rmw_zenoh_cpp's ``attachment_helpers.cpp`` (since Jazzy 0.2.4 / Humble 0.1.2, PR #601/#605)
writes, with zenoh-cpp's ``ext::Serializer``:

- the sequence number: int64, little-endian (8 bytes; a publisher's first message is 1);
- the source timestamp: int64 nanoseconds since the Unix epoch, little-endian (8 bytes);
- the publisher GID: ``std::array<uint8_t, 16>``, serialised as a sequence: its length as a
  LEB128 varint (one byte, 16) then the 16 bytes.

33 bytes in all. (Jazzy 0.2.0-0.2.3 used string keys before each value; not spoken here.)
The bridge's own publishers use GIDs starting with :data:`BRIDGE_GID_PREFIX`, so a bridge
never takes a sample it published itself for new input (loop safety).
"""

from __future__ import annotations

import hashlib
import struct
from dataclasses import dataclass

from bridge.errors import DecodeError

GID_SIZE = 16  # RMW_GID_STORAGE_SIZE
ATTACHMENT_SIZE = 8 + 8 + 1 + GID_SIZE
BRIDGE_GID_PREFIX = b"zab/"
_LAYOUT = struct.Struct("<qqB16s")


@dataclass(frozen=True)
class Attachment:
    """What a ROS 2 subscriber learns about a sample besides its payload."""

    sequence_number: int
    source_timestamp_ns: int
    gid: bytes

    def pack(self) -> bytes:
        if len(self.gid) != GID_SIZE:
            raise ValueError(f"a GID has {GID_SIZE} bytes, not {len(self.gid)}")
        return _LAYOUT.pack(self.sequence_number, self.source_timestamp_ns, GID_SIZE, self.gid)

    @classmethod
    def unpack(cls, data: bytes) -> Attachment:
        """Parse an attachment; ``DecodeError`` if it is not rmw_zenoh's 33-byte layout."""
        if len(data) != ATTACHMENT_SIZE:
            raise DecodeError(f"an rmw_zenoh attachment has {ATTACHMENT_SIZE} bytes, "
                              f"not {len(data)}")
        seq, stamp, length, gid = _LAYOUT.unpack(data)
        if length != GID_SIZE:
            raise DecodeError(f"GID length {length}, expected {GID_SIZE}")
        return cls(seq, stamp, gid)


def bridge_gid(*parts: str) -> bytes:
    """A stable 16-byte GID for one bridge publisher: the marker, then 12 hash bytes."""
    digest = hashlib.sha256("\0".join(parts).encode()).digest()
    return BRIDGE_GID_PREFIX + digest[: GID_SIZE - len(BRIDGE_GID_PREFIX)]


def from_bridge(attachment: bytes) -> bool:
    """True when ``attachment`` is rmw_zenoh's and names a bridge publisher's GID."""
    return (len(attachment) == ATTACHMENT_SIZE and attachment[16] == GID_SIZE
            and attachment[17:17 + len(BRIDGE_GID_PREFIX)] == BRIDGE_GID_PREFIX)
