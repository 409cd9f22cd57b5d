"""The relay part of ``zab demo`` (issue 29): a vehicle out of the surface's reach, its values
carried on by another (``deploy/missions/umci_relay.yaml``: ROV2 on RF only to ROV1, which
holds the acoustic link with the surface).

:func:`relay_plan` picks the surface node and the vehicle whose route to it is longest;
:class:`RelayWatch` records, from the surface bridge's events, the first frames of that
vehicle it took through a relay (their origin, relay, hops and values).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any

from bridge.core.events import Event, FrameReceived
from bridge.core.loaded import LoadedMission


@dataclass(frozen=True)
class RelayPlan:
    """The surface node, the vehicle reached through others, its route and the links of
    each hop."""

    surface: str
    vehicle: str
    path: tuple[str, ...]
    links: tuple[str, ...]


def relay_plan(loaded: LoadedMission) -> RelayPlan | None:
    """The vehicle whose traffic to the surface goes through the most relays (None: no
    surface node, or every vehicle reaches it directly)."""
    network, mission = loaded.network, loaded.mission
    surface = next((n for n, node in mission.nodes.items() if node.role == "surface"), None)
    if surface is None:
        return None
    found = []
    for vehicle in mission.nodes:
        path, problem = network.path(vehicle, surface)
        if vehicle != surface and problem is None and len(path) > 2:
            found.append(path)
    if not found:
        return None
    path = max(found, key=len)
    links = tuple("/".join(link.name for link in network.shared(a, b))
                  for a, b in itertools.pairwise(path))
    return RelayPlan(surface, path[0], tuple(path), links)


class RelayWatch:
    """The frames of the plan's vehicle that the surface's bridge took through a relay."""

    def __init__(self, plan: RelayPlan) -> None:
        self.plan = plan
        self.arrivals: list[tuple[float, FrameReceived]] = []

    def __call__(self, node: str, event: Event) -> None:
        if node == self.plan.surface and isinstance(event, FrameReceived) \
                and event.src == self.plan.vehicle and event.meta.get("via") \
                and event.values and len(self.arrivals) < 16:
            self.arrivals.append((event.time, event))

    def first(self) -> tuple[float, FrameReceived] | None:
        return self.arrivals[0] if self.arrivals else None


def shown_values(event: FrameReceived) -> tuple[str, Any]:
    """A channel the frame carried, and its first element's value."""
    channel, elements = next(iter(event.values.items()))
    return channel, elements[0] if elements else None
