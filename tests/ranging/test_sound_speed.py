"""Sound-speed equations against their published check values and each other."""

from __future__ import annotations

import math

import pytest

from bridge.ranging.sound_speed import (
    SoundSpeed,
    check_validity,
    coppens,
    depth_to_pressure,
    mackenzie,
    pressure_to_depth,
    sound_speed,
    unesco,
)


def test_unesco_check_value() -> None:
    # Fofonoff & Millard (1983): SVEL = 1731.995 m/s at S = 40, T = 40 °C, P = 10000 dbar
    assert unesco(40.0, 40.0, 10000.0) == pytest.approx(1731.995, abs=5e-4)


def test_unesco_surface_values() -> None:
    # Chen & Millero (1977) at the surface: 1449.14 m/s for S = 35, T = 0; pure water 20 °C
    assert unesco(0.0, 35.0, 0.0) == pytest.approx(1449.14, abs=0.01)
    assert unesco(20.0, 0.0, 0.0) == pytest.approx(1482.34, abs=0.01)


def test_mackenzie_check_value() -> None:
    # Mackenzie (1981): 1550.744 m/s at T = 25 °C, S = 35, D = 1000 m
    assert mackenzie(25.0, 35.0, 1000.0) == pytest.approx(1550.744, abs=5e-4)


def test_depth_check_value_and_inverse() -> None:
    # Fofonoff & Millard (1983): 9712.653 m at 10000 dbar, latitude 30°
    assert pressure_to_depth(10000.0, 30.0) == pytest.approx(9712.653, abs=1e-3)
    for depth in (0.0, 0.9, 10.0, 1000.0, 5000.0, 10000.0):
        p = depth_to_pressure(depth, 30.0)
        assert pressure_to_depth(p, 30.0) == pytest.approx(depth, abs=1e-6)
        # Saunders (1981) closed form, an independent approximation
        c1 = (5.92 + 5.25 * math.sin(math.radians(30.0)) ** 2) * 1e-3
        saunders = ((1 - c1) - math.sqrt((1 - c1) ** 2 - 8.84e-6 * depth)) / 4.42e-6
        assert p == pytest.approx(saunders, rel=1e-3, abs=0.01)
    assert depth_to_pressure(1000.0, 30.0) == pytest.approx(1009.3, abs=0.1)


@pytest.mark.parametrize(("depth", "tol"), [(0.0, 0.35), (20.0, 0.35), (100.0, 0.4), (1000.0, 1.0)])
def test_equations_agree_in_sea_water(depth: float, tol: float) -> None:
    worst_coppens = worst_unesco = 0.0
    for t in range(2, 31, 2):
        for s in range(30, 41):
            ref = mackenzie(t, s, depth)
            worst_coppens = max(worst_coppens, abs(coppens(t, s, depth) - ref))
            worst_unesco = max(worst_unesco, abs(unesco(t, s, depth_to_pressure(depth)) - ref))
    assert worst_coppens <= tol
    assert worst_unesco <= tol


def test_coppens_near_mackenzie_check_point() -> None:
    assert coppens(25.0, 35.0, 1000.0) == pytest.approx(1550.744, abs=0.5)


def test_fresh_water_coppens_matches_unesco() -> None:
    # Mackenzie is not fitted below S = 25; Coppens and UNESCO cover fresh water
    for t in (4.0, 10.0, 20.0, 25.0):
        assert coppens(t, 0.0, 1.0) == pytest.approx(
            unesco(t, 0.0, depth_to_pressure(1.0)), abs=1.5
        )
    assert not check_validity("mackenzie", 10.0, 0.0, 1.0)
    assert check_validity("coppens", 10.0, 0.0, 1.0)
    assert check_validity("unesco", 10.0, 0.0, 1.0)
    assert not check_validity("unesco", 45.0, 35.0, 0.0)


def test_sound_speed_dispatch() -> None:
    assert sound_speed(25, 35, 1000, "mackenzie") == mackenzie(25, 35, 1000)
    assert sound_speed(25, 35, 1000, "coppens") == coppens(25, 35, 1000)
    assert sound_speed(25, 35, 1000, "unesco", 30.0) == unesco(25, 35, depth_to_pressure(1000, 30))
    with pytest.raises(ValueError, match="unknown sound-speed equation"):
        sound_speed(25, 35, 1000, "delgrosso")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="non-finite"):
        sound_speed(math.nan, 35, 10)


def test_sound_speed_helper() -> None:
    fixed = SoundSpeed.fixed(1500)
    assert (fixed.mps, fixed.source) == (1500.0, "fixed")
    ctd = SoundSpeed.from_ctd(15.0, 35.0, 10.0, "mackenzie")
    assert ctd.mps == pytest.approx(mackenzie(15.0, 35.0, 10.0))
    assert ctd.source == "mackenzie"
    mean = SoundSpeed.mean_of(SoundSpeed.fixed(1480.0), 1500.0)
    assert (mean.mps, mean.source) == (1490.0, "mean")
    assert fixed.distance(0.02) == pytest.approx(30.0)
    with pytest.raises(ValueError, match="implausible"):
        SoundSpeed.fixed(340.0)
