"""The simulated water of a mission, set up in one place for every runtime (pure).

``zab sim`` and ``zab water`` serve it to their nodes (:class:`~bridge.sim.service.
WaterService`); ``zab sim --fast`` runs it on the virtual clock (:class:`~bridge.sim.ocean.
Ocean`). Both take the same preset, seed, loss, static positions and scripted paths from here.
"""

from __future__ import annotations

from dataclasses import dataclass

from bridge.core.positioning import simulated_preset
from bridge.mission.loader import LoadedMission
from bridge.mission.path import Path
from bridge.modems.presets import Preset
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
    ``loss`` (else ``modem.options.loss``, else 0), static positions and paths."""
    mission = loaded.mission
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
