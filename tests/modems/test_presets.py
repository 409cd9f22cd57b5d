"""Preset arithmetic and lookup."""

from __future__ import annotations

import pytest

from bridge.mission.presets import PRESETS, Preset, UnknownPresetError, get_preset


def test_evologics_matches_seed_000_timing() -> None:
    p = get_preset("evologics-s2c-im")
    assert p.frame_bytes == 64
    assert p.airtime(1) == pytest.approx(0.160, abs=0.005)
    assert p.airtime(64) == pytest.approx(0.850, abs=0.005)
    assert p.propagation_s(1500.0) == pytest.approx(1.0)


def test_micromodem_rate0_is_slow() -> None:
    p = get_preset("micromodem-rate0")
    assert p.frame_bytes == 32
    assert p.airtime(32) == pytest.approx(p.overhead_s + 3.2)
    assert p.airtime(32) > 5.0


def test_table3_presets() -> None:
    burst, rf = get_preset("s2cr-burst"), get_preset("s100-rf")
    assert burst.airtime(162) == pytest.approx(0.8)
    assert burst.propagation_s(1000.0) == pytest.approx(0.67)
    assert (burst.intrinsic_delay_s, burst.jitter_s) == (0.443, pytest.approx(0.41299))
    assert (burst.max_range_m, burst.min_range_m) == (3500.0, 0.0)
    assert rf.airtime(190) == pytest.approx(0.8)
    assert rf.propagation_s(5.0) < 1e-9
    assert (rf.max_range_m, rf.min_range_m) == (5.0, 0.5)


def test_every_preset_is_consistent() -> None:
    for name, p in PRESETS.items():
        assert p.name == name
        assert p.airtime(p.frame_bytes) > p.airtime(1) > 0


def test_unknown_preset_lists_known_names() -> None:
    with pytest.raises(KeyError) as info:
        get_preset("nope")
    assert isinstance(info.value, UnknownPresetError)
    assert "evologics-s2c-im" in str(info.value) and "'nope'" in str(info.value)


def test_invalid_preset_rejected() -> None:
    with pytest.raises(ValueError):
        Preset(name="bad", frame_bytes=0, bitrate_bps=100.0)
    with pytest.raises(ValueError):
        Preset(name="bad", frame_bytes=8, bitrate_bps=100.0, min_range_m=5, max_range_m=1)


def test_frame_time_includes_latency_and_jitter() -> None:
    burst = get_preset("s2cr-burst")
    expected = 0.443 + 3 * 0.41299 + burst.airtime(10) + 0.67
    assert burst.frame_time_s(10, 1000.0) == pytest.approx(expected)
    evo = get_preset("evologics-s2c-im")
    assert evo.frame_time_s(64, 1500.0) == pytest.approx(evo.airtime(64) + 1.0)
