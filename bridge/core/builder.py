"""Fill one frame from what is due: priority first, then oldest (pure)."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from bridge.core.store import ChannelState
from bridge.frozen import direct_init
from bridge.wire.channels import ChannelCodec
from bridge.wire.families import NameCodec
from bridge.wire.frame import FrameCodec
from bridge.wire.interest import InterestCodec
from bridge.wire.marks import MarkCodec
from bridge.wire.queries import QueryCodec

Offered = ChannelCodec | NameCodec | InterestCodec | QueryCodec | MarkCodec
"""What a candidate offers a frame an entry of: a channel or a system entry."""


@direct_init
@dataclass(frozen=True)
class FramePlan:
    """The channels chosen for a frame, and those that were due but did not fit."""

    chosen: tuple[ChannelState, ...]
    left_out: tuple[ChannelState, ...]


@direct_init
@dataclass(frozen=True)
class Candidate:
    """Something that could go in a frame as one entry of ``channel``: a latest-value channel
    (``what`` is its state) or a queued value or fragment. ``last_sent``: when the channel
    (for a stream, anything of it; in a key family, the member) last went in a frame.
    ``rank`` orders one channel's several candidates."""

    channel: Offered
    last_sent: float | None
    what: Any
    rank: int = 0

    def order(self) -> tuple[int, float, int, int]:
        """Higher priority first; among equals, what has waited longest since it was last
        sent (never sent counts as oldest), so a full frame rotates fairly."""
        last = self.last_sent if self.last_sent is not None else float("-inf")
        return (-self.channel.priority, last, self.channel.index, self.rank)


def fill(codec: FrameCodec, candidates: Iterable[Candidate], budget_bits: int,
         room: int) -> tuple[list[Candidate], list[Candidate]]:
    """Greedy packing into ``budget_bits`` and at most ``room`` entries: each candidate in
    order goes in when it still fits. Returns ``(chosen, left_out)``."""
    chosen: list[Candidate] = []
    left_out: list[Candidate] = []
    for candidate in sorted(candidates, key=Candidate.order):
        cost = codec.channel_cost_bits(candidate.channel)
        if cost <= budget_bits and len(chosen) < room:
            chosen.append(candidate)
            budget_bits -= cost
        else:
            left_out.append(candidate)
    return chosen, left_out

