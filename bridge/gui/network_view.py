"""What the page shows of a network of links (issue 29): the mission's links by kind and each
node's route, each observer's peers per link (``hop`` items), the link its traffic to a peer
takes now (``route`` items), and each relay's load (pure, clock-free)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from bridge.core.loaded import LoadedMission

Item = dict[str, Any]


def network_description(loaded: LoadedMission, node: str) -> dict[str, Any]:
    """The page's static picture of the network: each link (name, kind, members) and, from
    ``node``, the route to every other node (only the mission's one link: no links, routes
    of one hop)."""
    network = loaded.network
    links = [{"name": link.name, "kind": link.kind, "members": list(link.members)}
             for link in network.links] if network.several else []
    routes = {}
    for dest in loaded.mission.nodes:
        if dest != node:
            path, problem = network.path(node, dest)
            routes[dest] = {"path": path, "problem": problem}
    return {"links": links, "routes": routes}


def relay_view(stats: Mapping[str, Any]) -> dict[str, Any]:
    """A node's relay load in its stats: frames it carried on, and those waiting per link."""
    network = stats.get("network")
    if not isinstance(network, Mapping):
        return {}
    waiting = network.get("waiting")
    return {"relayed": network.get("relayed") if isinstance(network.get("relayed"), int)
            else 0,
            "carrying": {str(k): v for k, v in waiting.items() if isinstance(v, int)}
            if isinstance(waiting, Mapping) else {}}


class NetworkView:
    """Each observer's peers per link, and the link its traffic to each peer takes."""

    def __init__(self, nodes: set[str]) -> None:
        self.nodes = nodes
        self.hops: dict[tuple[str, str, str], Item] = {}
        self.routes: dict[tuple[str, str], Item] = {}

    def status(self, node: str, topic: str, name: str, value: Mapping[str, Any],
               now: float) -> Item | None:
        """A ``links/<link>/<peer>`` or ``route/<peer>`` key's value: the item it makes, or
        None when it says nothing new."""
        if topic == "links":
            link, _, peer = name.partition("/")
            return self._hop(node, link, peer, value.get("state"), now)
        if topic == "route" and name in self.nodes:
            item = {"kind": "route", "observer": node, "peer": name,
                    "link": value.get("link"), "via": value.get("via"),
                    "reason": value.get("reason"), "time": now}
            self.routes[(node, name)] = item
            return item
        return None

    def stats(self, node: str, stats: Mapping[str, Any], now: float) -> list[Item]:
        """The hops a node's stats show (each link's peers' states, once a second: a page
        that connects late learns them there)."""
        network = stats.get("network")
        links = network.get("links") if isinstance(network, Mapping) else None
        if not isinstance(links, Mapping):
            return []
        out = []
        for link, info in links.items():
            states = info.get("states") if isinstance(info, Mapping) else None
            for peer, state in (states.items() if isinstance(states, Mapping) else ()):
                if (item := self._hop(node, str(link), str(peer), state, now)) is not None:
                    out.append(item)
        return out

    def _hop(self, node: str, link: str, peer: str, state: object, now: float) -> Item | None:
        if peer not in self.nodes or state not in ("up", "degraded", "down"):
            return None
        previous = self.hops.get((node, link, peer))
        if previous is not None and previous["state"] == state:
            return None
        item = {"kind": "hop", "observer": node, "link": link, "peer": peer,
                "state": state, "since": now}
        self.hops[(node, link, peer)] = item
        return item


    def items(self) -> list[Item]:
        return [*self.hops.values(), *self.routes.values()]
