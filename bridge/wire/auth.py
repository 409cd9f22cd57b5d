"""Authenticated frames: a counter and a truncated keyed hash, so nobody without the mission key
can forge, alter or replay a frame (pure).

A sealed frame is the plain frame's bytes (without its check value), then::

    counter  32 bits  strictly increasing per sender; starts from the clock (1/16 s units) so
                      a restarted node does not fall behind what receivers already saw
    tag      tag_bytes × 8 bits: HMAC-SHA256(key, fingerprint ‖ sender address ‖ everything
                      before the tag), truncated

and the usual 16-bit check value last, so a frame from another mission file is still told apart
(``check``) from a forged one (``forged``).
"""

from __future__ import annotations

import hashlib
import hmac
import os
from pathlib import Path

from bridge.errors import FrameError, MissionError

COUNTER_BYTES = 4
COUNTER_TICKS_PER_S = 16
_COUNTER_MOD = 1 << (8 * COUNTER_BYTES)


def load_key(key_env: str, key_file: Path | None) -> bytes:
    """The mission key from the environment variable, else the file; never from the mission."""
    value = os.environ.get(key_env)
    if value:
        return value.encode()
    if key_file is not None:
        try:
            key = key_file.read_bytes().strip()
        except OSError as exc:
            raise MissionError(f"cannot read the frame key file {key_file}: {exc}") from None
        if key:
            return key
    where = f"${key_env}" + (f" or {key_file}" if key_file else "")
    raise MissionError(f"wire.auth is on but no key was found in {where}")


class Authenticator:
    """Seals outgoing frames and checks incoming ones for one node."""

    def __init__(self, key: bytes, fingerprint: bytes, address: int, tag_bytes: int) -> None:
        if len(key) < 16:
            raise MissionError("the frame key must be at least 16 bytes long")
        self._key = key
        self._fingerprint = fingerprint
        self.address = address
        self.tag_bytes = tag_bytes
        self._counter = -1
        self._seen: dict[int, int] = {}

    @property
    def overhead_bytes(self) -> int:
        return COUNTER_BYTES + self.tag_bytes

    def _tag(self, src: int, data: bytes) -> bytes:
        mac = hmac.new(self._key, self._fingerprint + src.to_bytes(2, "big") + data,
                       hashlib.sha256)
        return mac.digest()[: self.tag_bytes]

    def next_counter(self, now: float) -> int:
        self._counter = max(self._counter + 1, int(now * COUNTER_TICKS_PER_S)) % _COUNTER_MOD
        return self._counter

    def seal(self, frame: bytes, now: float) -> bytes:
        """``frame`` followed by this node's next counter and the tag."""
        data = frame + self.next_counter(now).to_bytes(COUNTER_BYTES, "big")
        return data + self._tag(self.address, data)

    def open(self, sealed: bytes, src: int) -> bytes:
        """The frame inside ``sealed`` from ``src``; FrameError if forged, altered or replayed."""
        if len(sealed) < self.overhead_bytes:
            raise FrameError("truncated frame: no room for the counter and tag")
        data, tag = sealed[: -self.tag_bytes], sealed[-self.tag_bytes:]
        if not hmac.compare_digest(tag, self._tag(src, data)):
            raise FrameError("forged or altered frame: the authentication tag does not match",
                             "forged")
        counter = int.from_bytes(data[-COUNTER_BYTES:], "big")
        if counter <= self._seen.get(src, -1):
            raise FrameError(f"replayed frame: counter {counter} already seen from {src}",
                             "replayed")
        self._seen[src] = counter
        return data[:-COUNTER_BYTES]
