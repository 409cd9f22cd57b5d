"""Wire protocol between the water service and sim modems (loopback TCP).

Each message is a 4-byte big-endian length followed by a msgpack map whose ``"t"`` key names
the message type. Times are wall-clock seconds (``time.time()``), data is msgpack ``bin``.

Modem -> water::

    {"t": "hello", "v": 1, "addr": int, "name": str, "pos": [x, y, depth] | None,
     "losses": bool}                      (optional: also tell this modem of frames it lost)
    {"t": "tx", "id": int, "data": bytes, "dest": int | None, "at": float | None}
                                          (``at``: start then; already past: txerr "expired")
    {"t": "pos", "pos": [x, y, depth]}

Water -> modem::

    {"t": "welcome", "preset": str, "frame_bytes": int}
    {"t": "txdone", "id": int, "time": float}
    {"t": "txerr", "id": int, "reason": str, "error": str}
    {"t": "rx", "src": int, "data": bytes, "time": float, "meta": {...}}
    {"t": "lost", "src": int, "reason": str, "time": float, "dest": int | None}
                                          (only to a modem that asked: a frame it heard but
                                           could not decode, see DETECTED_LOSSES)
    {"t": "error", "error": str}          (fatal; the water closes the connection)

:class:`MessageReader` is the sans-I/O decoder; :func:`read_message` wraps it for asyncio streams.
"""

from __future__ import annotations

import asyncio
import struct
from typing import Any

import msgpack

from bridge.wire.payloads import why_undecodable

__all__ = [
    "DETECTED_LOSSES",
    "MAX_MESSAGE_BYTES",
    "PROTOCOL_VERSION",
    "MessageReader",
    "ProtocolError",
    "pack",
    "read_message",
]

PROTOCOL_VERSION = 1

DETECTED_LOSSES = frozenset({"collision", "range_loss", "loss", "bit_errors"})
"""Loss reasons of :mod:`bridge.sim.ocean` where the signal reached the receiver (it would see
a packet start and fail its CRC); out of range and half-duplex, nothing reached it."""

# Far above any frame plus metadata (frames are <= a few hundred bytes); caps what a broken or
# hostile peer can make us buffer.
MAX_MESSAGE_BYTES = 64 * 1024

_LEN = struct.Struct(">I")


class ProtocolError(ValueError):
    """A peer sent bytes that are not a valid message."""


def pack(msg: dict[str, Any]) -> bytes:
    """Serialise one message, length prefix included."""
    body: bytes = msgpack.packb(msg, use_bin_type=True)
    if len(body) > MAX_MESSAGE_BYTES:
        raise ProtocolError(f"message of {len(body)} B exceeds {MAX_MESSAGE_BYTES} B")
    return _LEN.pack(len(body)) + body


def _unpack(body: bytes) -> dict[str, Any]:
    try:
        msg = msgpack.unpackb(body, raw=False, strict_map_key=False)
    except Exception as exc:  # msgpack raises several unrelated types on garbage
        raise ProtocolError(f"undecodable message: {why_undecodable(exc, body)}") from None
    if not isinstance(msg, dict) or not isinstance(msg.get("t"), str):
        raise ProtocolError("message is not a map with a string 't'")
    return msg


class MessageReader:
    """Sans-I/O decoder: :meth:`feed` bytes in any fragments, get whole messages back."""

    def __init__(self) -> None:
        self._buf = bytearray()

    def feed(self, data: bytes) -> list[dict[str, Any]]:
        """Add bytes; return every message now complete. Raises :class:`ProtocolError`."""
        self._buf += data
        out: list[dict[str, Any]] = []
        while len(self._buf) >= _LEN.size:
            (n,) = _LEN.unpack_from(self._buf)
            if n > MAX_MESSAGE_BYTES:
                raise ProtocolError(f"message length {n} exceeds {MAX_MESSAGE_BYTES}")
            if len(self._buf) < _LEN.size + n:
                break
            body = bytes(self._buf[_LEN.size : _LEN.size + n])
            del self._buf[: _LEN.size + n]
            out.append(_unpack(body))
        return out


async def read_message(reader: asyncio.StreamReader) -> dict[str, Any] | None:
    """Read one message; ``None`` on a clean end of stream between messages.

    Raises :class:`ProtocolError` on garbage and ``asyncio.IncompleteReadError`` if the stream
    ends inside a message.
    """
    try:
        head = await reader.readexactly(_LEN.size)
    except asyncio.IncompleteReadError as exc:
        if not exc.partial:
            return None
        raise
    (n,) = _LEN.unpack(head)
    if n > MAX_MESSAGE_BYTES:
        raise ProtocolError(f"message length {n} exceeds {MAX_MESSAGE_BYTES}")
    return _unpack(await reader.readexactly(n))
