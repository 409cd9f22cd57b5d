"""Fill one frame from the channels that are due: priority first, then oldest (pure)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from bridge.frame import FrameCodec
from bridge.store import ChannelState


@dataclass(frozen=True)
class FramePlan:
    """The channels chosen for a frame, and those that were due but did not fit."""

    chosen: tuple[ChannelState, ...]
    left_out: tuple[ChannelState, ...]


def _order(state: ChannelState) -> tuple[int, float, int]:
    """Higher priority first; among equals, the channel that has waited longest since it was
    last sent (never sent counts as oldest), so a full frame rotates fairly."""
    last = state.last_sent if state.last_sent is not None else float("-inf")
    return (-state.channel.priority, last, state.channel.index)


def plan_frame(codec: FrameCodec, due: Sequence[ChannelState], frame_bytes: int) -> FramePlan:
    """Greedy packing: each channel in order goes in when its bits still fit."""
    budget = codec.body_capacity_bits(frame_bytes) - codec.count_bits
    chosen: list[ChannelState] = []
    left_out: list[ChannelState] = []
    for state in sorted(due, key=_order):
        cost = codec.channel_cost_bits(state.channel)
        if cost <= budget:
            chosen.append(state)
            budget -= cost
        else:
            left_out.append(state)
    return FramePlan(tuple(chosen), tuple(left_out))
