"""The mission's timing maths, from the modem presets (pure): how long a node's frames keep
its modem busy and take to arrive, and how far apart nodes can be."""

from __future__ import annotations

import math

from bridge.mission.model import Mission
from bridge.mission.presets import Preset, node_preset

__all__ = ["busy_s", "frame_time_s", "max_distance_m", "node_preset"]


def max_distance_m(mission: Mission, preset: Preset) -> float:
    """Farthest two places nodes can be (positions and scripted waypoints), or the modem's
    maximum range when a node has neither."""
    places: list[list[tuple[float, float, float]]] = []
    for node in mission.nodes.values():
        spots = [node.position] if node.position else []
        spots += node.path.waypoints if node.path else []
        places.append([(p.x, p.y, p.depth) for p in spots])
    if len(places) < 2 or not all(places):
        return preset.max_range_m
    return min(preset.max_range_m, max(
        math.dist(a, b) for i, mine in enumerate(places) for theirs in places[i + 1:]
        for a in mine for b in theirs))


def busy_s(mission: Mission, node: str) -> float | None:
    """How long ``node``'s modem is busy with its largest frame: latency + airtime."""
    preset = node_preset(mission, node)
    if preset is None:
        return None
    size = min(mission.node_modem(node).frame_bytes, preset.frame_bytes)
    return preset.intrinsic_delay_s + preset.airtime(size)


def frame_time_s(mission: Mission, node: str) -> float | None:
    """Worst-case send-to-reception-end time of ``node``'s largest frame (None: no preset)."""
    preset = node_preset(mission, node)
    if preset is None:
        return None
    size = min(mission.node_modem(node).frame_bytes, preset.frame_bytes)
    return preset.frame_time_s(size, max_distance_m(mission, preset))
