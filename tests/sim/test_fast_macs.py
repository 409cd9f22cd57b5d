"""Polled, ALOHA and ranging fleets on the virtual clock: every node's core, the pure ocean."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from bridge.cli.app import app
from bridge.cli.sim_fast import run_fast
from bridge.core.events import FrameSent
from bridge.core.loaded import load_mission, parse_mission
from bridge.core.mac import PolledSchedule
from bridge.core.node import Status
from bridge.runtime.virtual_fleet import FastFleet, Timed
from tests.conftest import MISSIONS

BLUEROV = MISSIONS / "bluerov_rf.yaml"
COMMAND = {"oid": False, "clo": False, "order_type": 0, "eisn": False, "ic": False, "rit": 0,
           "vx": 0.5, "vy": 0.0, "vz": 0.0, "yaw_rate": 0.0, "arm": True,
           "hold_heading": False, "nav_mode": "manual", "lights": 10, "camera_tilt": 0.0,
           "gain": 1.0}
STATUS = {"st": 1, "ready": True, "eoid": False, "loc": False, "hold_heading": False,
          "armed": True, "nav_mode": "manual", "x": 1.0, "y": 2.0, "z": 1.0, "roll": 0.0,
          "pitch": 0.0, "yaw": 45.0}


def frames(fleet_outputs: list[Timed], node: str) -> list[Timed]:
    """The frames ``node`` sent."""
    return [t for t in fleet_outputs if t.node == node and isinstance(t.output, FrameSent)]


def test_polled_teleoperation_one_frame_each_way_per_ipg() -> None:
    fleet = FastFleet(load_mission(BLUEROV), seed=4)
    fleet.put("operator", "rov/command", COMMAND)
    fleet.put("rov", "rov/status", STATUS)
    fleet.put("rov", "rov/image_trunk", {"ft": True, "lt": False, "isn": False, "ci": False,
                                         "itsn": 3, "trunk": bytes(41)})
    fleet.run_until(64.1)
    polls = frames(fleet.outputs, "operator")
    replies = frames(fleet.outputs, "rov")
    assert len(polls) == 101  # t = 0, 0.64, ..., 64
    assert all(p.output.size == 16 and p.output.dest == "rov" for p in polls)
    assert {r.output.size for r in replies} == {57}
    assert len(replies) >= 99  # one per poll heard; the last poll's reply is still on its way
    # a reply leaves when its poll has arrived: delay + airtime of 16 B later, never unpolled
    for reply in replies:
        poll = max(p.time for p in polls if p.time < reply.time)
        assert 0.1 < reply.time - poll < 0.25
    got = fleet.published("rov", "rov/command")
    assert len(got) >= 99 and got[-1][1].value["vx"] == pytest.approx(0.5, abs=1e-3)
    status = fleet.published("operator", "rov/status")
    assert len(status) >= 98 and status[0][1].value["yaw"] == pytest.approx(45.0, abs=0.5)
    assert len(fleet.published("operator", "rov/image_trunk")) >= 98


def test_slave_stays_silent_without_polls() -> None:
    fleet = FastFleet(load_mission(BLUEROV), seed=1)
    fleet.put("rov", "rov/status", STATUS)
    fleet.stop("operator")
    fleet.run_until(30.0)
    assert fleet.cores["rov"].stats.frames_sent == 0
    fleet.resume("operator")
    fleet.run_until(40.0)
    assert fleet.cores["rov"].stats.frames_sent >= 14


ALOHA = """\
mission: aloha
modem: {backend: sim, frame_bytes: 32, options: {preset: evologics-s2c-im}}
mac: {type: aloha, backoff_s: 2.0, max_airtime_share: 0.1}
nodes:
  buoy: {address: 1, role: surface, position: {x: 0, y: 0, depth: 1}}
  a1: {address: 2, position: {x: 300, y: 0, depth: 20}}
  a2: {address: 3, position: {x: 0, y: 400, depth: 30}}
  a3: {address: 4, position: {x: -200, y: 200, depth: 10}}
channels:
  - name: nav
    from: "a[123]"
    to: buoy
    latching: true
    elements: [{in: nav, out: "{src}/nav", fields: [{field: depth, resolution: 0.1, min: 0,
                                                     max: 100}]}]
"""


def test_aloha_fleet_delivers_within_its_airtime_cap() -> None:
    fleet = FastFleet(parse_mission(ALOHA, "aloha.yaml"), seed=2)
    for i, node in enumerate(("a1", "a2", "a3")):
        fleet.put(node, "nav", {"depth": 10.0 + i})
    fleet.run_until(600.0)
    for i, node in enumerate(("a1", "a2", "a3")):
        got = fleet.published("buoy", f"{node}/nav")
        assert len(got) > 20 and got[-1][1].value["depth"] == pytest.approx(10.0 + i)
        sent = frames(fleet.outputs, node)
        airtime = fleet.ocean.preset.airtime(sent[0].output.size)
        assert len(sent) * airtime / 600.0 <= 0.1 + 1e-9
    lost = sum(sum(link["lost"].values()) for link in fleet.ocean.stats()["links"])
    assert lost > 0  # random access: some frames collide at the buoy


def test_hippocampus_rounds_give_ranges_and_fixes() -> None:
    fleet = FastFleet(load_mission(MISSIONS / "hippocampus.yaml"), seed=1)
    fleet.put("hippo", "sensors", {"depth": 1.0, "temperature_c": 15.2, "conductivity_us": 600})
    fleet.run_until(60.0)
    requests = frames(fleet.outputs, "hippo")
    assert [round(r.time, 6) for r in requests] == [3.0 * k for k in range(21)]
    assert all(r.output.size == 15 for r in requests)
    sent = sorted((t.time, t.node) for t in fleet.outputs if isinstance(t.output, FrameSent)
                  and t.node.startswith("anchor"))
    assert [n for _, n in sent[:6]] == ["anchor1", "anchor2", "anchor3"] * 2  # turns in order
    assert sum(sum(link["lost"].values()) for link in fleet.ocean.stats()["links"]) == 0
    status = [t.output for t in fleet.outputs if t.node == "hippo"
              and isinstance(t.output, Status)]
    ranged = {s.topic for s in status if s.topic.startswith("range/")}
    assert ranged == {"range/anchor1", "range/anchor2", "range/anchor3"}
    fixes = [s.payload for s in status if s.topic == "position" and s.payload.get("fix")]
    assert len(fixes) >= 15  # one per round once the anchors are heard
    assert len(fleet.published("anchor1", "hippo/sensors")) >= 20


def test_an_hour_of_teleoperation_on_the_virtual_clock() -> None:
    loaded = load_mission(BLUEROV)
    result = asyncio.run(run_fast(loaded, duration=3600.0, seed=1))
    ipg = loaded.mission.mac.ipg_s  # type: ignore[union-attr]
    polls = result.nodes["operator"]["frames_sent"]
    assert polls == int(3600 / ipg) + 1
    assert result.nodes["rov"]["frames_received"] >= polls - 5  # range loss is rare at 1 m
    assert result.channels["image"].delivered >= polls - 10
    age = result.channels["status"].age
    assert age is not None and ipg / 2 < age.mean_s < ipg  # about IPG/2 + delay
    assert result.clock == "virtual" and result.duration_s == 3600.0


def test_zab_sim_fast_and_speed(tmp_path: Path) -> None:
    runner = CliRunner()
    out = tmp_path / "report.json"
    result = runner.invoke(app, ["sim", str(MISSIONS / "hippocampus.yaml"), "--fast",
                                 "--duration", "120", "--report", str(out)])
    assert result.exit_code == 0, result.output
    assert "virtual clock" in result.output and "real time" in result.output
    report = json.loads(out.read_text())
    assert report["nodes"]["hippo"]["frames_sent"] == 41
    assert report["channels"]["sensors"]["delivered"] > 100  # synthetic inputs were fed
    paced = runner.invoke(app, ["sim", str(MISSIONS / "hippocampus.yaml"), "--speed", "400",
                                "--duration", "20"])
    assert paced.exit_code == 0, paced.output
    both = runner.invoke(app, ["sim", str(BLUEROV), "--fast", "--speed", "3"])
    assert both.exit_code == 2 and "exclude" in both.output


def test_polled_schedule_reads_the_mission() -> None:
    data = yaml.safe_load(BLUEROV.read_text())
    data["mac"] = {"type": "polled", "master": "operator", "guard_s": 0.05}
    loaded = parse_mission(yaml.safe_dump(data), "b.yaml")
    fleet = FastFleet(loaded, seed=1)
    master = fleet.schedules["operator"]
    assert isinstance(master, PolledSchedule) and 0.55 < master.ipg_s < 0.65
