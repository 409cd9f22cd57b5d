"""Worst-case times across a network of links (pure): how long a hop, a route and a round
trip may take, from each link's MAC and modem preset.

A hop from ``a`` to a neighbour ``b`` waits at most for ``a``'s next turn on their link (its
MAC's worst interval; :data:`~bridge.core.queries.UNBOUNDED_TURN_S` where the MAC gives no
bound) and then takes ``a``'s largest frame's time (latency, airtime, propagation). When they
share several links, the slowest bounds it (traffic may fail over to it). A route adds its
hops; a relay queues what it carries behind nothing but frames of higher rank, each of its
turns carrying a bundle, so its wait is the hop's.
"""

from __future__ import annotations

import itertools

from bridge.core.mac import frame_time_s, mac_for, mac_report
from bridge.mission.model import Mission
from bridge.mission.network import Network

__all__ = ["UNBOUNDED_TURN_S", "hop_s", "network_retry_s", "retry_floor_s", "round_trip_s",
           "route_s"]

UNBOUNDED_TURN_S = 30.0
"""A node's wait for a turn when the MAC gives no bound."""


def hop_s(network: Network, a: str, b: str) -> float:
    """The longest a frame of ``a`` takes to reach its neighbour ``b``."""
    worst = 0.0
    for link in network.shared(a, b):
        turn = mac_report(link.view, a, None).worst_interval_s
        worst = max(worst, (UNBOUNDED_TURN_S if turn is None else turn)
                    + (frame_time_s(link.view, a) or 0.0))
    return worst


def route_s(network: Network, a: str, b: str) -> float:
    """The longest a frame of ``a`` takes to reach ``b`` along the routes (each hop's
    :func:`hop_s`); infinite when there is no path."""
    path, problem = network.path(a, b)
    if problem is not None:
        return float("inf")
    return sum(hop_s(network, x, y) for x, y in itertools.pairwise(path))


def round_trip_s(network: Network, a: str, b: str) -> float:
    """A frame from ``a`` to ``b`` and one back."""
    return route_s(network, a, b) + route_s(network, b, a)


def network_retry_s(mission: Mission) -> float:
    """The first retransmission's wait of a reliable value in a mission with several links or
    routes: the longest round trip between two nodes that reach each other, and never less
    than a link's own MAC would wait."""
    network = Network(mission)
    links = max(mac_for(link.view).retry_s() for link in network.links)
    trips = [round_trip_s(network, a, b) for a in mission.nodes for b in mission.nodes
             if a < b]
    return max([links, *(t for t in trips if t != float("inf"))])


def retry_floor_s(network: Network, node: str) -> float:
    """The shortest wait before ``node`` sends a reliable value again once its timer learned
    the round trips (:meth:`~bridge.core.reliable.ReliableSender.learn`): what its links' own
    MACs wait for a neighbour (one TDMA cycle, else ten seconds)."""
    return max(mac_for(link.view).retry_s() for link in network.links_of(node))
