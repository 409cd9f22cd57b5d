"""The simulated ocean: modem presets and the pure channel model.

Only the pure parts are re-exported here; the asyncio server lives in
:mod:`bridge.sim.service` and its wire format in :mod:`bridge.sim.protocol`.
"""

from bridge.mission.presets import PRESETS, Preset, UnknownPresetError, get_preset
from bridge.sim.ocean import (
    LOSS_REASONS,
    Delivery,
    Event,
    LinkStats,
    Loss,
    LossCurve,
    Ocean,
    Position,
    TransmitRefused,
    TxDone,
)

__all__ = [
    "LOSS_REASONS",
    "PRESETS",
    "Delivery",
    "Event",
    "LinkStats",
    "Loss",
    "LossCurve",
    "Ocean",
    "Position",
    "Preset",
    "TransmitRefused",
    "TxDone",
    "UnknownPresetError",
    "get_preset",
]
