"""The ``@want`` system entry: which of the mission's channels a node's applications want.

Present in missions with ``demand``. One bit per mission channel, channel 0 most significant:
bit set = some application at the sending node subscribes to that channel's output key. A frame
carries at most one. Pure: no clock, no I/O.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

WANT_PRIORITY = 1 << 21  # interest goes first: it decides what the others send


@dataclass(frozen=True)
class InterestCodec:
    """A bitmap over the ``channels`` channels of the mission."""

    index: int
    channels: int
    name: str = "@want"
    repeatable: bool = False
    priority: int = WANT_PRIORITY

    @property
    def wire_bits(self) -> int:
        return self.channels

    def pack(self, wanted: Iterable[int]) -> int:
        n = 0
        for index in wanted:
            if not 0 <= index < self.channels:
                raise ValueError(f"no channel {index}")
            n |= 1 << (self.channels - 1 - index)
        return n

    def unpack(self, n: int) -> frozenset[int]:
        return frozenset(i for i in range(self.channels) if n >> (self.channels - 1 - i) & 1)
