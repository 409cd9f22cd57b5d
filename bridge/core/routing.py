"""Relays (pure): the network header of a node's own frames, and the frames it carries on for
others along the mission's static routes.

Every frame of a mission with several links or routes starts with a network header
(:mod:`bridge.wire.network`) naming the nodes it carries channel entries for. A frame for a
node that is not a neighbour is *routed*: its header also holds its origin, a number, its
hops, life, age and rank. A node that hears a routed frame

1. takes it once: the (origin, number) pairs it took lately are kept (:data:`SEEN_KEPT` per
   origin), so a copy heard again (directly and through a relay, or from two relays) is
   counted in ``frames_dropped["duplicate"]`` (no event: on a shared medium that is
   expected) and not taken again; its own frames carried on by a relay it ignores. A copy
   of a frame that carried reliable entries for this node, sent again by a neighbour it
   heard send it before, is answered as a repeated entry is: their acknowledgements are owed
   again (that neighbour keeps it until it hears them, :mod:`bridge.core.custody`; dropped
   unanswered, on umci_relay, where ROV2 takes the surface's frames directly, ROV1's copies
   were spent for nothing while a lost acknowledgement waited for a frame to the surface).
   A neighbour's first copy asks nothing: it carries on what it heard, not knowing;
2. forwards it for each node the frame serves whose route from the node it heard it from goes
   through this one (every node knows every node's routes: they are in the mission file;
   where that route lists several hops, only when the header's ``via`` names this one as
   the hop chosen: :meth:`~bridge.mission.network.Network.carries`) —
   the same bytes behind a rewritten header (``for`` narrowed to those nodes, one more hop,
   its life and age moved on by the time it waited here), queued on the link this node's
   policy chooses for their next hop. A frame that would take more than the mission's
   ``max_hops`` transmissions is not forwarded (``hop_limit``), nor one whose life ran out
   while it waited (``expired``).

A relay spends its own transmit opportunities on what it carries: at each one it fills the
transmission with the frames it carries, highest rank first (then the oldest), and its own
frame in the room left, as a bundle (:mod:`bridge.wire.network`); its own frame goes first
when it is more urgent than any of them (its most urgent due channel's rank), and every other
time when it is as urgent as the most urgent, so that neither starves the other. What it
carries is never changed, so a value keeps its priority (the rank), age (the header's age)
and TTL (its life) across hops,
and its authentication stays the origin's: receivers check it as a frame of the origin, with
the origin's replay window. Acknowledgements, query replies and interest bitmaps travel back
the same way, so ``delivered`` means the destination has the value. Routes are static: what
a relay learns costs no airtime, and it learns nothing (see docs/concepts.md).
"""

from __future__ import annotations

import math
import random
from collections import deque
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from bridge.core.bounds import hop_s
from bridge.core.builder import FramePlan
from bridge.core.custody import Custody
from bridge.core.events import FrameDropped
from bridge.core.links_policy import LinkPolicy
from bridge.core.linkset import LinkSet, LinkSide
from bridge.core.mac import frame_time_s
from bridge.core.outputs import Outbox
from bridge.frozen import direct_init
from bridge.mission.network import Network
from bridge.wire.channels import ChannelTable
from bridge.wire.frame import CHECK_BYTES, check_value
from bridge.wire.network import BUNDLE_MAX, NO_LIMIT, SEGMENT_MAX, SEQ_MOD, NetCodec, NetHeader

__all__ = ["SEEN_KEPT", "Arrival", "Carried", "Routing"]

SEEN_KEPT = 64
"""Routed-frame numbers kept per origin to tell a copy from a new frame (a quarter of the
number space: a number comes back only after 256 frames of that origin)."""

SEQ_RESERVE = 32
"""Routed-frame numbers reserved per state save: a restarted node resumes past every number
it may have used, within a quarter of the number space (so none of its new frames is taken
for a copy), at most one save per 32 routed frames."""

CARRIED_KEPT = 64
"""Frames a relay holds for each of its links at most; the oldest of the lowest rank is
dropped first (``frames_dropped["relay_full"]``)."""


@direct_init
@dataclass(frozen=True)
class Arrival:
    """A frame heard, as its network header tells it: built by ``origin`` (the sender itself
    unless relayed), its header and how many bytes that takes."""

    origin: str
    header: NetHeader
    start: int


@dataclass
class Carried:
    """A frame this node carries on for others, waiting on one of its links."""

    header: NetHeader
    frame: bytes  # the frame as its origin built it: after the header, before the check
    arrived: float
    dest: int | None  # the modem address it goes to (None: several, broadcast)

    def expires(self) -> float:
        return math.inf if self.header.life == NO_LIMIT else self.arrived + self.header.life


class Routing:
    """The network header of one node's frames, and the frames it carries for others."""

    def __init__(self, table: ChannelTable, network: Network, linkset: LinkSet,
                 policy: LinkPolicy, outbox: Outbox, rng: random.Random,
                 state: Mapping[str, Any]) -> None:
        assert table.net is not None
        self.codec: NetCodec = table.net
        self.table = table
        self.network = network
        self.node = linkset.node
        self.nodes = table.nodes
        self.index = table.nodes.index(self.node)
        self.linkset = linkset
        self.policy = policy
        self.outbox = outbox
        self.stats = outbox.stats
        self.max_hops = network.mission.max_hops
        self.listed = network.listed
        """Routes list several hops: routed frames name the hop chosen (``via``)."""
        self._seq = int(state.get("net_seq", rng.randrange(SEQ_MOD)))
        self._reserved = self._seq  # numbers from here on are not saved as used yet
        self._seen: dict[str, deque[int]] = {}
        self._streams: dict[tuple[str, int], tuple[frozenset[int], set[str]]] = {}
        """Of the frames taken lately (origin, number), those with reliable entries for
        this node: their streams (channel indices), and the neighbours heard sending it."""
        self.waiting: dict[str, list[Carried]] = {name: [] for name in linkset.sides}
        self.relayed = self.forwarded = 0
        """Frames of others this node sent on (and copies of them it queued)."""
        self.custody = custody_of(network, self.node)
        """The carried frames with reliable entries, kept until their next hop has them."""

    # -- own frames ----------------------------------------------------------------------------

    def header(self, serves: Iterable[str], priority: int | None, ttl_s: float | None,
               ) -> bytes:
        """The network header of an own frame carrying entries for ``serves`` (its highest
        channel ``priority``, its shortest ``ttl_s``): routed when one of them is reached
        through a relay."""
        serves = set(serves)
        indices = frozenset(self.nodes.index(n) for n in serves)
        hops = self.policy.hops
        if all(hops.get(n, n) == n for n in serves):
            return self.codec.encode(NetHeader(indices))
        seq, self._seq = self._seq, (self._seq + 1) % SEQ_MOD
        if seq == self._reserved:  # saved before the frame leaves, as a block
            self._reserved = (seq + SEQ_RESERVE) % SEQ_MOD
            self.outbox.unsaved = True
        life = NO_LIMIT if ttl_s is None else min(NO_LIMIT - 1, int(ttl_s))
        return self.codec.encode(NetHeader(indices, self.index, 0, seq, life, 0,
                                           self.rank(priority), self.via()))

    def via(self, hop: str | None = None) -> int:
        """The network header's ``via``: ``hop`` (default: the hop this node chose among those
        its routes list), 0 when routes list no several hops."""
        if not self.listed:
            return 0
        hop = hop or self.policy.choice.chosen
        return 0 if hop is None else self.nodes.index(hop)

    def rank(self, priority: int | None) -> int:
        """``priority``'s place among the mission's channel priorities (0: none)."""
        if priority is None:
            return 0
        return self.table.priorities.index(priority) if priority in self.table.priorities \
            else 0

    def state(self) -> dict[str, Any]:
        """Where a restarted node resumes its routed-frame numbers: past every one reserved."""
        return {"net_seq": self._reserved}

    # -- frames heard --------------------------------------------------------------------------

    def arrived(self, data: bytes, src: str, now: float,
                again: Callable[[str, frozenset[int]], None] | None = None
                ) -> Arrival | None:
        """The network header of a frame heard from neighbour ``src`` (its check passed);
        None when it is a copy of a frame taken already or malformed (counted). A copy of a
        frame that carried reliable entries for this node, from a neighbour heard sending it
        before, calls ``again`` with its origin and their streams (their acknowledgements
        are owed again)."""
        try:
            header, start = self.codec.decode(data)
        except ValueError as exc:  # (FrameError)
            self._dropped(src, "malformed", str(exc), now)
            return None
        origin = src if header.origin is None else self.nodes[header.origin]
        self.custody.heard(src, now)
        mine = origin == self.node  # its own frame, carried on by a relay it hears
        if mine or (header.origin is not None and header.seq in self._seen.get(origin, ())):
            if not mine:
                self.stats.frames_dropped["duplicate"] += 1  # (a broadcast medium: expected)
                found = self._streams.get((origin, header.seq))
                if found is not None and again is not None:
                    streams, senders = found
                    if src in senders:  # sent again: src did not hear the answer
                        again(origin, streams)
                    senders.add(src)
            if header.hops:  # a neighbour carried on a frame this node sent: it has it
                self.custody.forwarded(src, origin, header.seq)
            return None
        return Arrival(origin, header, start)

    def taken(self, arrival: Arrival, data: bytes, src: str, now: float,
              reliable: frozenset[tuple[int, int]] = frozenset()) -> None:
        """The frame of ``arrival`` (heard from ``src``) was valid: remember its number, and
        queue it on for the nodes that route through this one; ``reliable``: its reliable
        entries (channel index, seq), for which it is kept until its next hop has it
        (:mod:`bridge.core.custody`)."""
        header = arrival.header
        if header.origin is None:
            return
        seen = self._seen.setdefault(arrival.origin, deque(maxlen=SEEN_KEPT))
        if len(seen) == SEEN_KEPT:
            self._streams.pop((arrival.origin, seen[0]), None)
        seen.append(header.seq)
        channels = self.table.channels
        streams = frozenset(i for i, _ in reliable
                            if channels[i].reaches(arrival.origin, self.node))
        if streams and self.index in header.serves:
            self._streams[(arrival.origin, header.seq)] = (streams, {src})
        via = self.nodes[header.via] if self.listed else None
        mine = [self.nodes[i] for i in sorted(header.serves)
                if self.nodes[i] != self.node
                and self.network.carries(self.node, src, self.nodes[i], via)]
        if not mine:
            return
        if header.hops + 2 > self.max_hops:  # (it came over hops + 1 transmissions)
            self._dropped(src, "hop_limit", f"frame of {arrival.origin} after "
                          f"{header.hops + 1} hops (max_hops {self.max_hops})", now)
            return
        frame = data[arrival.start:-CHECK_BYTES]
        by_link: dict[tuple[str, str | None], list[str]] = {}
        for dest in mine:
            link = self.policy.link_for(dest)
            if link is None:
                self._dropped(src, "no_route", f"{self.node} has no link to {dest}", now)
                continue  # (with listed routes: one frame per hop, which it names)
            by_link.setdefault((link, self.policy.hops[dest] if self.listed else None),
                               []).append(dest)
        for (link, hop), dests in by_link.items():
            side = self.linkset.sides[link]
            hops = {self.policy.hops[d] for d in dests}
            out = NetHeader(frozenset(self.nodes.index(d) for d in dests), header.origin,
                            header.hops + 1, header.seq, header.life, header.age, header.rank,
                            self.via(hop) if hop is not None else 0)
            carried = Carried(out, frame, now, side.address_of(next(iter(hops)))
                              if len(hops) == 1 else None)
            self._queue(side, carried)
            if reliable and len(hops) == 1 and overhears(
                    self.network, self.node, arrival.origin, next(iter(hops)), dests):
                self.custody.keep(carried, link, next(iter(hops)), arrival.origin, header.seq,
                                  self._owed(arrival.origin, dests, reliable))

    def keep_own(self, side: LinkSide, data: bytes, reliable: frozenset[tuple[int, int]],
                 now: float) -> None:
        """An own frame (``data``, its network header and check included) carrying the
        reliable entries ``reliable`` left on ``side`` at ``now``: when it is routed, through
        one first hop, it is kept until that hop carries it on, as a relay keeps what it
        carries (:mod:`bridge.core.custody`)."""
        header, start = self.codec.decode(data)
        if not reliable or header.origin is None:
            return
        dests = [self.nodes[i] for i in header.serves]
        hops = {self.policy.hops.get(d) for d in dests}
        hop = next(iter(hops))
        if len(hops) != 1 or hop is None or hop in dests \
                or not overhears(self.network, self.node, self.node, hop, dests):
            return  # (a frame for a neighbour: the stream's own retries are one hop)
        carried = Carried(header, data[start:-CHECK_BYTES], now, side.address_of(hop))
        self.custody.keep(carried, side.name, hop, self.node, header.seq,
                          self._owed(self.node, dests, reliable))
        self.custody.sent(carried, now)

    def _owed(self, origin: str, dests: Iterable[str], reliable: Iterable[tuple[int, int]]
              ) -> dict[str, set[tuple[int, int]]]:
        """Per destination, the reliable entries of ``origin`` it is to acknowledge."""
        channels = self.table.channels
        return {d: {e for e in reliable if channels[e[0]].reaches(origin, d)} for d in dests}

    def _queue(self, side: LinkSide, carried: Carried) -> None:
        queue = self.waiting[side.name]
        queue.append(carried)
        self.forwarded += 1
        if len(queue) > CARRIED_KEPT:
            worst = min(queue, key=lambda c: (c.header.rank, -c.arrived))
            queue.remove(worst)
            self.custody.forget(worst)
            self.stats.frames_dropped["relay_full"] += 1

    def _dropped(self, src: str | None, reason: str, error: str, now: float) -> None:
        self.stats.frames_dropped[reason] += 1
        self.outbox.event(FrameDropped(now, src, reason, error))

    # -- frames carried out --------------------------------------------------------------------

    def expire(self, now: float) -> None:
        """Frames whose life ran out while they waited here are dropped (counted)."""
        for name, queue in self.waiting.items():
            for carried in [c for c in queue if c.expires() < now]:
                queue.remove(carried)
                self.custody.forget(carried)
                origin = self.nodes[carried.header.origin or 0]
                self._dropped(origin, "expired", f"frame {carried.header.seq} of {origin} "
                              f"waited past its life on link {name}", now)

    def next_due(self, side: LinkSide) -> float | None:
        """When this node has a frame to carry on ``side``: now, when a kept frame is due
        again, or None."""
        return -math.inf if self.waiting[side.name] else self.custody.next_time(side.name)

    def resend(self, side: LinkSide, now: float) -> None:
        """Kept frames due again on ``side`` go back in its queue."""
        self.waiting[side.name].extend(self.custody.due(side.name, now))

    def best_rank(self, side: LinkSide) -> int | None:
        """The highest rank of the frames waiting on ``side`` (None: none)."""
        return max((c.header.rank for c in self.waiting[side.name]), default=None)

    def pick(self, side: LinkSide, room: int, now: float, bundled: bool = False
             ) -> list[tuple[Carried, bytes]]:
        """The frames carried on ``side`` that fit in ``room`` bytes, highest rank first,
        then the oldest, each with its bytes as it leaves now: one alone, or several (and
        room for them) as a bundle; ``bundled``: they join a bundle whose count ``room``
        left out already, each with its length byte (beside the node's own frame)."""
        self.expire(now)
        picked: list[tuple[Carried, bytes]] = []
        used = 0 if bundled else 1  # a bundle's count
        for carried in sorted(self.waiting[side.name], key=lambda c: (-c.header.rank,
                                                                      c.arrived)):
            data = self.frame(carried, now)
            if not picked and not bundled:
                if len(data) <= room:
                    picked.append((carried, data))
                    used += 1 + len(data)
            elif (len(picked) < BUNDLE_MAX - bundled and used + 1 + len(data) <= room
                  and max([len(data), *(len(d) for _, d in picked[:1])]) <= SEGMENT_MAX):
                picked.append((carried, data))
                used += 1 + len(data)
        return picked

    def frame(self, carried: Carried, now: float) -> bytes:
        """The bytes of ``carried`` as they leave now: its header aged by its wait here."""
        waited = max(0.0, now - carried.arrived)
        header = carried.header
        life = header.life if header.life == NO_LIMIT else max(0, header.life - int(waited))
        age = min(NO_LIMIT, header.age + round(waited))
        head = self.codec.encode(NetHeader(header.serves, header.origin, header.hops,
                                           header.seq, life, age, header.rank, header.via))
        data = head + carried.frame
        return data + check_value(data, self.table.fingerprint)

    def sent(self, side: LinkSide, carried: Iterable[Carried], now: float) -> None:
        """The frames ``carried`` went out on ``side`` at ``now``."""
        queue = self.waiting[side.name]
        for item in carried:
            if item in queue:
                queue.remove(item)
            self.custody.sent(item, now)
            self.relayed += 1

    @staticmethod
    def plan() -> FramePlan:
        return FramePlan((), ())

    def snapshot(self) -> dict[str, Any]:
        return {"relayed": self.relayed, "queued": self.forwarded,
                "waiting": {name: len(q) for name, q in self.waiting.items()},
                "custody": self.custody.snapshot(),
                "routes": self.policy.snapshot()}


def custody_of(network: Network, node: str) -> Custody[Carried]:
    """``node``'s custody of the frames it carries, timed per neighbour: a frame of it heard
    answers a copy once that copy's frame time and its own have passed; unheard, the copy
    waits its worst-case round trip (:func:`~bridge.core.bounds.hop_s` there and back)."""
    answer: dict[str, float] = {}
    trip: dict[str, float] = {}
    for link in network.links_of(node):
        for peer in link.members:
            if peer == node:
                continue
            answer[peer] = max(answer.get(peer, 0.0), (frame_time_s(link.view, node) or 0.0)
                               + (frame_time_s(link.view, peer) or 0.0))
            trip[peer] = hop_s(network, node, peer) + hop_s(network, peer, node)
    return Custody[Carried](answer, trip)


def overhears(network: Network, node: str, origin: str, hop: str, dests: Iterable[str]
              ) -> bool:
    """Whether ``node`` hears what shows that ``hop`` has a frame of ``origin`` for ``dests``:
    for each, ``hop`` carrying it on (``node`` is on every link ``hop`` shares with each next
    hop its routes list: whichever it uses), or, ``hop`` being the destination, its
    acknowledgement coming back (its route to ``origin`` goes through ``node``). Where it
    would not (umci_relay: the surface does not hear ROV1's RF), custody would only send
    copies blind: the frame is left to the stream's end-to-end retries."""
    for dest in dests:
        if hop == dest:
            if node not in network.next_hops(dest, origin):
                return False
            continue
        nexts = network.next_hops(hop, dest)
        if not nexts or not all(node in link.members for n in nexts
                                for link in network.shared(hop, n)):
            return False
    return True
