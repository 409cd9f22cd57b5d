"""Latest-value store of the channels a node sends (seed 000: newest data overwrites older).

Pure: every method takes ``now`` (seconds). Values are packed when they arrive, so a payload
that cannot be encoded is refused at its key, not discovered later inside a frame.

A channel is *due* when every element has a value, the channel's ``interval_s`` has passed
since it was last sent, and either new data arrived since then or the channel is latching.
"""

from __future__ import annotations

import heapq
from collections.abc import Iterable
from dataclasses import dataclass, field

from bridge.wire.channels import ChannelCodec


@dataclass
class ChannelState:
    """What a sender holds for one channel."""

    channel: ChannelCodec
    packed: list[int | None]
    updated: list[float | None]  # when each element's value arrived here
    taken: list[float | None] = field(default_factory=list)  # when each was taken (its age)
    fresh: bool = False
    last_sent: float | None = None
    sends: int = 0

    @property
    def complete(self) -> bool:
        return None not in self.packed

    def payload(self) -> int:
        """The channel's bits: every element's packed value, first element most significant."""
        n = 0
        for element, packed in zip(self.channel.elements, self.packed, strict=True):
            n = (n << element.layout.bits) | (packed or 0)
        return n

    def ready_at(self, now: float | None = None) -> float | None:
        """When the channel becomes due, or None while nothing could be sent (incomplete, sent
        already, or older than the channel's ``ttl_s`` at ``now``)."""
        if not self.complete or not (self.fresh or self.channel.latching):
            return None
        ttl = self.channel.ttl_s
        if ttl is not None and now is not None and (self.age(now) or 0.0) > ttl:
            return None
        if self.last_sent is None:
            return float("-inf")
        return self.last_sent + self.channel.interval_s

    def age(self, now: float) -> float | None:
        """Seconds since the newest value of any element arrived."""
        stamps = [t for t in self.updated if t is not None]
        return now - max(stamps) if stamps else None


@dataclass
class OutboundStore:
    """Channel states of one sending node.

    :meth:`next_due` is asked at every planning step, so the due times of channels without a
    ``ttl_s`` (which do not depend on ``now``) wait in a heap, refreshed when a channel
    changes (stale entries are skipped); channels with a ``ttl_s`` are looked at each time.
    Change states through the methods below only.
    """

    states: dict[int, ChannelState] = field(default_factory=dict)
    _heap: list[tuple[float, int]] = field(default_factory=list, init=False, repr=False)
    _filed: dict[int, float | None] = field(default_factory=dict, init=False, repr=False)
    _ttl: list[ChannelState] = field(default_factory=list, init=False, repr=False)

    def __post_init__(self) -> None:
        self._ttl = [s for s in self.states.values() if s.channel.ttl_s is not None]
        for state in self.states.values():
            if state.channel.ttl_s is None:
                self._changed(state)

    def _changed(self, state: ChannelState) -> None:
        """Re-file ``state``'s due time (channels with a ``ttl_s`` are not filed); a heap entry
        counts while it holds its channel's filed time."""
        if state.channel.ttl_s is not None:
            return
        index, ready = state.channel.index, state.ready_at()
        if index in self._filed and self._filed[index] == ready:
            return  # unchanged: its entry stands
        self._filed[index] = ready
        if ready is not None:
            heapq.heappush(self._heap, (ready, index))
            if len(self._heap) > 4 * len(self.states) + 16:  # stale entries: compact
                self._heap = sorted({e for e in self._heap if self._filed[e[1]] == e[0]})

    @classmethod
    def for_node(cls, channels: Iterable[ChannelCodec], node: str) -> OutboundStore:
        return cls(
            {
                c.index: ChannelState(c, [None] * len(c.elements), [None] * len(c.elements),
                                      [None] * len(c.elements))
                for c in channels
                if c.sent_by(node) and c.destinations(node)
            }
        )

    def update_value(self, index: int, element: int, packed: int, now: float) -> bool:
        """Store an element of a reliable or fragmented channel (whose values are queued, not
        sent from here); returns whether the channel now holds a complete value."""
        state = self.states[index]
        state.packed[element] = packed
        state.updated[element] = now
        self._changed(state)
        return state.complete

    def update(self, index: int, element: int, packed: int, now: float,
               taken: float | None = None) -> None:
        """Store a newly packed element value, taken at ``taken`` (default: ``now``); it
        replaces whatever was there."""
        state = self.states[index]
        state.packed[element] = packed
        state.updated[element] = now
        state.taken[element] = now if taken is None else taken
        state.fresh = True
        self._changed(state)

    def restore(self, index: int, packed: list[int | None], updated: list[float | None],
                taken: list[float | None]) -> None:
        """Channel ``index``'s value as an earlier run of the node held it (a latching
        channel's, :mod:`bridge.core.latched`): due at once, its age and ``ttl_s`` counted
        from its own times."""
        state = self.states[index]
        state.packed[:], state.updated[:], state.taken[:] = packed, updated, taken
        state.fresh, state.last_sent = False, None
        self._changed(state)

    def due(self, now: float) -> list[ChannelState]:
        """Channels that may go in a frame sent at ``now``."""
        out = []
        for state in self.states.values():
            ready = state.ready_at(now)
            if ready is not None and ready <= now + 1e-9:
                out.append(state)
        return out

    def next_due(self, now: float | None = None) -> float | None:
        """The earliest time a channel becomes due (may be in the past), or None."""
        heap, filed = self._heap, self._filed
        while heap and filed[heap[0][1]] != heap[0][0]:
            heapq.heappop(heap)
        best = heap[0][0] if heap else None
        for state in self._ttl:
            t = state.ready_at(now)
            if t is not None and (best is None or t < best):
                best = t
        return best

    def resend(self, index: int) -> None:
        """Channel ``index`` is due again at once (its value went out on another link)."""
        state = self.states[index]
        state.last_sent = None
        self._changed(state)

    def mark_sent(self, sent: Iterable[ChannelState], built: float) -> None:
        """The frame built at ``built`` carried these channels. A value that arrived after
        the frame was built (while the modem was sending it) stays fresh, to go next time."""
        for state in sent:
            for t in state.updated:
                if t is not None and t > built:
                    break
            else:
                state.fresh = False
            state.last_sent = built
            state.sends += 1
            self._changed(state)
