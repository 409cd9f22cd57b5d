"""The ``@mark`` system entry of authenticated missions: where a peer's counter must resume.

A receiver refuses a frame whose counter is at or below the highest it accepted from that
sender (a replay). When such a frame carries a valid tag, either someone replayed it or its
sender lost its state and counts from the start again; the receiver cannot tell which, and
need not: it answers in its next frames with ``@mark``, naming the sender and its mark. A
sender hearing its own name there resumes its counter past the mark
(:meth:`~bridge.wire.auth.Authenticator.resume_past`); to a replayer's victim, whose counter is
past it already, it changes nothing. See docs/wire-format.md.

Fields, most significant first: the sender's place in the mission (``peer_bits``), then the
64-bit mark.
"""

from __future__ import annotations

from dataclasses import dataclass

MARK_BITS = 64
MARK_PRIORITY = 1 << 22  # before anything else: it lets a peer be heard again


@dataclass(frozen=True)
class MarkCodec:
    """The ``@mark`` entry, after every other entry of an authenticated mission."""

    index: int
    peer_bits: int
    name: str = "@mark"
    repeatable: bool = False  # (one a frame: the count field keeps its size)
    priority: int = MARK_PRIORITY

    @property
    def wire_bits(self) -> int:
        return self.peer_bits + MARK_BITS

    def pack(self, peer: int, mark: int) -> int:
        return (peer << MARK_BITS) | (mark & ((1 << MARK_BITS) - 1))

    def unpack(self, n: int) -> tuple[int, int]:
        """``(peer, mark)``."""
        return n >> MARK_BITS, n & ((1 << MARK_BITS) - 1)
