"""The deploy kit: example missions pass `zab check`, the Zenoh configs load and route on loopback
with their access control, the systemd unit verifies and stops the bridge cleanly."""

from __future__ import annotations

import json
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
import zenoh
from typer.testing import CliRunner

from bridge.cli.app import app
from bridge.runtime.logbook import read_log
from tests.conftest import MISSIONS, REPO, free_port
from tests.harness import zab_run

RUNNER = CliRunner()
ZENOH = REPO / "deploy" / "zenoh"
UNIT = REPO / "deploy" / "systemd" / "zab@.service"


@pytest.mark.parametrize("path", sorted(MISSIONS.glob("*.yaml")), ids=lambda p: p.name)
def test_every_example_mission_passes_zab_check(path: Path, mission_key: str) -> None:
    result = RUNNER.invoke(app, ["check", str(path)])
    assert result.exit_code == 0, result.output


def test_the_named_examples_are_there() -> None:
    assert {"morph.yaml", "remus_ccl.yaml"} <= {p.name for p in MISSIONS.glob("*.yaml")}


@pytest.mark.parametrize("name", ["surface-router", "surface-client", "vehicle"])
def test_zenoh_configs_load(name: str) -> None:
    config = zenoh.Config.from_file(str(ZENOH / f"{name}.json5"))
    assert json.loads(config.get_json("scouting/multicast/enabled")) is False
    endpoints = json.loads(config.get_json("listen/endpoints"))
    assert not any(e.startswith(("tcp/[::]", "tcp/0.0.0.0")) for e in endpoints)


def _on_loopback(name: str, listen: list[str], connect: list[str] | None = None) -> zenoh.Config:
    """A deploy config with its endpoints moved to free loopback ports (no TLS files here)."""
    config = zenoh.Config.from_file(str(ZENOH / f"{name}.json5"))
    config.insert_json5("listen/endpoints", json.dumps(listen))
    if connect is not None:
        config.insert_json5("connect/endpoints", json.dumps(connect))
    return config


def _client(port: int, user: str | None = None, password: str = "") -> zenoh.Session:
    config = zenoh.Config()
    config.insert_json5("mode", '"client"')
    config.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    config.insert_json5("scouting/multicast/enabled", "false")
    if user is not None:
        config.insert_json5("transport/auth/usrpwd",
                            json.dumps({"user": user, "password": password}))
    return zenoh.open(config)


def _wait_for(items: list, count: int, seconds: float = 5.0) -> None:
    end = time.time() + seconds
    while len(items) < count and time.time() < end:
        time.sleep(0.05)


def test_vehicle_router_without_a_certificate_only_reads() -> None:
    """A vehicle router that joins over the plain loopback listener is a station tool: the
    station's `gps` reaches its apps, but its `lsv/nav` never reaches the surface (a surfaced
    vehicle joins over TLS with its certificate: tests/deploy/test_tls.py)."""
    surface_port, vehicle_port, dead = free_port(), free_port(), free_port()
    surface = zenoh.open(_on_loopback("surface-router", [f"tcp/127.0.0.1:{surface_port}"]))
    sessions = [surface]
    try:
        vehicle = zenoh.open(_on_loopback(  # the WiFi TLS endpoint is down: it keeps retrying
            "vehicle", [f"tcp/127.0.0.1:{vehicle_port}"],
            [f"tls/127.0.0.1:{dead}", f"tcp/127.0.0.1:{surface_port}"]))
        sessions.append(vehicle)
        app_on_vehicle, tool = _client(vehicle_port), _client(surface_port)
        sessions += [app_on_vehicle, tool]
        on_vehicle: list[tuple[str, bytes]] = []
        app_on_vehicle.declare_subscriber("gps", lambda s: on_vehicle.append(
            (str(s.key_expr), s.payload.to_bytes())))
        at_surface: list[tuple[str, bytes]] = []
        tool.declare_subscriber("lsv/**", lambda s: at_surface.append((str(s.key_expr),
                                                                        s.payload.to_bytes())))
        deadline = time.time() + 10
        while not on_vehicle and time.time() < deadline:
            app_on_vehicle.put("lsv/nav", b"fix")
            tool.put("gps", b"station fix")
            time.sleep(0.1)
        assert on_vehicle and on_vehicle[0] == ("gps", b"station fix")
        for _ in range(5):  # puts after the route is known both ways
            app_on_vehicle.put("lsv/nav", b"fix")
            time.sleep(0.1)
        time.sleep(0.5)
        assert at_surface == []
    finally:
        for s in reversed(sessions):
            s.close()


def test_router_acl_lets_only_operators_publish_commands(tmp_path: Path) -> None:
    """The router's own rules and policies, with subjects named by username instead of by TLS
    certificate (tests/deploy/test_acl.py has the certificates): a viewer's command is dropped,
    an operator's goes through, an operator cannot speak for a vehicle. Every client here is
    also a station tool (plain TCP on loopback), which adds no right to publish."""
    users = tmp_path / "users.txt"
    users.write_text("operator-console:op\nviewer:vw\nsurface-bridge:br\nlsv:ls\n")
    port = free_port()
    config = _on_loopback("surface-router", [f"tcp/127.0.0.1:{port}"])
    config.insert_json5("transport/auth/usrpwd", json.dumps(
        {"user": "router", "password": "rt", "dictionary_file": str(users)}))
    subjects = json.loads(config.get_json("access_control/subjects"))
    for subject in subjects:
        if subject.get("cert_common_names"):
            subject["usernames"] = subject.pop("cert_common_names")
    config.insert_json5("access_control/subjects", json.dumps(subjects))
    router = zenoh.open(config)
    sessions = [router]
    try:
        bridge, operator = _client(port, "surface-bridge", "br"), _client(port, "operator-console",
                                                                         "op")
        viewer, lsv = _client(port, "viewer", "vw"), _client(port, "lsv", "ls")
        sessions += [bridge, operator, viewer, lsv]
        got: list[tuple[str, bytes]] = []
        bridge.declare_subscriber("**", lambda s: got.append((str(s.key_expr),
                                                               s.payload.to_bytes())))
        time.sleep(0.5)
        viewer.put("command", b"viewer")
        operator.put("lsv/nav", b"operator")
        lsv.put("ssv/status", b"lsv outside its name")
        lsv.put("lsv/nav", b"lsv")
        operator.put("command", b"operator")
        _wait_for(got, 2)
        time.sleep(0.3)
        assert sorted(got) == [("command", b"operator"), ("lsv/nav", b"lsv")]
        with pytest.raises(zenoh.ZError):
            sessions.append(_client(port, "viewer", "wrong password"))
    finally:
        for s in reversed(sessions):
            s.close()


def test_systemd_unit_is_hardened_and_runs_one_node_per_instance(tmp_path: Path) -> None:
    text = UNIT.read_text()
    service = dict(line.split("=", 1) for line in text.splitlines()
                   if "=" in line and not line.startswith("#"))
    assert service["ExecStart"].split()[1:5] == ["run", "/etc/zab/mission.yaml", "--node", "%i"]
    assert service["Restart"] == "always" and service["RestartPreventExitStatus"] == "2"
    assert service["NoNewPrivileges"] == "yes" and service["DevicePolicy"] == "closed"
    assert service["DeviceAllow"] == "/dev/zab-modem rw"
    assert service["StandardError"] == "journal"
    analyze = shutil.which("systemd-analyze")
    if analyze is None:
        pytest.skip("systemd-analyze not installed")
    zab = shutil.which("zab") or str(Path(sys.executable).with_name("zab"))
    instance = tmp_path / "zab@lsv.service"
    instance.write_text(text.replace("/usr/local/bin/zab", zab))
    done = subprocess.run([analyze, "verify", str(instance)], capture_output=True, text=True,
                          timeout=60)
    problems = [line for line in (done.stdout + done.stderr).splitlines()
                if "zab@lsv.service" in line]
    assert not problems, problems


LAB = """\
mission: unit
modem: {backend: udp, frame_bytes: 16}
nodes:
  a: {address: 1, modem: {options: {port: PORT_A}}, zenoh: {listen: [tcp/127.0.0.1:ZA]}}
  b: {address: 2, modem: {options: {port: PORT_B}}, zenoh: {listen: [tcp/127.0.0.1:ZB]}}
channels:
  - {name: ping, from: a, to: b, elements: [{in: ping, out: a/ping, fields: [{field: n, type:
      int, min: 0, max: 9}]}]}
"""


def test_sigterm_stops_zab_run_and_closes_its_time_stamped_log(tmp_path: Path) -> None:
    """What systemd does: start `zab run --node %i --log .../%i-{time}.mcap`, then SIGTERM."""
    text = LAB
    for name, kind in (("PORT_A", socket.SOCK_DGRAM), ("PORT_B", socket.SOCK_DGRAM),
                       ("ZA", socket.SOCK_STREAM), ("ZB", socket.SOCK_STREAM)):
        text = text.replace(name, str(free_port(kind)))
    mission = tmp_path / "mission.yaml"
    mission.write_text(text)
    assert yaml.safe_load(text)["nodes"]["a"]["address"] == 1
    logs = tmp_path / "logs"
    with zab_run(mission, "a", "--log", str(logs / "a-{time}.mcap")):
        time.sleep(0.5)  # then SIGTERM, as systemd stops it; it must exit 0
    [log] = list(logs.glob("a-*.mcap"))
    assert "{time}" not in log.name and len(log.stem) == len("a-20260101T000000Z")
    data = read_log(log)
    assert data.node == "a" and data.loaded is not None
    assert any(r.kind == "link" for r in data.records)
