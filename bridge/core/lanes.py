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

A lane's frame may go shorter still, its *express* (:meth:`~bridge.core.node.NodeCore.express`):
after a lane's frame of a one-element channel, the core writes a :class:`Clearance` saying until
when a sample on that lane would again make its channel the one thing due with the MAC open:
when the channel's interval and the MAC's gap have passed, and before any other channel comes
due. While nothing else changes the store (its ``changes`` count) and no acknowledgement is
owed, a sample inside that window is packed and its frame built from the clearance alone; the
store, the MAC, the last send and the counters are kept with the books, as a lane's frame
would have left them. A frame the codec builds whole (DLBL delays, authentication) has none.

Frames heard have a short way too: :meth:`~bridge.core.node.NodeCore.hear` outputs a plain
frame's values at once and leaves the rest of its reception (counters, link and MAC records,
ranging, status, the event) to :meth:`~bridge.core.node.NodeCore.settle`, which the runtime
runs off the data path and every other method of the core runs first. It needs a node whose
MAC ignores what it hears and that decodes nothing beyond values for Zenoh (no queries,
surfacing or anchor positions): :func:`hears_plainly`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from bridge.core.mac import EPS, Schedule
from bridge.core.store import ChannelState
from bridge.wire.channels import ElementCodec

if TYPE_CHECKING:
    from bridge.core.node import NodeCore

__all__ = ["Clearance", "Lane", "clearance_after", "hears_plainly", "lanes_for"]


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
    frame: Callable[[int], bytes] | None
    """The channel's frame alone, from its payload (:meth:`FrameCodec.lone`; None: the codec
    builds it)."""


@dataclass(slots=True)
class Clearance:
    """When a sample on ``state``'s lane goes out alone at once (see the module docstring)."""

    state: ChannelState
    due_from: float
    """The channel's interval has passed (its last frame's build time + ``interval_s``)."""
    open_from: float
    """The MAC's gap has passed (its last frame's start + ``gap``)."""
    gap: float
    """:meth:`Schedule.reopens_s`."""
    until: float
    """When another channel may come due (its ``ready_at``, without ``ttl_s``)."""
    stamp: int
    """The store's ``changes`` the clearance was worked out from."""

    def moved_on(self, start: float) -> None:
        """A frame of the channel started at ``start`` (as built then)."""
        self.due_from = start + self.state.channel.interval_s
        self.open_from = start + self.gap

    def admits(self, state: ChannelState, now: float, changes: int) -> bool:
        """Whether a sample on ``state``'s lane at ``now`` makes it the one channel due with
        the MAC open, as :meth:`OutboundStore.lone_due` and :meth:`Schedule.open_now` would
        say (their tolerances)."""
        return state is self.state and changes == self.stamp and self.due_from <= now + 1e-9 \
            and self.open_from <= now + EPS and now + 1e-9 < self.until


def clearance_after(core: NodeCore, chosen: tuple[ChannelState, ...], built: float,
                    start: float) -> Clearance | None:
    """The clearance of a lane's frame of ``chosen`` built at ``built`` and started at
    ``start``, once the store and the MAC have recorded it; None where no express may
    follow (a MAC that must be asked, a channel of several elements, a codec that builds
    the whole frame)."""
    gap = core.schedule.reopens_s()
    if gap is None or len(chosen) != 1 or chosen[0].channel.index not in core.expressible:
        return None
    state = chosen[0]
    until = math.inf
    for other in core.store.states.values():
        if other is not state:
            ready = other.ready_at()
            if ready is not None and ready < until:
                until = ready
    return Clearance(state, built + state.channel.interval_s, start + gap, gap, until,
                     core.store.changes)


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
        lanes[key] = Lane(core.store.states[channel.index], index, element, dest, ack,
                          codec.lone(channel, core.epoch))
    return lanes


def hears_plainly(core: NodeCore) -> bool:
    """Whether :meth:`~bridge.core.node.NodeCore.hear` may keep a frame's books for later."""
    return type(core.schedule).on_heard is Schedule.on_heard and core.queries is None \
        and core.surfacing is None and not core.anchor_keys
