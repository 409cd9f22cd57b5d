"""The links and routes of a mission (pure data): who carries which modem, and how traffic
reaches a node that is not a neighbour.

A mission without ``links`` has one link, ``modem``: its ``modem`` and ``mac`` sections, every
node a member. A mission with ``links`` names several (seed 002's generic link layer: an
acoustic modem under TDMA between the surface and one ROV, an RF modem under polling between
the ROVs): each is a :class:`LinkInfo` whose :attr:`LinkInfo.view` is the mission as that
link's MAC and timing see it (its modem and MAC, its members only, their addresses on it), so
the MAC rules of :mod:`bridge.core.mac` work on a link unchanged.

Routes. Two nodes are *neighbours* when they share a link. A node reaches another node through
the next hop its ``routes`` give (``{rov2: rov1}``; ``default``: every node not named, but
that hop itself), or the first of several whose link is up (``{rov2: [rov1, rov3]}``: the
*primary* first, then its alternatives), and any other node it shares a link with directly.
Routes are static and part of the mission file, so every node knows every node's routes: a
relay forwards a frame for exactly the destinations for which the node it heard it from
routes through it (:meth:`Network.carries`: through it alone, or through it among several
when the frame's header names it as the hop chosen), and ``zab check`` refuses a loop or a
path longer than ``max_hops`` over any choice of listed hops (:func:`network_problems`).
The listed routes of one node name the same hops in the same order (``default: [r1, r2]``,
or the same list for each destination): one choice per node, so every routed frame it sends
has one chosen hop to name.
"""

from __future__ import annotations

import contextlib
import itertools
from collections.abc import Iterable
from dataclasses import dataclass
from functools import cached_property
from typing import Any

from bridge.mission.model import (
    LinkSpec,
    Mission,
    Modem,
    ModemOverride,
    Node,
    listed_routes,
    route_hops,
    route_text,
)
from bridge.mission.presets import Preset, node_preset, preset_problem

__all__ = ["DEFAULT_LINK", "DEFAULT_ROUTE", "LinkInfo", "Network", "modem_problems",
           "network_problems", "water_address"]

DEFAULT_LINK = "modem"
"""The name of the one link of a mission without ``links``."""

DEFAULT_ROUTE = "default"
"""The ``routes`` key that routes every node not named otherwise (but its hop itself)."""

Loc = tuple[str | int, ...]


@dataclass(frozen=True)
class LinkInfo:
    """One link: its name and kind, its members and their addresses on it, and the mission as
    its MAC sees it (:attr:`view`)."""

    name: str
    kind: str
    members: tuple[str, ...]
    addresses: dict[str, int]
    view: Mission

    def name_of(self, address: int) -> str | None:
        """The member at ``address`` on this link (None: nobody)."""
        return self._names.get(address)

    @cached_property
    def _names(self) -> dict[int, str]:
        names: dict[int, str] = {}
        for name in reversed(self.members):  # the first in mission order wins
            names[self.addresses[name]] = name
        return names

    def frame_bytes_of(self, node: str) -> int:
        """The largest frame ``node`` sends on this link."""
        return self.view.node_modem(node).frame_bytes

    def preset_of(self, node: str) -> Preset | None:
        """``node``'s modem preset on this link (its frames' timing), looked up once per node
        for every core of the mission (a lookup builds the node's modem settings)."""
        presets = self._presets
        if node not in presets:
            presets[node] = node_preset(self.view, node)
        return presets[node]

    @cached_property
    def _presets(self) -> dict[str, Preset | None]:
        return {}


class Network:
    """The links and static routes of a mission."""

    def __init__(self, mission: Mission) -> None:
        self.mission = mission
        self.links: tuple[LinkInfo, ...] = tuple(_links(mission))
        self.several = mission.links is not None
        """The mission names its links (else it has the one link of its modem)."""
        self.routed = any(node.routes for node in mission.nodes.values())
        """Some node routes traffic through another."""
        self.listed = listed_routes(mission)
        """Some route lists several hops (routed frames name the hop chosen)."""
        self._on: dict[str, frozenset[str]] = {
            node: frozenset(link.name for link in self.links if node in link.addresses)
            for node in mission.nodes}  # the links each node is a member of

    @property
    def networked(self) -> bool:
        """Frames carry the network header (several links or routes: docs/wire-format.md)."""
        return self.several or self.routed

    def link(self, name: str) -> LinkInfo:
        return next(link for link in self.links if link.name == name)

    def links_of(self, node: str) -> tuple[LinkInfo, ...]:
        """The links ``node`` is a member of, in mission order."""
        return tuple(link for link in self.links if node in link.members)

    def shared(self, a: str, b: str) -> tuple[LinkInfo, ...]:
        """The links both ``a`` and ``b`` are members of, in mission order."""
        return tuple(link for link in self.links if a in link.addresses and b in link.addresses)

    def neighbours(self, node: str) -> tuple[str, ...]:
        """The nodes sharing a link with ``node``, in mission order."""
        return tuple(n for n in self.mission.nodes if n != node and self.shared(node, n))

    def next_hops(self, node: str, dest: str) -> tuple[str, ...]:
        """The neighbours through which ``node`` reaches ``dest``, best first (``dest`` itself
        when direct); () when it has no way to it."""
        hops = self.mission.nodes[node].hops_to(dest)
        if hops:
            return hops
        return () if self._on[node].isdisjoint(self._on[dest]) else (dest,)

    def next_hop(self, node: str, dest: str) -> str | None:
        """The neighbour through which ``node`` reaches ``dest`` first (its primary route:
        ``dest`` itself when direct); None when it has no way to it."""
        hops = self.next_hops(node, dest)
        return hops[0] if hops else None

    def carries(self, relay: str, src: str, dest: str, via: str | None) -> bool:
        """Whether ``relay``, hearing a frame for ``dest`` from ``src``, carries it on:
        ``src`` routes ``dest`` through it alone, or through it among several and chose it
        (``via``: the hop the frame's header names)."""
        hops = self.next_hops(src, dest)
        return relay in hops and (len(hops) == 1 or via == relay)

    def path(self, node: str, dest: str, first: str | None = None
             ) -> tuple[list[str], str | None]:
        """The nodes from ``node`` to ``dest`` following each hop's primary route (``first``:
        ``node``'s hop, when not its primary), and what goes wrong on the way (None: the
        path reaches ``dest``)."""
        path = [node]
        while path[-1] != dest:
            here = path[-1]
            hop = first if first is not None and here == node else self.next_hop(here, dest)
            if hop is None:
                return path, f"{here} has no route to {dest}"
            problem = self._step(path, hop, dest)
            if problem is not None:  # (a path too long is shown with its last hop)
                return [*path, hop] if "max_hops" in problem else path, problem
            path.append(hop)
        return path, None

    def _step(self, path: list[str], hop: str, dest: str) -> str | None:
        """What is wrong with going on from ``path`` to ``hop`` (None: nothing)."""
        here = path[-1]
        if not self.shared(here, hop):
            return f"{here} routes {dest} through {hop}, which shares no link with it"
        if hop in path:
            return f"routing loop {' -> '.join([*path[path.index(hop):], hop])}"
        if len(path) > self.mission.max_hops:
            return f"{' -> '.join([*path, hop])} takes more than max_hops {self.mission.max_hops}"
        return None

    def paths(self, node: str, dest: str) -> Iterable[tuple[list[str], str | None]]:
        """Every path from ``node`` to ``dest`` over any choice of listed hops, primary first,
        each with what goes wrong on it (None: it reaches ``dest``)."""
        stack: list[list[str]] = [[node]]
        while stack:
            path = stack.pop()
            here = path[-1]
            if here == dest:
                yield path, None
                continue
            hops = self.next_hops(here, dest)
            if not hops:
                yield path, f"{here} has no route to {dest}"
            for hop in reversed(hops):  # (the primary comes off the stack first)
                problem = self._step(path, hop, dest)
                if problem is not None:
                    yield [*path, hop], problem
                else:
                    stack.append([*path, hop])

    def relayed(self, node: str) -> tuple[str, ...]:
        """The destinations ``node`` reaches only through another node."""
        return tuple(d for d in self.mission.nodes
                     if d != node and any(hop != d for hop in self.next_hops(node, d)))

    def routed_over(self, node: str, link: str) -> tuple[str, ...]:
        """The destinations ``node`` may reach through a relay it hands them to on ``link``."""
        members = self.link(link).members
        return tuple(d for d in self.relayed(node)
                     if any(hop in members for hop in self.next_hops(node, d)))

    def path_frame_bytes(self, node: str, dest: str) -> int:
        """The largest frame every link on every path from ``node`` to ``dest`` carries (the
        smallest of each hop's links)."""
        sizes = [min(link.frame_bytes_of(a) for link in self.shared(a, b))
                 for path, problem in self.paths(node, dest) if problem is None
                 for a, b in itertools.pairwise(path)]
        return min(sizes, default=min(link.frame_bytes_of(node)
                                      for link in self.links_of(node)))

    def describe(self) -> list[str]:
        """What every node must agree on about routes (part of the mission fingerprint)."""
        return [f"{name}:{dest}>{route_text(hop)}" for name, node in self.mission.nodes.items()
                for dest, hop in sorted(node.routes.items())]


def _links(mission: Mission) -> Iterable[LinkInfo]:
    """The mission's links; without ``links``, its one link over ``modem`` and ``mac``."""
    if mission.links is None:
        addresses = {name: node.address for name, node in mission.nodes.items()}
        yield LinkInfo(DEFAULT_LINK, "acoustic", tuple(mission.nodes), addresses, mission)
        return
    for name, spec in mission.links.items():
        members = _members(mission, spec)
        addresses = {n: _address(mission, spec, n) for n in members}
        yield LinkInfo(name, spec.kind, members, addresses, _view(mission, spec, members,
                                                                  addresses))


def _address(mission: Mission, spec: LinkSpec, node: str) -> int:
    """``node``'s address on the link of ``spec``: its own there, else the node's."""
    address = spec.member(node).address
    return mission.nodes[node].address if address is None else address


def _members(mission: Mission, spec: LinkSpec) -> tuple[str, ...]:
    if spec.nodes is None:
        return tuple(mission.nodes)
    return tuple(n for n in mission.nodes if n in spec.nodes)  # mission order


def _view(mission: Mission, spec: LinkSpec, members: tuple[str, ...],
          addresses: dict[str, int]) -> Mission:
    """``mission`` as ``spec``'s MAC and timing see it: its modem and MAC, its members with
    their address and modem settings on it."""
    nodes: dict[str, Node] = {
        n: mission.nodes[n].model_copy(update={"address": addresses[n],
                                               "modem": spec.member(n).modem})
        for n in members}
    view = mission.model_copy(update={"modem": spec.modem, "mac": spec.mac, "nodes": nodes,
                                      "links": None, "link": spec.link or mission.link})
    view.__dict__.pop("names_found", None)  # (a cache of the whole mission's addresses)
    return view


def network_problems(mission: Mission) -> Iterable[tuple[Loc, str]]:
    """What a mission's links and routes get wrong, as ``(location, message)``."""
    if mission.links is not None:
        yield from _link_problems(mission)
    network = Network(mission)
    names = set(mission.links or ())
    for name, node in mission.nodes.items():
        yield from _route_problems(mission, network, name, node)
        for i, link in enumerate(node.prefer or ()):
            if link not in names:
                yield (("nodes", name, "prefer", i), _unknown_link(link, names))
    for c, channel in enumerate(mission.channels):
        for i, link in enumerate(channel.prefer or ()):
            if link not in names:
                yield (("channels", c, "prefer", i), _unknown_link(link, names))
    if DEFAULT_ROUTE in mission.nodes:
        yield (("nodes", DEFAULT_ROUTE), f"{DEFAULT_ROUTE!r} names every other node in routes:"
               " give this node another name")
    if network.routed:
        for name in mission.nodes:
            for dest in mission.nodes:
                if dest != name and network.next_hop(name, dest) is not None:
                    yield from _path_problems(network, name, dest)


def _route_problems(mission: Mission, network: Network, name: str, node: Node
                    ) -> Iterable[tuple[Loc, str]]:
    """What one node's routes get wrong: unknown nodes, non-neighbours, lists that differ."""
    lists: dict[tuple[str, ...], str] = {}
    for dest, route in node.routes.items():
        loc: Loc = ("nodes", name, "routes", dest)
        hops = route_hops(route)
        if dest != DEFAULT_ROUTE and dest not in mission.nodes:
            yield (loc, f"unknown node {dest!r}")
            continue
        if dest == name:
            yield (loc, f"a route from {name} to itself (routes name the nodes it reaches "
                   "through others)")
            continue
        if not hops:
            yield (loc, "name at least one hop")
        if len(set(hops)) < len(hops):
            yield (loc, f"a hop listed twice in {list(hops)}")
        for i, hop in enumerate(hops):
            at: Loc = loc if isinstance(route, str) else (*loc, i)
            if hop not in mission.nodes:
                yield (at, f"unknown node {hop!r}")
            elif hop in (name, dest):
                yield (at, f"{name} cannot route {dest} through {hop}")
            elif not network.shared(name, hop):
                yield (at, f"{name} shares no link with {hop}: it cannot hand it traffic")
        if len(hops) > 1:
            lists.setdefault(hops, dest)
    if len(lists) > 1:
        (a, first), (b, second) = list(lists.items())[:2]
        yield (("nodes", name, "routes", second), f"{name} lists {list(b)} for {second} but "
               f"{list(a)} for {first}: a node's routes that list several hops list the same "
               "ones in the same order (one choice per node)")


def _path_problems(network: Network, name: str, dest: str) -> Iterable[tuple[Loc, str]]:
    """Loops and paths over ``max_hops`` from ``name`` to ``dest``, over any choice of listed
    hops (the first of each kind)."""
    found: set[str] = set()
    for _, problem in network.paths(name, dest):
        if problem is None or "no route" in problem:
            continue
        kind = problem.split(" ", 1)[0]
        if kind not in found:
            found.add(kind)
            yield (("nodes", name, "routes"), f"{name} to {dest}: {problem}")


def _unknown_link(link: str, names: set[str]) -> str:
    if not names:
        return f"unknown link {link!r}: the mission has one link (give `links` to name several)"
    return f"unknown link {link!r} (links: {', '.join(sorted(names))})"


def _link_problems(mission: Mission) -> Iterable[tuple[Loc, str]]:
    """A mission with ``links``: no mission-wide modem or MAC, known members, everybody on a
    link, one address per member on each."""
    for field in ("modem", "mac"):
        if field in mission.model_fields_set:
            yield ((field,), f"give {field} per link in `links`, not for the whole mission")
    for name, node in mission.nodes.items():
        if node.modem.model_fields_set:
            yield (("nodes", name, "modem"), "with `links`, a node's modem settings go in "
                   f"links.<link>.nodes.{name}.modem")
    if mission.wire.dlbl:
        yield (("wire", "dlbl"), "DLBL ranging over several links is not supported yet")
    if mission.wire.format != "zab":
        yield (("wire", "format"), "several links need zab's frame format")
    assert mission.links is not None
    on_a_link: set[str] = set()
    for name, spec in mission.links.items():
        for member in spec.nodes or ():
            if member not in mission.nodes:
                yield (("links", name, "nodes", member), f"unknown node {member!r}")
        members = _members(mission, spec)
        if len(members) < 2:
            yield (("links", name, "nodes"), "a link needs at least two members")
        on_a_link.update(members)
        seen: dict[int, str] = {}
        for member in members:
            address = _address(mission, spec, member)
            if address in seen:
                yield (("links", name, "nodes", member), f"address {address} already used on "
                       f"link {name!r} by {seen[address]!r}")
            seen.setdefault(address, member)
    for name in mission.nodes:
        if name not in on_a_link:
            yield (("nodes", name), f"{name} is on no link")


def water_address(value: Any) -> tuple[str, int] | None:
    """A modem's ``water`` option, ``"host:port"`` (or a bare port number, meaning
    127.0.0.1), as ``(host, port)``; None when it is neither (the port is not checked)."""
    if isinstance(value, int) and not isinstance(value, bool):
        return "127.0.0.1", value
    if isinstance(value, str):
        host, sep, port = value.rpartition(":")
        if not sep:
            host, port = "127.0.0.1", value
        with contextlib.suppress(ValueError):
            return host.strip("[]") or "127.0.0.1", int(port)
    return None


def modem_problems(mission: Mission) -> Iterable[tuple[Loc, str]]:
    """What the options of the mission's modems name that does not exist: a ``preset`` no
    modem kind has (the MAC's timing and the simulated water come from it), a ``water`` no
    water can listen on, wherever a modem's settings are given; and two links whose modems
    give the same ``water`` (one water is one ocean with one preset: ``zab water`` starts one
    per link, at its address); a simulated water's ``seed`` that is not a whole number, its
    ``loss`` not a share from 0 to 1."""
    for loc, modem in _modem_sections(mission):
        if "preset" in modem.options:
            problem = preset_problem(modem.options["preset"])
            if problem is not None:
                yield ((*loc, "options", "preset"), problem)
        if "water" in modem.options:
            problem = _water_problem(modem.options["water"])
            if problem is not None:
                yield ((*loc, "options", "water"), problem)
        for option, check in (("seed", _seed_problem), ("loss", _loss_problem)):
            if option in modem.options and (problem := check(modem.options[option])):
                yield ((*loc, "options", option), problem)
    waters: dict[tuple[str, int], str] = {}
    for link, spec in (mission.links or {}).items():
        address = water_address(spec.modem.options.get("water"))
        if address is None or _water_problem(address[1]) is not None:
            continue
        if address in waters:
            yield (("links", link, "modem", "options", "water"),
                   f"{address[0]}:{address[1]} is also the water of link {waters[address]!r}: "
                   "each link needs a water of its own (one `zab water` per link, each with "
                   "the link's modem preset)")
        waters.setdefault(address, link)


def _water_problem(value: Any) -> str | None:
    """What is wrong with ``value`` as the address of a water (None: nothing)."""
    address = water_address(value)
    if address is None:
        return f"must be the 'host:port' of `zab water` (got {value!r})"
    if not 1 <= address[1] <= 65535:
        return f"port {address[1]} is out of range (1-65535)"
    return None


def _seed_problem(value: Any) -> str | None:
    """What is wrong with ``value`` as the simulated water's random seed (None: nothing)."""
    if isinstance(value, int) and not isinstance(value, bool):
        return None
    return f"must be a whole number, the simulated water's random seed (got {value!r})"


def _loss_problem(value: Any) -> str | None:
    """What is wrong with ``value`` as the share of frames the simulated water loses."""
    if isinstance(value, int | float) and not isinstance(value, bool) and 0 <= value <= 1:
        return None
    return ("must be a number from 0 to 1, the share of frames the simulated water loses "
            f"(got {value!r})")


def _modem_sections(mission: Mission) -> Iterable[tuple[Loc, Modem | ModemOverride]]:
    """Every modem section of the mission file, with its place: the mission's, each node's,
    each link's and each link member's."""
    yield ("modem",), mission.modem
    for name, node in mission.nodes.items():
        yield ("nodes", name, "modem"), node.modem
    for link, spec in (mission.links or {}).items():
        yield ("links", link, "modem"), spec.modem
        if isinstance(spec.nodes, dict):
            for name, member in spec.nodes.items():
                yield ("links", link, "nodes", name, "modem"), member.modem
