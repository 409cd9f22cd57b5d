"""Speed of sound in sea water, pure: Mackenzie, Coppens and UNESCO (Chen–Millero).

All three take temperature in °C, salinity in PSU (practical salinity) and depth in metres, or
pressure in decibars for UNESCO. They compute outside their validity ranges (listed in
:data:`VALIDITY` and each docstring) without complaint; :func:`check_validity` says whether an
input is inside. Fresh water (S = 0) is inside only for Coppens and UNESCO.

Each equation is checked in ``tests/ranging/test_sound_speed.py`` against the check value its
source publishes (Mackenzie: 1550.744 m/s; UNESCO: 1731.995 m/s; the depth formula: 9712.653 m),
and Coppens against Mackenzie and UNESCO over typical sea water.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

Equation = Literal["unesco", "mackenzie", "coppens"]

#: (temperature °C, salinity PSU, depth m or pressure dbar) ranges each equation was fitted on.
VALIDITY: dict[str, tuple[tuple[float, float], tuple[float, float], tuple[float, float]]] = {
    "mackenzie": ((2.0, 30.0), (25.0, 40.0), (0.0, 8000.0)),  # depth m
    "coppens": ((0.0, 35.0), (0.0, 45.0), (0.0, 4000.0)),  # depth m
    "unesco": ((0.0, 40.0), (0.0, 40.0), (0.0, 10000.0)),  # pressure dbar
}


def check_validity(equation: Equation, t_c: float, s_psu: float, z: float) -> bool:
    """Whether ``(t_c, s_psu, z)`` is in ``equation``'s fitted range (z: m; dbar for UNESCO)."""
    (t0, t1), (s0, s1), (z0, z1) = VALIDITY[equation]
    return t0 <= t_c <= t1 and s0 <= s_psu <= s1 and z0 <= z <= z1


def mackenzie(t_c: float, s_psu: float, depth_m: float) -> float:
    """Mackenzie (1981), nine-term equation, m/s.

    K. V. Mackenzie, "Nine-term equation for sound speed in the oceans", J. Acoust. Soc. Am.
    70(3), 807–812 (1981). Valid for T 2–30 °C, S 25–40, depth 0–8000 m; standard error
    0.070 m/s. Check value: 1550.744 m/s at T = 25 °C, S = 35, D = 1000 m.
    """
    t, ds, d = t_c, s_psu - 35.0, depth_m
    return (
        1448.96
        + 4.591 * t
        - 5.304e-2 * t**2
        + 2.374e-4 * t**3
        + 1.340 * ds
        + 1.630e-2 * d
        + 1.675e-7 * d**2
        - 1.025e-2 * t * ds
        - 7.139e-13 * t * d**3
    )


def coppens(t_c: float, s_psu: float, depth_m: float) -> float:
    """Coppens (1981), m/s.

    A. B. Coppens, "Simple equations for the speed of sound in Neptunian waters", J. Acoust.
    Soc. Am. 69(3), 862–863 (1981). With t = T/10 and D the depth in km::

        c(0,S,t) = 1449.05 + 45.7t − 5.21t² + 0.23t³ + (1.333 − 0.126t + 0.009t²)(S − 35)
        c(D,S,t) = c(0,S,t) + (16.23 + 0.253t)D + (0.213 − 0.1t)D²
                   + [0.016 + 0.0002(S − 35)](S − 35)tD

    Valid for T 0–35 °C, S 0–45, depth 0–4000 m; agrees with Mackenzie within about 0.5 m/s in
    sea water (no published check value; cross-checked in the tests).
    """
    t, ds, d = t_c / 10.0, s_psu - 35.0, depth_m / 1000.0
    c0 = 1449.05 + 45.7 * t - 5.21 * t**2 + 0.23 * t**3 + (1.333 - 0.126 * t + 0.009 * t**2) * ds
    return (
        c0 + (16.23 + 0.253 * t) * d + (0.213 - 0.1 * t) * d**2 + (0.016 + 0.0002 * ds) * ds * t * d
    )


def unesco(t_c: float, s_psu: float, pressure_dbar: float) -> float:
    """UNESCO (1983) sound speed: Chen and Millero (1977) as given by Fofonoff and Millard, m/s.

    C.-T. Chen and F. J. Millero, "Speed of sound in seawater at high pressures", J. Acoust.
    Soc. Am. 62(5), 1129–1135 (1977); N. P. Fofonoff and R. C. Millard, "Algorithms for
    computation of fundamental properties of seawater", UNESCO Tech. Pap. Mar. Sci. 44 (1983).
    Valid for T 0–40 °C, S 0–40, pressure 0–10000 dbar (gauge: 0 at the surface). Temperature is
    IPTS-68 as in the source; ITS-90 differs by < 0.01 °C here (< 0.03 m/s), negligible for
    ranging. Check value: 1731.995 m/s at S = 40, T = 40 °C, P = 10000 dbar. Use
    :func:`depth_to_pressure` to go from depth.
    """
    t, s, p = t_c, s_psu, pressure_dbar / 10.0  # the polynomial is in bars
    sr = math.sqrt(abs(s))
    # S² term
    d = 1.727e-3 - 7.9836e-6 * p
    # S^(3/2) term
    b1 = 7.3637e-5 + 1.7945e-7 * t
    b0 = -1.922e-2 - 4.42e-5 * t
    b = b0 + b1 * p
    # S¹ term
    a3 = (-3.389e-13 * t + 6.649e-12) * t + 1.100e-10
    a2 = ((7.988e-12 * t - 1.6002e-10) * t + 9.1041e-9) * t - 3.9064e-7
    a1 = (((-2.0122e-10 * t + 1.0507e-8) * t - 6.4885e-8) * t - 1.2580e-5) * t + 9.4742e-5
    a0 = (((-3.21e-8 * t + 2.006e-6) * t + 7.164e-5) * t - 1.262e-2) * t + 1.389
    a = ((a3 * p + a2) * p + a1) * p + a0
    # S⁰ term (pure water)
    c3 = (-2.3643e-12 * t + 3.8504e-10) * t - 9.7729e-9
    c2 = (((1.0405e-12 * t - 2.5335e-10) * t + 2.5974e-8) * t - 1.7107e-6) * t + 3.1260e-5
    c1 = (((-6.1185e-10 * t + 1.3621e-7) * t - 8.1788e-6) * t + 6.8982e-4) * t + 0.153563
    c0 = (
        (((3.1464e-9 * t - 1.47800e-6) * t + 3.3420e-4) * t - 5.80852e-2) * t + 5.03711
    ) * t + 1402.388
    c = ((c3 * p + c2) * p + c1) * p + c0
    return c + (a + b * sr + d * s) * s


def pressure_to_depth(pressure_dbar: float, lat_deg: float = 45.0) -> float:
    """Depth in metres from pressure in dbar (Fofonoff and Millard 1983, ``DEPTH``).

    Uses the 1980 equation of state for a standard ocean (S = 35, T = 0 °C) and the 1970
    gravity formula. Check value: 9712.653 m at 10000 dbar, latitude 30°.
    """
    x = math.sin(math.radians(lat_deg)) ** 2
    gr = 9.780318 * (1.0 + (5.2788e-3 + 2.36e-5 * x) * x) + 1.092e-6 * pressure_dbar
    p = pressure_dbar
    return (((-1.82e-15 * p + 2.279e-10) * p - 2.2512e-5) * p + 9.72659) * p / gr


def depth_to_pressure(depth_m: float, lat_deg: float = 45.0) -> float:
    """Pressure in dbar at ``depth_m``: :func:`pressure_to_depth` inverted by Newton's method.

    Exact to 1e-6 dbar against the UNESCO depth formula (Saunders' 1981 closed form agrees
    within 0.1 % over 0–10000 m). About 1.0 dbar per metre near the surface.
    """
    p = depth_m * 1.01  # first guess
    for _ in range(20):
        f = pressure_to_depth(p, lat_deg) - depth_m
        h = 1e-3
        slope = (pressure_to_depth(p + h, lat_deg) - pressure_to_depth(p - h, lat_deg)) / (2 * h)
        step = f / slope
        p -= step
        if abs(step) < 1e-9:
            break
    return p


def sound_speed(
    t_c: float, s_psu: float, depth_m: float, equation: Equation = "unesco", lat_deg: float = 45.0
) -> float:
    """Sound speed in m/s from temperature, salinity and depth with the chosen equation."""
    if not all(math.isfinite(v) for v in (t_c, s_psu, depth_m)):
        raise ValueError(f"non-finite CTD input: T={t_c}, S={s_psu}, depth={depth_m}")
    if equation == "unesco":
        return unesco(t_c, s_psu, depth_to_pressure(max(depth_m, 0.0), lat_deg))
    if equation == "mackenzie":
        return mackenzie(t_c, s_psu, depth_m)
    if equation == "coppens":
        return coppens(t_c, s_psu, depth_m)
    raise ValueError(f"unknown sound-speed equation {equation!r} (unesco, mackenzie, coppens)")


@dataclass(frozen=True)
class SoundSpeed:
    """A sound speed for ranging, with where it came from.

    Build one with :meth:`fixed` (the mission's value) or :meth:`from_ctd` (live temperature,
    salinity, depth), and :meth:`mean_of` for the mean of both ends of a link (seed 001: a
    quick remedy when the two ends see different water, assuming a linear gradient).
    """

    mps: float
    source: str = "fixed"

    def __post_init__(self) -> None:
        if not (math.isfinite(self.mps) and 1300.0 <= self.mps <= 1800.0):
            raise ValueError(f"implausible sound speed {self.mps} m/s (expected 1300–1800)")

    @classmethod
    def fixed(cls, mps: float) -> SoundSpeed:
        """A constant sound speed (from the mission file)."""
        return cls(float(mps), "fixed")

    @classmethod
    def from_ctd(
        cls,
        t_c: float,
        s_psu: float,
        depth_m: float,
        equation: Equation = "unesco",
        lat_deg: float = 45.0,
    ) -> SoundSpeed:
        """The sound speed from a CTD reading with ``equation``."""
        return cls(sound_speed(t_c, s_psu, depth_m, equation, lat_deg), equation)

    @staticmethod
    def mean_of(a: SoundSpeed | float, b: SoundSpeed | float) -> SoundSpeed:
        """The mean of the sound speeds at both ends of a link."""
        va = a.mps if isinstance(a, SoundSpeed) else float(a)
        vb = b.mps if isinstance(b, SoundSpeed) else float(b)
        return SoundSpeed((va + vb) / 2.0, "mean")

    def distance(self, travel_time_s: float) -> float:
        """One-way travel time to metres: ``d = c·Tw``."""
        return self.mps * travel_time_s
