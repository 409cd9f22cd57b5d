"""The MAC section of the mission file: models, loader errors, computed times, zab check."""

from __future__ import annotations

import pytest
import yaml

from bridge.core.loaded import LoadedMission, load_mission, parse_mission
from bridge.core.mac import (
    AlohaSchedule,
    FreeSchedule,
    PolledSchedule,
    RangingSchedule,
    schedule_for,
)
from bridge.errors import MissionError
from bridge.mission.presets import get_preset
from bridge.report.check import check_mission
from tests.conftest import MISSIONS

BASE = """\
mission: m
modem: {backend: sim, frame_bytes: 32, options: {preset: s100-rf}}
nodes:
  top: {address: 1, role: surface, position: {x: 0, y: 0, depth: 0}}
  rov1: {address: 2, position: {x: 3, y: 0, depth: 0}}
  rov2: {address: 3, position: {x: 0, y: 4, depth: 0}}
channels:
  - name: nav
    from: "rov[12]"
    to: top
    elements: [{in: nav, out: "{src}/nav", fields: [{field: x, bits: 16, min: 0, max: 1}]}]
"""


def with_mac(mac: dict, text: str = BASE) -> LoadedMission:
    data = yaml.safe_load(text)
    data["mac"] = mac
    return parse_mission(yaml.safe_dump(data, sort_keys=False), "m.yaml")


def mac_error(mac: dict, text: str = BASE) -> str:
    with pytest.raises(MissionError) as info:
        with_mac(mac, text)
    return str(info.value)


def test_polled_ipg_computed_from_the_preset() -> None:
    loaded = with_mac({"type": "polled", "master": "top", "guard_s": 0.05})
    rf = get_preset("s100-rf")
    frame = rf.intrinsic_delay_s + 3 * rf.jitter_s + rf.airtime(32) + rf.propagation_s(5.0)
    schedules = {n: schedule_for(loaded.mission, n) for n in ("top", "rov1", "rov2")}
    assert all(isinstance(s, PolledSchedule) for s in schedules.values())
    top = schedules["top"]
    assert isinstance(top, PolledSchedule)
    assert top.ipg_s == pytest.approx(2 * frame + 0.05)
    assert top.sequence == ("rov1", "rov2")


def test_polled_weights_interleave() -> None:
    loaded = with_mac({"type": "polled", "master": "top", "ipg_s": 1,
                       "weights": {"rov1": 2, "rov2": 1}})
    top = schedule_for(loaded.mission, "top")
    assert isinstance(top, PolledSchedule) and top.sequence == ("rov1", "rov2", "rov1")


@pytest.mark.parametrize(("mac", "where", "message"), [
    ({"type": "polled", "master": "boss"}, "mac.master", "unknown node 'boss'"),
    ({"type": "polled", "master": "top", "order": ["rov1", "top"]}, "mac.order[1]",
     "cannot poll itself"),
    ({"type": "polled", "master": "top", "weights": {"rov3": 1}}, "mac.weights.rov3",
     "unknown node 'rov3'"),
    ({"type": "polled", "master": "top", "order": ["rov1"], "weights": {"rov1": 1}}, "mac",
     "either order or weights"),
    ({"type": "polled", "master": "top", "ipg_s": 0}, "mac.ipg_s", "greater than 0"),
    ({"type": "aloha", "max_airtime_share": 1.5}, "mac.max_airtime_share", "less than or equal"),
    ({"type": "aloha", "ranging": {"requester": "rov1", "anchors": ["top", "rov1"],
                                   "interval_s": 3}}, "mac.ranging.anchors[1]",
     "cannot answer itself"),
    ({"type": "none", "ranging": {"requester": "rov9", "anchors": ["top"], "interval_s": 3}},
     "mac.ranging.requester", "unknown node 'rov9'"),
])
def test_mac_mistakes_are_located(mac: dict, where: str, message: str) -> None:
    text = mac_error(mac)
    assert f": {where}: " in text and message in text
    assert "m.yaml:" in text


def test_times_without_a_preset_must_be_given() -> None:
    udp = BASE.replace("backend: sim, frame_bytes: 32, options: {preset: s100-rf}",
                       "backend: udp, frame_bytes: 32")
    assert "mac.ipg_s: required" in mac_error({"type": "polled", "master": "top"}, udp)
    assert "mac.slot_s: required" in mac_error({"type": "aloha", "slotted": True}, udp)
    assert "mac.ranging.tmax_s: required" in mac_error(
        {"type": "none", "ranging": {"requester": "rov1", "anchors": ["top"], "interval_s": 3}},
        udp)
    loaded = with_mac({"type": "polled", "master": "top", "ipg_s": 2.0}, udp)
    assert schedule_for(loaded.mission, "rov1").worst_gap_s() == 4.0  # type: ignore[attr-defined]


def test_aloha_and_ranging_schedules() -> None:
    aloha = with_mac({"type": "aloha", "slotted": True, "backoff_s": 1})
    sched = schedule_for(aloha.mission, "rov1")
    assert isinstance(sched, AlohaSchedule) and sched.slot_s is not None
    ranged = with_mac({"type": "none", "ranging": {"requester": "rov1", "anchors": ["top"],
                                                   "interval_s": 3}})
    wrapped = schedule_for(ranged.mission, "top")
    assert isinstance(wrapped, RangingSchedule) and isinstance(wrapped.inner, FreeSchedule)


def test_check_warns_when_the_ipg_is_too_short_or_aloha_crowded() -> None:
    report = check_mission(with_mac({"type": "polled", "master": "top", "ipg_s": 0.2}))
    assert any("ipg_s 0.200 s is shorter" in w for w in report.warnings)
    timing = report.data["mac_timing"]
    assert timing["ipg_s"] == 0.2 and timing["needed_ipg_s"] > 0.2
    nodes = {n["name"]: n["mac"] for n in report.data["nodes"]}
    assert nodes["top"]["worst_interval_s"] == 0.2 and nodes["top"]["note"] == "master"
    assert nodes["rov1"]["worst_interval_s"] == 0.4
    crowded = check_mission(with_mac({"type": "aloha"}))
    assert any("pure ALOHA delivers at most" in w for w in crowded.warnings)
    capped = check_mission(with_mac({"type": "aloha", "max_airtime_share": 0.02}))
    assert not any("ALOHA" in w for w in capped.warnings)
    shares = [n["mac"]["airtime_share"] for n in capped.data["nodes"]]
    assert all(s is not None and s <= 0.02 for s in shares)


def test_shipped_missions_check_clean() -> None:
    bluerov = check_mission(load_mission(MISSIONS / "bluerov_rf.yaml"))
    assert bluerov.ok and not bluerov.warnings
    timing = bluerov.data["mac_timing"]
    assert timing["ipg_s"] == 0.64 and timing["needed_ipg_s"] < 0.64
    hippo = load_mission(MISSIONS / "hippocampus.yaml")
    report = check_mission(hippo)
    assert report.ok and not report.warnings
    # seed 001 eq. 6 with the slowest sound (1400 m/s) over the longest distance, 15 B at 266
    assert report.data["mac_timing"]["ranging_tmax_s"] == pytest.approx(
        36.4 / 1400 + 15 * 8 / 266, abs=0.005)
    assert isinstance(schedule_for(hippo.mission, "hippo"), RangingSchedule)


def test_zab_check_prints_the_mac_report() -> None:
    from typer.testing import CliRunner

    from bridge.cli.app import app

    result = CliRunner().invoke(app, ["check", str(MISSIONS / "bluerov_rf.yaml")])
    assert result.exit_code == 0, result.output
    assert "mac polled: ipg_s 0.64" in result.output and "sequence rov" in result.output
    assert "worst interval" in result.output and "0.640 s" in result.output
    hippo = CliRunner().invoke(app, ["check", str(MISSIONS / "hippocampus.yaml")])
    assert "ranging requester" in hippo.output and "ranging anchor" in hippo.output
