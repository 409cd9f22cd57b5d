"""The surfacing part of ``zab demo``: a vehicle's scripted path brings it to the surface, where
``zab sim``'s simulated WiFi joins its Zenoh to the surface's (:mod:`bridge.runtime.surface_wifi`,
decided by :func:`bridge.sim.scenario.surface_script`), then it dives again.

:func:`surfacing_for_tour` makes the mission do it (when it has no ``surfacing`` yet);
:class:`SurfacingWatch` is a plain Zenoh application at the surface node that sees it happen:
the vehicle's bridge token appearing and going, and what arrives from the vehicle meanwhile.
"""

from __future__ import annotations

import math
import threading
import time
from collections import Counter
from typing import Any

import zenoh

from bridge.cli.poke import value_of
from bridge.core.events import Event, FrameSent, Surfaced
from bridge.core.loaded import LoadedMission
from bridge.mission.model import Mission, Position
from bridge.mission.presets import node_preset
from bridge.runtime.session import origin_of, origin_tag
from bridge.sim.scenario import surface_script

SURFACE_AT_S = 30.0  # path time at which the tour's vehicle reaches the surface
SURFACED_S = 14.0  # how long it stays there
TRANSIT_MPS = 0.8  # the formation's speed (bridge.cli.demo), which it keeps
ROUTER = {"mode": "router", "scouting/delay": 0, "scouting/gossip/enabled": False}


def surfacing_for_tour(data: dict[str, Any], mission: Mission, duration: float) -> str | None:
    """Give the mission (raw YAML data, changed in place) a scripted surfacing: the last
    submerged vehicle with a position rises to the surface, stays, dives (sailing north with
    the formation, or where it is if that would take it out of the water's range of the
    surface node within the tour's ``duration``, by ``mission``: ``data`` as loaded); it and
    the surface
    node run Zenoh routers, so the simulated WiFi joins them; the mission's ``surfacing``
    settings stay (republish by default). Returns the change in words (None: a node has a
    scripted path already, or there is no surface node or vehicle to use)."""
    nodes = data.get("nodes") or {}
    surface = next((n for n, v in nodes.items() if v.get("role") == "surface"), None)
    vehicles = [n for n, v in nodes.items() if v.get("role", "submerged") != "surface"
                and v.get("position")]
    if any(v.get("path") for v in nodes.values()) or surface is None or not vehicles:
        return None
    name = vehicles[-1]
    node = nodes[name]
    x, y = float(node["position"].get("x", 0)), float(node["position"].get("y", 0))
    depth = float(node["position"].get("depth", 0))
    if depth <= 0:
        return None
    start = {"x": x, "y": y, "depth": depth}
    if _sails_out_of_range(mission, name, surface, duration):  # (an RF link in a tank): up and down
        speed = min(depth / SURFACE_AT_S, TRANSIT_MPS)
        y_up = round(y + speed * SURFACED_S, 2)
        node["path"] = {"speed_mps": round(speed, 4), "waypoints": [
            start, {"x": x, "y": y, "depth": 0}, {"x": x, "y": y_up, "depth": 0},
            {"x": x, "y": y_up, "depth": depth}]}
    else:
        # it keeps sailing north with the formation, rising to the surface and diving again
        # on the way, so its navigation (and its position track) stays that of a transiting
        # vehicle
        run = TRANSIT_MPS * SURFACE_AT_S  # metres sailed (along the slope) until it surfaces
        rise = math.sqrt(max(run**2 - depth**2, 0.0))  # northward while rising
        north = [y + rise, y + rise + TRANSIT_MPS * SURFACED_S]
        north.append(north[-1] + rise)
        node["path"] = {"speed_mps": TRANSIT_MPS, "waypoints": [
            start, {"x": x, "y": round(north[0], 2), "depth": 0},
            {"x": x, "y": round(north[1], 2), "depth": 0},
            {"x": x, "y": round(north[2], 2), "depth": depth},
            {"x": x, "y": round(north[2] + TRANSIT_MPS * 600, 2), "depth": depth}]}
    for who in (surface, name):
        nodes[who].setdefault("zenoh", {}).update(ROUTER)
    if data.get("surfacing") is None:
        data["surfacing"] = {"republish": True}
    return (f"{name} surfaces about {SURFACE_AT_S:.0f} s in for about {SURFACED_S:.0f} s (a "
            f"scripted path); {surface}'s and {name}'s Zenoh run as routers, joined over the "
            "simulated WiFi while it is up")


def _sails_out_of_range(mission: Mission, vehicle: str, surface: str,
                        duration: float) -> bool:
    """Whether ``vehicle`` sailing north with the formation for ``duration`` would leave the
    simulated water's range of ``surface`` (the shorter of their presets' ranges; a mission
    without presets has no such limit)."""
    ranges = [p.max_range_m for p in (node_preset(mission, vehicle),
                                      node_preset(mission, surface)) if p is not None]
    if not ranges:
        return False
    here, there = (mission.nodes[n].position or Position() for n in (vehicle, surface))
    gap = math.dist((here.x, here.y, here.depth), (there.x, there.y, there.depth))
    reach = min(ranges)
    return gap <= reach < gap + TRANSIT_MPS * duration  # (out of its range already: relays)


def turns_to_wait(loss: float, miss: float = 1e-3) -> int:
    """How many of a sender's turns to wait for one frame to get through water losing
    ``loss`` of the frames, so that all of them being lost has odds below ``miss``."""
    if loss <= 0:
        return 1
    if loss >= 1:
        return 1  # nothing gets through: waiting longer shows nothing more
    return max(1, math.ceil(math.log(miss) / math.log(loss) - 1e-9))


class SentAtSwitches:
    """The vehicle's own bridge, as it saw the surface node come and go over IP: when it saw
    each switch, and which channels each of its frames carried, by the time the frame began
    (fed the fleet's events). A frame built just before the switch and reported after it
    counts as sent before: what matters is when the bridge chose its contents."""

    def __init__(self, vehicle: str, surface: str) -> None:
        self.vehicle, self.surface = vehicle, surface
        self.switches: list[tuple[bool, float]] = []
        self.surface_switches: list[tuple[bool, float]] = []  # the surface bridge's own view
        self.frames: list[tuple[float, list[str]]] = []
        self._lock = threading.Lock()

    def __call__(self, node: str, event: Event) -> None:
        if node == self.surface and isinstance(event, Surfaced) and event.peer == self.vehicle:
            with self._lock:
                self.surface_switches.append((event.ip, event.time))
        if node != self.vehicle:
            return
        with self._lock:
            if isinstance(event, Surfaced) and event.peer == self.surface:
                self.switches.append((event.ip, event.time))
            elif isinstance(event, FrameSent):
                self.frames.append((event.time, event.channels))

    def surface_saw_up(self, after: float) -> float | None:
        """When the surface node's bridge first saw the vehicle over IP at or after wall time
        ``after`` (its own view: an acoustic copy it decoded before then is published, by
        design, even if the token had reached an application a moment sooner)."""
        with self._lock:
            return next((t for ip, t in self.surface_switches if ip and t >= after), None)

    def while_up(self) -> dict[str, int] | None:
        """Values sent per channel in frames begun between the vehicle's first up and the down
        after it (None: its bridge has not seen both yet)."""
        with self._lock:
            up = next((i for i, (ip, _) in enumerate(self.switches) if ip), None)
            if up is None:
                return None
            down = next((t for ip, t in self.switches[up + 1:] if not ip), None)
            if down is None:
                return None
            start = self.switches[up][1]
            return dict(Counter(name for t, names in self.frames if start <= t < down
                                for name in names))


class SurfacingWatch:
    """At the surface node: the vehicle's bridge token (up: joined over IP) and the values
    arriving from the vehicle, with wall times and how each came: ``ip`` (relayed by the
    vehicle's bridge, or the vehicle's program's own sample where it publishes on the output
    key) or ``acoustic`` (published by the surface's bridge from a frame)."""

    def __init__(self, loaded: LoadedMission, session: zenoh.Session, surface: str,
                 vehicle: str) -> None:
        self.surface, self.vehicle = surface, vehicle
        self.t0 = time.time()
        self.switches: list[tuple[float, bool]] = []
        self.arrivals: list[tuple[float, str, Any, str]] = []
        mission = loaded.mission.mission
        self._via = {origin_tag(mission, vehicle): "ip", origin_tag(mission, surface): "acoustic"}
        self.changed = threading.Event()
        self._lock = threading.Lock()
        elements = [e for c in loaded.table.channels
                    if c.sent_by(vehicle) and surface in c.destinations(vehicle)
                    for e in c.elements]
        keys = sorted({e.output_key(vehicle, surface) for e in elements})
        self.keys = keys
        # where the output key is the input key, the vehicle's bridge relays nothing over
        # IP: the program's own sample arrives, with no bridge's attachment
        self._own = {e.output_key(vehicle, surface) for e in elements
                     if e.output_key(vehicle, surface) == e.input_key(vehicle)}
        self._entities = [session.declare_subscriber(k, self._arrived) for k in keys]
        self._entities.append(session.liveliness().declare_subscriber(
            f"@zab/{loaded.mission.mission}/{vehicle}/bridge", self._token, history=True))

    def _token(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.switches.append((time.time(), sample.kind == zenoh.SampleKind.PUT))
        self.changed.set()

    def _arrived(self, sample: zenoh.Sample) -> None:
        attachment = sample.attachment.to_bytes() if sample.attachment is not None else b""
        via = self._via.get(origin_of(attachment))
        if via is None and not attachment and str(sample.key_expr) in self._own:
            via = "ip"
        if via is None:  # not from either bridge
            return
        value = value_of(str(sample.key_expr), sample.payload.to_bytes(), str(sample.encoding))
        with self._lock:
            self.arrivals.append((time.time(), str(sample.key_expr), value, via))
        self.changed.set()

    def switch(self, up: bool, after: float = 0.0) -> float | None:
        """When the token last came (``up``) or went, after wall time ``after``."""
        with self._lock:
            return next((t for t, u in reversed(self.switches) if u == up and t >= after), None)

    def between(self, start: float, end: float, via: str) -> list[tuple[float, str, Any]]:
        """Arrivals ``via`` ip or acoustic at wall times in [start, end)."""
        with self._lock:
            return [a[:3] for a in self.arrivals if start <= a[0] < end and a[3] == via]


def surfaced_vehicle(loaded: LoadedMission) -> tuple[str, str, float, float] | None:
    """(surface node, vehicle, surfacing, dive) of the mission's first scripted surfacing, in
    seconds of path time (None: there is none)."""
    script = surface_script(loaded)
    if script is None or not script.surface_nodes:
        return None
    for vehicle, windows in script.windows.items():
        for start, end in windows:
            if start >= 0 and end < float("inf"):
                return script.surface_nodes[0], vehicle, start, end
    return None
