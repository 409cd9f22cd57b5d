"""Lanes: the short way from a sample to its frame, when its channel alone is due.

On the direct data path a sample's frame leaves from the Zenoh callback, and every step run
there delays it: on a VM whose cores idle between samples, each step costs many times what it
costs back to back (issue #14). Most of the time a sample makes its own channel the only thing
due, and the frame :meth:`~bridge.core.node.NodeCore.build_frame` builds then holds that
channel alone. A lane is what the core works out once per input key so that this case skips
the general machinery (candidates, priorities, the fill); every other case takes it.

A key has a lane on a *plain* node (nothing but latest-value channels to send: no reliable or
fragmented streams, key families, demand, queries, surfacing or positioning) when it feeds
exactly one channel that fits a frame by itself. The frames are the same either way
(``tests/core/test_lanes.py`` builds both, sample by sample).

Frames heard have a short way too: :meth:`~bridge.core.node.NodeCore.hear` outputs a plain
frame's values at once and leaves the rest of its reception (counters, link and MAC records,
ranging, status, the event) to :meth:`~bridge.core.node.NodeCore.settle`, which the runtime
runs off the data path and every other method of the core runs first. It needs a node whose
MAC ignores what it hears and that decodes nothing beyond values for Zenoh (no queries,
surfacing or anchor positions): :func:`hears_plainly`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from bridge.core.mac import Schedule
from bridge.core.store import ChannelState
from bridge.wire.channels import ElementCodec

if TYPE_CHECKING:
    from bridge.core.node import NodeCore

__all__ = ["Lane", "hears_plainly", "lanes_for"]


@dataclass(frozen=True, slots=True)
class Lane:
    """One input key's channel, the element it feeds and where the channel's frames go."""

    state: ChannelState
    index: int
    """Which of the channel's elements the key feeds."""
    element: ElementCodec
    dest: int | None
    """The unicast address of the channel's one destination (None: broadcast)."""
    ack: bool | None
    """The modem's acknowledgement (:meth:`NodeCore.addressing`)."""


def lanes_for(core: NodeCore) -> dict[str, Lane]:
    """The lanes of ``core``'s input keys (none unless the node is plain)."""
    others = (core.interest, core.queries, core.surfacing, core.positioning)
    if core.senders or core.families.senders or any(o is not None for o in others):
        return {}
    codec = core.codec
    budget = codec.body_capacity_bits(core.frame_bytes) - codec.count_bits
    lanes = {}
    for key, bound in core.bindings.items():
        if len(bound) != 1 or core.ros2_input(key) is not None:
            continue
        ((channel, index, element),) = bound
        if channel.stream or codec.channel_cost_bits(channel) > budget:
            continue
        dest, ack = core.addressing(set(channel.destinations(core.node)), channel.ack)
        lanes[key] = Lane(core.store.states[channel.index], index, element, dest, ack)
    return lanes


def hears_plainly(core: NodeCore) -> bool:
    """Whether :meth:`~bridge.core.node.NodeCore.hear` may keep a frame's books for later."""
    return type(core.schedule).on_heard is Schedule.on_heard and core.queries is None \
        and core.surfacing is None and not core.anchor_keys
