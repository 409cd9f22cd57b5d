"""What ``zab check`` adds for a mission with several links or routes: its links, each route
and its worst-case time, what each relay carries against what its turns can carry, and each
channel's worst-case end-to-end age.

Budget of a relay, per link it sends on, in bytes per second: what it really sends there
against what its turns carry, ``frame_bytes`` less a bundle's count byte at each of its turns
(their mean rate under its MAC: the backlog grows when more is offered over time; the worst
interval bounds latency, not throughput). What it sends is frames, never bare values:

- every frame of another node that it carries on, whole: the origin's frame header, epoch,
  count, authentication and check, the routed network header and the bundle's length byte,
  besides the entries. An origin's frame goes on through the relay as soon as one entry in
  it is for a node behind the relay, so it carries there every entry the origin put in it,
  those for its neighbours too (up to one a frame of each channel it sends on that link);
- the entries that make those frames: each channel's values to a node behind the relay (one
  per ``interval_s``, or one per turn of its sender at every opportunity; a stream's no
  more than its window per round trip), and the acknowledgements the origin owes a reliable
  or fragmented stream sent to it from behind the relay, a frame for each frame of the
  stream (the :data:`~bridge.core.receivers.ACK_REPEATS` repeats ride in frames sent there
  anyway); an origin sends at most one frame per turn on its link;
- its own frame (its own values, acknowledgements and their frame), in the room left.

Sizes are the frame builder's (:meth:`~bridge.wire.frame.FrameCodec.frame_bytes_for`,
:meth:`~bridge.wire.frame.FrameCodec.channel_cost_bits`, the network header's, and
:meth:`~bridge.wire.network.NetCodec.bundle_bytes`), each frame's entries rounded up to the
byte. Not counted: retransmissions after a loss (a lossy hop adds them), queries and their
replies (as often as applications ask), ``@want`` and ``@key`` entries. A relay over budget
delays and then drops what it carries (a warning).

A relay that a route lists as an alternative is budgeted as if it carried that route's
share all the time (it does while the hops listed before it are down).

Each route's worst case is over its primary path (every hop's first listed hop); a route
that lists several hops says its alternatives, each with its own worst case (taken while
the hops before them are down).

Age bound of a channel from a sender to a receiver: its ``interval_s``, then each hop's
longest wait for the sender's turn and its frame's time (:func:`~bridge.core.bounds.hop_s`),
hop after hop along the route (a relay within its budget sends what it carries at its next
turn). A bound above the channel's ``ttl_s`` is a warning: its values may expire on the way.
"""

from __future__ import annotations

import itertools
import math
from collections import defaultdict
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from bridge.core.bounds import hop_s
from bridge.core.loaded import LoadedMission
from bridge.core.mac import mac_report
from bridge.core.receivers import ACK_REPEATS
from bridge.mission.network import Network
from bridge.wire.channels import WINDOW, ChannelCodec
from bridge.wire.frame import FrameCodec
from bridge.wire.network import NetCodec

__all__ = ["network_section"]

Port = tuple[str, str]
"""A node on one of its links: (node, link name)."""


@dataclass(frozen=True)
class Flow:
    """Entries of one kind a node puts in its frames on one link: at most ``per_s`` a
    second, ``bits`` each (index included), for ``serves``, at most ``per_frame`` in one
    frame; they make a frame of their own at most ``frames_per_s`` a second (0: they only
    ride in frames sent anyway)."""

    what: str
    per_s: float
    bits: int
    serves: frozenset[str]
    frames_per_s: float
    per_frame: int = 1


def network_section(loaded: LoadedMission, codec: FrameCodec,
                    by_link: dict[str, list[dict[str, Any]]]) -> tuple[dict[str, Any],
                                                                      list[str]]:
    """The ``network`` section of ``zab check``'s report and its warnings; ``by_link``: each
    link's node entries (their ``mac`` worst intervals)."""
    mission, table, network = loaded.mission, loaded.table, loaded.network
    net = table.net
    assert net is not None
    warnings: list[str] = []
    links = [{"name": link.name, "kind": link.kind, "mac": link.view.mac.type,
              "members": list(link.members),
              "frame_bytes": {n: link.frame_bytes_of(n) for n in link.members}}
             for link in network.links]
    routes = []
    for a, b in itertools.permutations(mission.nodes, 2):
        path, problem = network.path(a, b)
        if problem is None and len(path) > 2:
            others = [{"path": other, "bound_s": _bound(network, other)}
                      for other, wrong in network.paths(a, b) if wrong is None and other != path]
            routes.append({"from": a, "to": b, "path": path, "bound_s": _bound(network, path),
                           "alternatives": others})
    ages = []
    for channel in table.channels:
        worst: dict[str, Any] | None = None
        for sender in channel.senders:
            for dest in channel.destinations(sender):
                path, problem = network.path(sender, dest)
                if problem is not None:
                    warnings.append(f"channel {channel.name!r}: {sender} to {dest}: {problem}")
                    continue
                bound = channel.interval_s + sum(hop_s(network, x, y)
                                                 for x, y in itertools.pairwise(path))
                if worst is None or bound > worst["age_bound_s"]:
                    worst = {"channel": channel.name, "from": sender, "to": dest,
                             "route": path, "age_bound_s": _round(bound)}
                if channel.ttl_s is not None and bound > channel.ttl_s:
                    warnings.append(f"channel {channel.name!r}: {' -> '.join(path)} may take "
                                    f"{bound:.1f} s, more than its ttl_s {channel.ttl_s:g}")
        if worst is not None:
            ages.append(worst)
    for spec in {c.spec.name: c.spec for c in table.query_codecs}.values():
        for asker, server in itertools.product(spec.askers, spec.servers):
            problems = [network.path(a, b)[1] for a, b in ((asker, server), (server, asker))
                        if asker != server]
            problem = next((p for p in problems if p is not None), None)
            if problem is not None:
                warnings.append(f"query {spec.name!r}: {asker} asking {server}: {problem}")
    relays = Budgets(loaded, codec).relays()
    for relay in relays:
        if not relay["fits"]:
            warnings.append(f"relay {relay['node']} on {relay['link']}: its own frames "
                            f"({relay['own_Bps']:g} B/s) and the frames it carries "
                            f"({relay['carried_Bps']:g} B/s, {relay['carried_fps']:g} frames/s) "
                            f"need more than its turns carry ({relay['capacity_Bps']:g} B/s): "
                            "what it carries waits, and past its life is dropped")
    return {"links": links, "routes": routes, "relays": relays, "age_bounds": ages,
            "max_hops": mission.max_hops, "header_bytes": {"plain": net.plain_bytes,
                                                           "routed": net.routed_bytes}}, warnings


class Budgets:
    """What each relay sends on each of its links, against what its turns carry (the
    module's doc), from the frame builder's sizes."""

    def __init__(self, loaded: LoadedMission, codec: FrameCodec) -> None:
        self.mission, self.table, self.network = loaded.mission, loaded.table, loaded.network
        self.codec = codec
        assert self.table.net is not None
        self.net = self.table.net
        self.turns: dict[Port, float] = {
            (node, link.name): mac_report(link.view, node, None).mean_turns_per_s()
            for link in self.network.links for node in link.members}
        """Each node's transmit opportunities a second on each of its links, on average."""
        self._flows: dict[Port, list[Flow]] = defaultdict(list)
        for channel in self.table.channels:
            for sender in channel.senders:
                self._channel_flows(channel, sender)
        for channel in self.table.streams:
            for sender in channel.senders:
                self._ack_flows(channel, sender)

    def relays(self) -> list[dict[str, Any]]:
        """Per relay and link it carries frames on: its own and carried bytes a second, the
        frames it carries, what its turns carry, and whether that fits."""
        carried: dict[Port, dict[str, set[str]]] = defaultdict(lambda: defaultdict(set))
        for origin, dest in itertools.permutations(self.mission.nodes, 2):
            path, problem = self.network.path(origin, dest)
            if problem is not None or len(path) <= 2:
                continue
            for way in _ways(self.network, origin, dest, path):
                for x, y in itertools.pairwise(way[1:]):
                    carried[(x, _link(self.network, None, dest, x, y))][origin].add(dest)
        out = []
        for (node, link), origins in sorted(carried.items()):
            frames = [self.frames_of(origin, frozenset(dests))
                      for origin, dests in sorted(origins.items())]
            sources = [{"origin": origin, "for": sorted(dests), "frames_per_s": _round(f),
                        "Bps": _round(b)}
                       for (origin, dests), (f, b) in zip(sorted(origins.items()), frames,
                                                          strict=True) if f > 0]
            fps, load = sum(f for f, _ in frames), sum(b for _, b in frames)
            own = self.own_bytes(node, link)
            turns = self.turns.get((node, link), 0.0)
            capacity = turns * (self.network.link(link).frame_bytes_of(node)
                                - NetCodec.bundle_bytes(()))
            out.append({"node": node, "link": link, "own_Bps": _round(own),
                        "carried_Bps": _round(load), "carried_fps": _round(fps),
                        "capacity_Bps": _round(capacity), "turns_per_s": _round(turns),
                        "margin_Bps": _round(capacity - own - load),
                        "fits": own + load <= capacity, "carried_from": sources})
        return out

    def frames_of(self, origin: str, serving: frozenset[str]) -> tuple[float, float]:
        """The frames a second ``origin`` sends with an entry for one of ``serving`` (nodes
        behind a relay), over every link of its, and their bytes as a relay carries them
        (the routed network header, the bundle's length byte)."""
        frames = total = 0.0
        for link in self.network.links_of(origin):
            fps, size = self._frames((origin, link.name),
                                     self._flows.get((origin, link.name), []), serving)
            frames += fps
            total += fps * self._segment(self.net.routed_bytes + size)
        return frames, total

    def own_bytes(self, node: str, link: str) -> float:
        """What ``node`` sends of its own on ``link`` a second, frames and all."""
        flows = self._flows.get((node, link), [])
        header = self.net.routed_bytes if self.network.routed_over(node, link) \
            else self.net.plain_bytes
        fps, size = self._frames((node, link), flows, None)
        return fps * self._segment(header + size)

    def _frames(self, port: Port, flows: list[Flow], serving: frozenset[str] | None
                ) -> tuple[float, int]:
        """How many frames a second ``port`` sends with an entry for ``serving`` (None:
        any), and the bytes of each (its entries' mean, rounded up, as the builder sizes a
        frame: :meth:`~bridge.wire.frame.FrameCodec.frame_bytes_for`). Entries for
        ``serving`` that only ride in frames sent anyway ride in those; every other entry
        rides in them at most once a frame."""
        mine = [f for f in flows if serving is None or f.serves & serving]
        fps = min(self.turns.get(port, 0.0), sum(f.frames_per_s for f in mine))
        if fps <= 0:
            return 0.0, 0
        bits = sum(min(f.per_s, fps * f.per_frame) * f.bits for f in flows)
        empty = self.codec.frame_bytes_for(())
        room = self.network.link(port[1]).frame_bytes_of(port[0])
        return fps, min(room, empty + math.ceil(bits / fps / 8))

    def _held(self, node: str, bits: int) -> int:
        """How many entries of ``bits`` each a frame of ``node`` holds on its smallest
        link."""
        return self._room_entries(min(link.frame_bytes_of(node)
                                      for link in self.network.links_of(node)), bits)

    def _room_entries(self, frame_bytes: int, bits: int) -> int:
        room = frame_bytes - self.net.routed_bytes
        return max(1, (self.codec.body_capacity_bits(room) - self.codec.count_bits) // bits)

    @staticmethod
    def _segment(size: int) -> int:
        """Bytes a frame of ``size`` takes in a bundle (with its length byte)."""
        return NetCodec.bundle_bytes((size,)) - NetCodec.bundle_bytes(())

    def _channel_flows(self, channel: ChannelCodec, sender: str) -> None:
        """``sender``'s entries of ``channel``, per link its first hop takes."""
        serves: dict[str, set[str]] = defaultdict(set)
        for dest in channel.destinations(sender):
            hop = self.network.next_hop(sender, dest)
            if hop is None:
                continue
            serves[_link(self.network, channel, dest, sender, hop)].add(dest)
        for link, dests in serves.items():
            per_s, frames = self._rates(channel, sender, dests)
            bits = self.codec.channel_cost_bits(channel)
            self._flows[(sender, link)].append(Flow(
                channel.name, per_s, bits, frozenset(dests), frames,
                self._held(sender, bits) if channel.repeatable else 1))

    def _ack_flows(self, channel: ChannelCodec, sender: str) -> None:
        """The acknowledgements each receiver of ``sender``'s stream ``channel`` owes it: one
        frame of the receiver after each of ``sender``'s frames with entries of it, and in
        the :data:`ACK_REPEATS` frames the receiver sends after that anyway."""
        ack = self.table.ack
        assert ack is not None
        for receiver in channel.destinations(sender):
            hop = self.network.next_hop(receiver, sender)
            if hop is None:
                continue
            _, frames = self._rates(channel, sender, [receiver])
            link = _link(self.network, None, sender, receiver, hop)
            self._flows[(receiver, link)].append(Flow(
                f"ack {channel.name}", (1 + ACK_REPEATS) * frames,
                self.codec.channel_cost_bits(ack), frozenset({sender}), frames))

    def _rates(self, channel: ChannelCodec, sender: str, dests: Iterable[str]
               ) -> tuple[float, float]:
        """Entries a second ``sender`` sends of ``channel`` to ``dests`` at most, and the
        frames that carry them: one value per ``interval_s`` (fragmented: each of its
        fragments), or at every opportunity one frame per turn of its busiest link; a
        stream no more than its window (``WINDOW`` entries past the first unacknowledged)
        per round trip to its farthest destination, in as few frames as hold them."""
        turns = max((t for (n, _), t in self.turns.items() if n == sender), default=0.0)
        per_value = -(-channel.value_bytes // channel.chunk_bytes) if channel.fragmented \
            else channel.family.bound if channel.family is not None else 1
        per_s = per_value / channel.interval_s if channel.interval_s > 0 else math.inf
        frames = min(turns, per_s)
        held = self._held(sender, self.codec.channel_cost_bits(channel)) \
            if channel.repeatable else 1
        if channel.stream:
            trip = max((self._round_trip_s(sender, d) for d in dests), default=0.0)
            if trip > 0:
                per_s = min(per_s, (WINDOW + 1) / trip)
                frames = min(frames, -(-(WINDOW + 1) // held) / trip)
        if math.isinf(per_s):  # at every opportunity: one a frame, or frames full of them
            per_s = frames * held
        return per_s, frames

    def _round_trip_s(self, a: str, b: str) -> float:
        """The shortest mean time a frame of ``a`` takes to ``b`` and one back: each hop's
        mean wait for its sender's turn (half the mean interval), airtime left out."""
        total = 0.0
        for x, y in (a, b), (b, a):
            path, problem = self.network.path(x, y)
            if problem is not None:
                return 0.0
            for u, v in itertools.pairwise(path):
                turns = self.turns.get((u, _link(self.network, None, y, u, v)), 0.0)
                total += 0.5 / turns if turns else 0.0
        return total


def _ways(network: Network, sender: str, dest: str, path: list[str]) -> list[list[str]]:
    """The paths from ``sender`` to ``dest``: its primary ``path``, and where routes list
    several hops, every other (a relay on one carries its share while the hops before it
    are down: budgeted as if it always did)."""
    if not network.listed:
        return [path]
    return [way for way, problem in network.paths(sender, dest) if problem is None]


def _bound(network: Network, path: list[str]) -> float | None:
    """The worst case of a frame along ``path``: each hop's longest wait and frame time."""
    return _round(sum(hop_s(network, x, y) for x, y in itertools.pairwise(path)))


def _link(network: Network, channel: ChannelCodec | None, dest: str, x: str, y: str) -> str:
    """The link hop ``x -> y`` takes for ``channel`` (None: a relay's, or an
    acknowledgement's) to ``dest`` while every link is up."""
    shared = [link.name for link in network.shared(x, y)]
    first = [*(channel.prefer if channel is not None else ()),
             *(network.mission.nodes[dest].prefer or ())]
    return next((n for n in first if n in shared), shared[0])


def _round(value: float) -> float | None:
    return None if math.isinf(value) else round(value, 3)
