"""The simulated water of a mission, set up in one place for every runtime (pure).

``zab sim`` and ``zab water`` serve it to their nodes (:class:`~bridge.sim.service.
WaterService`); ``zab sim --fast`` runs it on the virtual clock (:class:`~bridge.sim.ocean.
Ocean`). Both take the same preset, seed, loss, static positions and scripted paths from here,
and the same scripted surfacings (:func:`surface_script`: a vehicle whose path reaches the
surface is on the surface's IP link while it is there).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from bridge.core.loaded import LoadedMission
from bridge.core.positioning import simulated_preset
from bridge.mission.model import Mission
from bridge.mission.path import Path
from bridge.mission.presets import Preset
from bridge.sim.ocean import Position


@dataclass(frozen=True)
class Water:
    """What the simulated water of a mission is made of."""

    preset: Preset
    seed: int
    positions: dict[int, Position]  # nodes with a static position (others join at the origin)
    loss: float
    paths: dict[int, Path]


def water_of(loaded: LoadedMission, seed: int | None = None, loss: float | None = None,
             preset: Preset | None = None) -> Water:
    """The mission's water: its preset, ``seed`` (else ``modem.options.seed``, else 0),
    ``loss`` (else ``modem.options.loss``, else 0), static positions and paths. With several
    links, its first link's (:func:`waters_of` gives each)."""
    return _water(loaded.network.links[0].view, seed, loss, preset)


def waters_of(loaded: LoadedMission, seed: int | None = None,
              loss: float | None = None) -> dict[str, Water]:
    """The water of each link of the mission, by link name: each modem kind with its own
    preset (range, rate, delay), the members at their addresses on it, one seed each (the
    first link's is the mission's)."""
    return {link.name: _water(link.view, None if seed is None else seed + i, loss, None)
            for i, link in enumerate(loaded.network.links)}


def water_stats(stats: Mapping[str | None, dict[str, Any]]) -> dict[str, Any]:
    """The counters of a mission's waters as one: its one water's, or with several links
    each link's rows named by ``link`` (and each water's counters under ``per_link``)."""
    if len(stats) == 1:
        return next(iter(stats.values()))
    return {"links": [{**row, "link": link} for link, one in stats.items()
                      for row in one["links"]], "per_link": dict(stats)}


def _water(mission: Mission, seed: int | None, loss: float | None,
           preset: Preset | None) -> Water:
    options = mission.modem.options
    return Water(
        preset=preset if preset is not None else simulated_preset(mission),
        seed=seed if seed is not None else int(options.get("seed", 0)),
        positions={node.address: (node.position.x, node.position.y, node.position.depth)
                   for node in mission.nodes.values() if node.position is not None},
        loss=float(options.get("loss", 0.0)) if loss is None else loss,
        paths={node.address: Path.from_spec(node.path)
               for node in mission.nodes.values() if node.path is not None},
    )


SURFACE_DEPTH_M = 0.1
"""A vehicle whose scripted path is at most this deep is at the surface, on the surface's IP
link (the simulated WiFi)."""

Window = tuple[float, float]  # path time from, to (either may be infinite)


def surface_windows(path: Path, depth_m: float = SURFACE_DEPTH_M) -> tuple[Window, ...]:
    """When ``path`` is at most ``depth_m`` deep, in path time: for a looping path, within one
    pass ``[0, duration_s)`` (it repeats); otherwise for all time (the first window may start
    at -inf, the last end at +inf: waiting at the first or last waypoint)."""
    points = path.waypoints
    stops = [*points, points[0]] if path.loop else list(points)
    out: list[list[float]] = []

    def add(a: float, b: float) -> None:
        if out and a <= out[-1][1] + 1e-9:
            out[-1][1] = max(out[-1][1], b)
        elif b >= a:
            out.append([a, b])

    if not path.loop and points[0][2] <= depth_m:
        add(-math.inf, 0.0)
    t = 0.0
    for a, b in itertools.pairwise(stops):
        span = math.dist(a, b) / path.speed_mps
        d0, d1 = a[2], b[2]
        if d0 <= depth_m and d1 <= depth_m:
            add(t, t + span)
        elif d0 <= depth_m:  # rising out of the window: leaves it on the way down
            add(t, t + span * (depth_m - d0) / (d1 - d0))
        elif d1 <= depth_m:  # coming up: reaches it on the way
            add(t + span * (d0 - depth_m) / (d0 - d1), t + span)
        t += span
    if not path.loop and points[-1][2] <= depth_m:
        add(t, math.inf)
    return tuple((a, b) for a, b in out)


@dataclass(frozen=True)
class SurfaceScript:
    """Which vehicles are at the surface when, from their scripted paths: a surfaced vehicle
    reaches the mission's surface nodes (and the other surfaced vehicles) over IP. ``zab sim``
    joins their Zenoh over a simulated WiFi then; ``zab sim --fast`` tells their cores."""

    surface_nodes: tuple[str, ...]
    windows: dict[str, tuple[Window, ...]]  # vehicles whose path reaches the surface
    periods: dict[str, float]  # looping paths: the pass duration (windows repeat)
    start: float = 0.0  # time 0 of every path

    def surfaced(self, node: str, t: float) -> bool:
        """Whether ``node`` is at the surface at time ``t``."""
        windows = self.windows.get(node, ())
        s = t - self.start
        if node in self.periods:
            s %= self.periods[node]
        return any(a <= s < b for a, b in windows)

    def next_change(self, node: str, t: float) -> float | None:
        """The first time after ``t`` at which ``node`` surfaces or dives (None: never)."""
        windows = self.windows.get(node, ())
        if not windows:
            return None
        s = t - self.start
        period = self.periods.get(node)
        if period is None:
            edges = [e for w in windows for e in w if math.isfinite(e) and e > s + 1e-9]
            return self.start + min(edges) if edges else None
        base = math.floor(s / period) * period
        edges = [base + k * period + e for k in (0, 1) for w in windows for e in w
                 if base + k * period + e > s + 1e-9]
        return self.start + min(edges) if edges else None

    def next_any(self, t: float) -> float | None:
        """The first time after ``t`` at which some vehicle surfaces or dives."""
        return min((c for v in self.windows if (c := self.next_change(v, t)) is not None),
                   default=None)

    def ip_pairs(self, t: float) -> set[tuple[str, str]]:
        """Every pair (in mission order as given) reaching each other over IP at ``t``."""
        nodes = [*self.surface_nodes, *self.windows]
        return {(a, b) for i, a in enumerate(nodes) for b in nodes[i + 1:]
                if b in self.ip_peers(a, t)}

    def ip_peers(self, node: str, t: float) -> set[str]:
        """The nodes ``node`` reaches over IP at ``t`` (none while it is under water)."""
        if node in self.surface_nodes:
            return {v for v in self.windows if self.surfaced(v, t)}
        if not self.surfaced(node, t):
            return set()
        return {*self.surface_nodes, *(v for v in self.windows
                                       if v != node and self.surfaced(v, t))}


def surface_script(loaded: LoadedMission, start: float = 0.0) -> SurfaceScript | None:
    """The mission's scripted surfacings (None when no vehicle's path reaches the surface, or
    the mission has no ``surfacing`` section: nobody would switch to IP)."""
    mission = loaded.mission
    if mission.surfacing is None:
        return None
    windows: dict[str, tuple[Window, ...]] = {}
    periods: dict[str, float] = {}
    for name, node in mission.nodes.items():
        if node.role == "surface" or node.path is None:
            continue
        path = Path.from_spec(node.path)
        if found := surface_windows(path):
            windows[name] = found
            if path.loop and path.duration_s > 0:
                periods[name] = path.duration_s
    if not windows:
        return None
    surface = tuple(n for n, node in mission.nodes.items() if node.role == "surface")
    return SurfaceScript(surface, windows, periods, start)
