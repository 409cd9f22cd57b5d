"""Link health: is each peer up, degraded or down, from when it was last heard (pure).

A node that has nothing to send still sends a *heartbeat* (an empty frame) at least every
``heartbeat_s``, so its peers can tell silence from absence (not in Goby's format, which has
no empty frame: :mod:`bridge.wire.goby`). By default the MAC says how often
(:meth:`~bridge.core.mac.Mac.heartbeat_s`): one TDMA cycle (every slot carries a frame), ten
seconds with random access, none when polled (every poll and every reply is a frame). A peer
is *degraded* after :data:`DEGRADED_PERIODS` and *down* after :data:`DOWN_PERIODS` of its
periods without a frame,
its period being the longer of its heartbeat and the MAC's cycle: at 40 % frame loss a peer
that keeps sending looks down once in about 2 500 periods (0.4 ** 8 per period), where the
former 4 cycles without a heartbeat went down while a sender waited out its retransmissions.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from enum import StrEnum

from bridge.core.events import Link, PeerLink
from bridge.core.mac import mac_for
from bridge.core.mac.base import FREE_HEARTBEAT_S
from bridge.core.outputs import Outbox
from bridge.mission.model import Mission
from bridge.mission.network import Network
from bridge.wire.goby import frame_codec_class

DEGRADED_PERIODS = 3
DOWN_PERIODS = 8


class LinkState(StrEnum):
    UP = "up"
    DEGRADED = "degraded"
    DOWN = "down"


def heartbeat_s(mission: Mission) -> float | None:
    """How often a node sends at least a frame: the mission's ``link.heartbeat_s``, or its
    default from the MAC (None: the MAC makes every node send anyway, or the wire format has
    no empty frame: a Goby node with nothing to send sends nothing)."""
    if not frame_codec_class(mission.wire.format).empty_frames:
        return None
    if mission.link.heartbeat_s is not None:
        return mission.link.heartbeat_s
    return mac_for(mission).heartbeat_s()


@dataclass(frozen=True)
class LinkThresholds:
    """Silence after which a link is degraded, then down."""

    degraded_after_s: float
    down_after_s: float

    @classmethod
    def for_mission(cls, mission: Mission) -> LinkThresholds:
        cycle = mac_for(mission).cycle_s() or 0.0
        period = max(heartbeat_s(mission) or 0.0, cycle) or FREE_HEARTBEAT_S
        link = mission.link
        degraded = link.degraded_after_s or DEGRADED_PERIODS * period
        down = link.down_after_s or max(DOWN_PERIODS * period, degraded)
        return cls(degraded, max(down, degraded))

    @classmethod
    def for_node(cls, network: Network, node: str) -> LinkThresholds:
        """A peer of ``node`` heard over any of its links: the slowest link's thresholds."""
        found = [cls.for_mission(link.view) for link in network.links_of(node)]
        return cls(max(t.degraded_after_s for t in found), max(t.down_after_s for t in found))

    def state(self, last_heard: float | None, now: float) -> LinkState:
        if last_heard is None or now - last_heard >= self.down_after_s:
            return LinkState.DOWN
        if now - last_heard >= self.degraded_after_s:
            return LinkState.DEGRADED
        return LinkState.UP


class LinkWatch:
    """Which peers' link states may have changed since the last look, so that a node
    re-evaluates only those, not every peer at every tick.

    A state changes only when the peer is heard (:meth:`heard`) or when its silence crosses a
    threshold: after each look at a peer, its next crossing goes in a heap (an entry counts
    while it is the peer's latest). A node hears its peers far more often than their states
    change, so a hearing is no reason to look at a peer that was up at its last look (and is
    heard no earlier than the hearing that look saw): it stays up, its filed crossing comes
    early, and the look then files the next one from the latest hearing.

    :meth:`due` returns the peers to re-evaluate, in the order given at construction; with no
    time going backwards this covers every peer whose state can differ from the one last
    reported (and, at such an early crossing, a peer still up).
    """

    SLACK_S = 1e-6
    """Crossings are looked at this early, so float rounding of ``heard + threshold`` never
    delays one (an early look finds no change and waits for the crossing again)."""

    def __init__(self, thresholds: LinkThresholds, peers: Iterable[str]) -> None:
        self.thresholds = thresholds
        self.order = {peer: i for i, peer in enumerate(peers)}
        self._dirty: set[str] = set(self.order)  # the first look covers every peer
        self._heap: list[tuple[float, int, str]] = []  # (crossing, order, peer)
        self._crossing: dict[str, float] = {}  # each watched peer's latest crossing
        self._up: dict[str, float] = {}  # peers up at their last look: the hearing it saw
        self._last = -math.inf

    def heard(self, peer: str, at: float | None = None) -> None:
        """``peer`` was heard (at time ``at``, if given): its state may change at the next
        look, unless it was up then and ``at`` is no earlier than the hearing seen."""
        if peer in self.order:
            seen = self._up.get(peer)
            if at is None or seen is None or at < seen:
                self._dirty.add(peer)

    def due(self, now: float, last_heard: Mapping[str, float]) -> list[str]:
        """The peers whose state may differ at ``now`` from the last look at them; each is
        watched again from ``last_heard`` (the caller re-evaluates all of them)."""
        heap = self._heap
        if not self._dirty and now >= self._last and (not heap or heap[0][0] > now + self.SLACK_S):
            self._last = now
            return []  # the common tick: nothing heard, no threshold crossed
        peers, self._dirty = self._dirty, set()
        if now < self._last:  # time went backwards: a state may go back too, look at everyone
            peers = set(self.order)
        self._last = now
        crossing = self._crossing
        while heap and heap[0][0] <= now + self.SLACK_S:
            at, _, peer = heapq.heappop(heap)
            if crossing.get(peer) == at:
                peers.add(peer)
        out = sorted(peers, key=self.order.__getitem__) if len(peers) > 1 else list(peers)
        t = self.thresholds
        for peer in out:
            heard = last_heard.get(peer)
            crossing.pop(peer, None)
            self._up.pop(peer, None)
            if heard is None:
                continue  # down until heard
            silent = now - heard
            if silent < t.degraded_after_s:
                self._up[peer] = heard
                at = heard + t.degraded_after_s
            elif silent < t.down_after_s:
                at = heard + t.down_after_s
            else:
                continue  # down: the next hearing is the next change
            crossing[peer] = at
            heapq.heappush(heap, (at, self.order[peer], peer))
        return out


class Links:
    """Each peer's link state, from when it was last heard; every change reported as the
    ``link/<peer>`` status and a :class:`~bridge.core.events.Link` event."""

    def __init__(self, thresholds: LinkThresholds, peers: Iterable[str], outbox: Outbox,
                 on_up: Callable[[], None] | None = None, link: str | None = None) -> None:
        """``on_up``: called when a peer comes up from silence (down or never heard);
        ``link``: the peers' states on this one of several links (reported on
        ``links/<link>/<peer>`` as :class:`~bridge.core.events.PeerLink`)."""
        self.thresholds = thresholds
        self.outbox = outbox
        self.on_up = on_up
        self.link = link
        self.states: dict[str, LinkState] = {}
        self.last_heard: dict[str, float] = {}
        self._watch = LinkWatch(thresholds, peers)

    def heard(self, peer: str, now: float) -> None:
        """A valid frame from ``peer`` at ``now``; its state changes at :meth:`update`."""
        self.last_heard[peer] = now
        self._watch.heard(peer, now)

    def update(self, now: float) -> None:
        """Re-evaluate the peers whose state may have changed, reporting changes."""
        for peer in self._watch.due(now, self.last_heard):
            heard = self.last_heard.get(peer)
            state = self.thresholds.state(heard, now)
            previous = self.states.get(peer)
            if previous is state:
                continue
            self.states[peer] = state
            if self.on_up is not None and state is LinkState.UP \
                    and previous in (None, LinkState.DOWN):
                self.on_up()
            silent = None if heard is None else now - heard
            said = state.value
            if self.link is not None:
                self.outbox.status(f"links/{self.link}/{peer}", {
                    "peer": peer, "state": said, "last_heard": heard,
                    "silent_s": silent, "link": self.link})
                self.outbox.event(PeerLink(now, peer, self.link, said, heard, silent))
                continue
            self.outbox.status(f"link/{peer}", {"peer": peer, "state": said,
                                                "last_heard": heard, "silent_s": silent})
            self.outbox.event(Link(now, peer, said, heard, silent))
