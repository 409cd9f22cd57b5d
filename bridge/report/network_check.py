"""What ``zab check`` adds for a mission with several links or routes: its links, each route
and its worst-case time, what each relay carries against what its turns can carry, and each
channel's worst-case end-to-end age.

Budget of a relay, per link it sends on: every second, its turns there carry at most
``frame_bytes / worst interval`` bytes (a turn is a frame, or a bundle of frames). Its own
channels that go out on that link need their frames' bytes once per ``interval_s`` (a channel
sent at every opportunity needs every turn), and every frame it carries for others needs its
bytes (with their network header and a bundle's length byte) as often as its origin sends the
channels it carries. A relay over budget delays and then drops what it carries (a warning).

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
from typing import Any

from bridge.core.bounds import hop_s
from bridge.core.loaded import LoadedMission
from bridge.mission.network import Network
from bridge.wire.channels import ChannelCodec
from bridge.wire.frame import FrameCodec

__all__ = ["network_section"]


def network_section(loaded: LoadedMission, codec: FrameCodec,
                    by_link: dict[str, list[dict[str, Any]]]) -> tuple[dict[str, Any],
                                                                      list[str]]:
    """The ``network`` section of ``zab check``'s report and its warnings; ``by_link``: each
    link's node entries (their ``mac`` worst intervals)."""
    mission, table, network = loaded.mission, loaded.table, loaded.network
    net = table.net
    assert net is not None
    warnings: list[str] = []
    turns = {(link, e["name"]): e["mac"]["worst_interval_s"]
             for link, entries in by_link.items() for e in entries}
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
    own: dict[tuple[str, str], float] = defaultdict(float)
    carried: dict[tuple[str, str], float] = defaultdict(float)
    ages = []
    for channel in table.channels:
        worst: dict[str, Any] | None = None
        for sender in channel.senders:
            rate = _rate(channel, sender, network, turns)
            first_links: set[str] = set()
            for dest in channel.destinations(sender):
                path, problem = network.path(sender, dest)
                if problem is not None:
                    warnings.append(f"channel {channel.name!r}: {sender} to {dest}: {problem}")
                    continue
                size = codec.frame_bytes_for([channel]) + (
                    net.routed_bytes if len(path) > 2 else net.plain_bytes)
                carriers: set[tuple[str, str]] = set()  # on any path it may take, once each
                for way in _ways(network, sender, dest, path):
                    for i, (x, y) in enumerate(itertools.pairwise(way)):
                        link = _link(network, channel, dest, x, y)
                        if i == 0:
                            first_links.add(link)
                        else:
                            carriers.add((x, link))
                for carrier in carriers:
                    carried[carrier] += rate * (size + 1)
                bound = channel.interval_s + sum(hop_s(network, x, y)
                                                 for x, y in itertools.pairwise(path))
                if worst is None or bound > worst["age_bound_s"]:
                    worst = {"channel": channel.name, "from": sender, "to": dest,
                             "route": path, "age_bound_s": _round(bound)}
                if channel.ttl_s is not None and bound > channel.ttl_s:
                    warnings.append(f"channel {channel.name!r}: {' -> '.join(path)} may take "
                                    f"{bound:.1f} s, more than its ttl_s {channel.ttl_s:g}")
            for link in first_links:
                size = codec.frame_bytes_for([channel]) + net.routed_bytes
                own[(sender, link)] += rate * size
        if worst is not None:
            ages.append(worst)
    for spec in {c.spec.name: c.spec for c in table.query_codecs}.values():
        for asker, server in itertools.product(spec.askers, spec.servers):
            problems = [network.path(a, b)[1] for a, b in ((asker, server), (server, asker))
                        if asker != server]
            problem = next((p for p in problems if p is not None), None)
            if problem is not None:
                warnings.append(f"query {spec.name!r}: {asker} asking {server}: {problem}")
    relays = []
    for (node, link), load in sorted(carried.items()):
        interval = turns.get((link, node))
        capacity = network.link(link).frame_bytes_of(node) / interval if interval else 0.0
        need = own[(node, link)] + load
        relay = {"node": node, "link": link, "own_Bps": _round(own[(node, link)]),
                 "carried_Bps": _round(load), "capacity_Bps": _round(capacity),
                 "fits": need <= capacity}
        relays.append(relay)
        if need > capacity:
            warnings.append(f"relay {node} on {link}: its own data ({own[(node, link)]:.1f} "
                            f"B/s) and what it carries ({load:.1f} B/s) need more than its "
                            f"turns carry ({capacity:.1f} B/s): what it carries waits, and "
                            "past its life is dropped")
    return {"links": links, "routes": routes, "relays": relays, "age_bounds": ages,
            "max_hops": mission.max_hops, "header_bytes": {"plain": net.plain_bytes,
                                                           "routed": net.routed_bytes}}, warnings


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


def _rate(channel: ChannelCodec, sender: str, network: Network,
          turns: dict[tuple[str, str], float | None]) -> float:
    """Values per second ``sender`` sends of ``channel`` at most: one per ``interval_s``, or
    (every opportunity) one per turn of its busiest link."""
    if channel.interval_s > 0:
        return 1.0 / channel.interval_s
    intervals = [t for link in network.links_of(sender)
                 if (t := turns.get((link.name, sender)))]
    return 1.0 / min(intervals) if intervals else 0.0


def _link(network: Network, channel: ChannelCodec, dest: str, x: str, y: str) -> str:
    """The link hop ``x -> y`` takes for ``channel`` to ``dest`` while every link is up."""
    shared = [link.name for link in network.shared(x, y)]
    first = [*channel.prefer, *(network.mission.nodes[dest].prefer or ())]
    return next((n for n in first if n in shared), shared[0])


def _round(value: float) -> float | None:
    return None if math.isinf(value) else round(value, 3)
