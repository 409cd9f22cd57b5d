"""Ranging and localisation maths, pure and clock-free (issue #5).

- :mod:`~bridge.ranging.sound_speed`: UNESCO (Chen–Millero), Mackenzie, Coppens equations.
- :mod:`~bridge.ranging.dlbl`: DLBL delay vectors and two-way travel times (seed 000).
- :mod:`~bridge.ranging.twr`: explicit two-way ranging and scheduled anchor replies (seed 001).
- :mod:`~bridge.ranging.localise`: circle intersection and least squares fixes (seed 001).
- :mod:`~bridge.ranging.track`: a constant-velocity filter for a moving node.
"""

from bridge.ranging.dlbl import DlblRanger, Range, two_sided
from bridge.ranging.localise import (
    NO_FIX_REASONS,
    Fix,
    NoFix,
    attempt,
    dop,
    horizontal_range,
    intersect_circles,
    locate,
)
from bridge.ranging.sound_speed import (
    VALIDITY,
    SoundSpeed,
    check_validity,
    coppens,
    depth_to_pressure,
    mackenzie,
    pressure_to_depth,
    sound_speed,
    unesco,
)
from bridge.ranging.track import Track
from bridge.ranging.twr import (
    AnchorReplier,
    RangingRound,
    reply_slot,
    round_timeout,
    tmax,
    travel_time,
)

__all__ = [
    "NO_FIX_REASONS",
    "VALIDITY",
    "AnchorReplier",
    "DlblRanger",
    "Fix",
    "NoFix",
    "Range",
    "RangingRound",
    "SoundSpeed",
    "Track",
    "attempt",
    "check_validity",
    "coppens",
    "depth_to_pressure",
    "dop",
    "horizontal_range",
    "intersect_circles",
    "locate",
    "mackenzie",
    "pressure_to_depth",
    "reply_slot",
    "round_timeout",
    "sound_speed",
    "tmax",
    "travel_time",
    "two_sided",
    "unesco",
]
