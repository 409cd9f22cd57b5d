"""Modem presets: the timing and range figures of each simulated modem kind.

A :class:`Preset` is plain data. The rest of the bridge (``zab check``, the TDMA planner, the
simulated water) asks it two questions: how long does a frame of ``n`` bytes occupy the water
(:meth:`Preset.airtime`) and how long does sound take to cover ``d`` metres
(:meth:`Preset.propagation_s`).

Sources of the figures:

- ``evologics-s2c-im``: seed 000 (MORPH), section II-E: the ensonified signal lasts 160 ms for one
  user byte and 850 ms for a full 64 B message; the line through both points is
  ``0.149 s + 10.95 ms/byte``. S2C 18/34 modems are rated to about 3.5 km.
- ``micromodem-rate0``: WHOI Micro-Modem FH-FSK, 80 bps, 32 B frames. Each packet is preceded by
  a cycle-initialisation mini-packet and a preamble, a few seconds of fixed overhead.
- ``micromodem-rate1`` … ``micromodem-rate6``: the PSK rates, one preset each, whose
  ``frame_bytes`` is a whole packet of the rate (192, 192, 512, 512, 2048, 192 B: all its WHOI
  frames, which the emulated modem puts in the water as one transmission, as the modem sends
  one PSK packet behind one probe), the rate's nominal bit rate (libumutil; rate 6 takes rate
  2's, the same spreading [C]) and ~1 s of FM probe and header [C, reference 2.6].
- ``s2cr-burst`` and ``s100-rf``: seed 002 (UMCI), Table 3, the statistical models of the
  EvoLogics S2CR in burst mode and the WFS S100 RF modem (bit rate, intrinsic delay and jitter,
  propagation per metre, minimum and maximum distance).
- ``hippocampus-266``: seed 001 (µAUV ranging): the authors' small modem sending 15-byte packets
  at 266 bit/s, communicating over at least 150 m (section IV); no latency figures are given.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from bridge.mission.model import Mission

__all__ = ["MICROMODEM_PSK", "PRESETS", "Preset", "UnknownPresetError", "get_preset", "node_preset",
           "preset_problem"]

MICROMODEM_PSK: dict[int, tuple[int, float]] = {
    1: (192, 250.0), 2: (192, 500.0), 3: (512, 1200.0), 4: (512, 1300.0), 5: (2048, 5300.0),
    6: (192, 500.0),
}
"""Micro-Modem PSK rate -> (bytes of a whole packet, nominal bit/s): the rate table of
:mod:`bridge.modems.micromodem.rates`, kept here as plain data for the presets."""


@dataclass(frozen=True)
class Preset:
    """Timing, range and error figures of one modem kind.

    Times are in seconds, distances in metres. ``per_byte_s``, when set, replaces
    ``8 / bitrate_bps`` as the time per payload byte. ``intrinsic_delay_s`` and ``jitter_s`` are
    the mean and standard deviation of the modem's own latency before the signal enters the water.
    """

    name: str
    frame_bytes: int
    bitrate_bps: float
    overhead_s: float = 0.0
    per_byte_s: float | None = None
    intrinsic_delay_s: float = 0.0
    jitter_s: float = 0.0
    sound_speed_mps: float = 1500.0
    max_range_m: float = 1000.0
    min_range_m: float = 0.0
    ber: float = 0.0
    description: str = ""

    def __post_init__(self) -> None:
        if self.frame_bytes < 1:
            raise ValueError(f"preset {self.name!r}: frame_bytes must be >= 1")
        if self.bitrate_bps <= 0:
            raise ValueError(f"preset {self.name!r}: bitrate_bps must be > 0")
        if self.sound_speed_mps <= 0:
            raise ValueError(f"preset {self.name!r}: sound_speed_mps must be > 0")
        if min(self.overhead_s, self.intrinsic_delay_s, self.jitter_s) < 0:
            raise ValueError(f"preset {self.name!r}: times must be >= 0")
        if self.per_byte_s is not None and self.per_byte_s < 0:
            raise ValueError(f"preset {self.name!r}: per_byte_s must be >= 0")
        if not 0 <= self.min_range_m <= self.max_range_m:
            raise ValueError(f"preset {self.name!r}: need 0 <= min_range_m <= max_range_m")
        if not 0 <= self.ber < 1:
            raise ValueError(f"preset {self.name!r}: ber must be in [0, 1)")

    @property
    def byte_time_s(self) -> float:
        """Seconds per payload byte."""
        return self.per_byte_s if self.per_byte_s is not None else 8.0 / self.bitrate_bps

    @property
    def propagation_s_per_m(self) -> float:
        """Seconds of travel per metre of range."""
        return 1.0 / self.sound_speed_mps

    def airtime(self, n_bytes: int) -> float:
        """Seconds a frame of ``n_bytes`` payload bytes occupies the water."""
        if n_bytes < 0:
            raise ValueError("n_bytes must be >= 0")
        return self.overhead_s + n_bytes * self.byte_time_s

    def propagation_s(self, distance_m: float) -> float:
        """Travel time over ``distance_m`` metres."""
        return distance_m / self.sound_speed_mps

    def frame_time_s(self, n_bytes: int, distance_m: float, jitter_sigmas: float = 3.0) -> float:
        """Worst-case seconds from ``send`` to the end of reception at ``distance_m``.

        Intrinsic delay plus ``jitter_sigmas`` standard deviations of jitter, airtime and
        propagation: what a TDMA slot must leave for one frame.
        """
        latency = self.intrinsic_delay_s + jitter_sigmas * self.jitter_s
        return latency + self.airtime(n_bytes) + self.propagation_s(distance_m)

    def replace(self, **changes: object) -> Preset:
        """A copy with some fields changed (e.g. a faster clone for tests)."""
        return dataclasses.replace(self, **changes)  # type: ignore[arg-type]


PRESETS: dict[str, Preset] = {
    p.name: p
    for p in (
        Preset(
            name="evologics-s2c-im",
            frame_bytes=64,
            bitrate_bps=976.0,
            overhead_s=0.149,
            per_byte_s=0.01095,
            sound_speed_mps=1500.0,
            max_range_m=3500.0,
            description="EvoLogics S2C 18/34 instant messages (160 ms @1 B, 850 ms @64 B)",
        ),
        Preset(
            name="micromodem-rate0",
            frame_bytes=32,
            bitrate_bps=80.0,
            overhead_s=3.0,
            sound_speed_mps=1500.0,
            max_range_m=5000.0,
            description="WHOI Micro-Modem rate 0, FH-FSK 80 bps, cycle-init + preamble overhead",
        ),
        *(
            Preset(
                name=f"micromodem-rate{rate}",
                frame_bytes=packet,
                bitrate_bps=bps,
                overhead_s=1.0,
                sound_speed_mps=1500.0,
                max_range_m=5000.0,
                description=f"WHOI Micro-Modem rate {rate}, PSK {bps:g} bps, {packet} B packets "
                "behind an FM probe and header",
            )
            for rate, (packet, bps) in MICROMODEM_PSK.items()
        ),
        Preset(
            name="s2cr-burst",
            frame_bytes=64,
            bitrate_bps=1620.0,
            intrinsic_delay_s=0.443,
            jitter_s=0.41299,
            sound_speed_mps=1.0 / 0.67e-3,
            max_range_m=3500.0,
            min_range_m=0.0,
            description="EvoLogics S2CR burst mode, seed 002 Table 3",
        ),
        Preset(
            name="s100-rf",
            frame_bytes=128,
            bitrate_bps=1900.0,
            intrinsic_delay_s=0.085,
            jitter_s=0.0132,
            sound_speed_mps=1.0 / 3.3e-12,
            max_range_m=5.0,
            min_range_m=0.5,
            description="WFS S100 underwater RF modem, seed 002 Table 3 (propagation ~ instant)",
        ),
        Preset(
            name="hippocampus-266",
            frame_bytes=15,
            bitrate_bps=266.0,
            sound_speed_mps=1500.0,
            max_range_m=150.0,
            description="seed 001's µAUV modem: 15 B packets at 266 bit/s, 150 m",
        ),
    )
}


class UnknownPresetError(KeyError):
    """No preset of that name; the message lists the known ones."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else "unknown preset"


def get_preset(name: str) -> Preset:
    """The preset called ``name``; :class:`UnknownPresetError` (a ``KeyError``) lists the rest."""
    problem = preset_problem(name)
    if problem is not None:
        raise UnknownPresetError(problem)
    return PRESETS[name]


def preset_problem(name: object) -> str | None:
    """What is wrong with ``name`` as the name of a preset, listing the known ones (None: it
    names one). A mission's ``preset`` option is checked with it at load."""
    if isinstance(name, str) and name in PRESETS:
        return None
    return f"unknown modem preset {name!r}; known presets: {', '.join(sorted(PRESETS))}"


def node_preset(mission: Mission, node: str) -> Preset | None:
    """The modem preset that gives ``node`` known timings, if any."""
    name = mission.node_modem(node).options.get("preset")
    if not isinstance(name, str):
        return None
    try:
        return get_preset(name)
    except UnknownPresetError:
        return None
