"""The command line as a user runs it: check, schema, sim --report, run + SIGINT, packaging."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import yaml
from typer.testing import CliRunner

from bridge.cli.app import app
from bridge.mission.schema import default_schema_path, schema_text
from tests.conftest import MISSIONS, REPO, free_port
from tests.harness import zab_run

RUNNER = CliRunner()


def zab(*args: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "bridge", *args], capture_output=True,
                          text=True, timeout=timeout, cwd=REPO)


def test_check_json_for_every_example_mission(mission_key: str) -> None:
    for path in sorted(MISSIONS.glob("*.yaml")):
        result = RUNNER.invoke(app, ["check", str(path), "--json"])
        assert result.exit_code == 0, (path, result.output)
        data = json.loads(result.output)
        assert {"mission", "frame_bytes", "channels", "nodes"} <= data.keys()
        for channel in data["channels"]:
            assert {"name", "index", "bits", "from", "to"} <= channel.keys()
        for node in data["nodes"]:
            assert {"name", "address", "listen"} <= node.keys()


def test_check_morph_reports_listing_1() -> None:
    data = json.loads(RUNNER.invoke(app, ["check", str(MISSIONS / "morph.yaml"), "--json",
                                          "--no-key"]).output)
    target = next(c for c in data["channels"] if c["name"] == "target_reference")
    assert target["bits"] == 14 and target["from"] == ["lsv"] and target["to"] == ["gcv"]
    assert data["frame_bytes"] == 64 and len(data["nodes"]) == 5


def test_check_exit_1_when_a_channel_never_fits(tmp_path: Path) -> None:
    # 16 B frames: 14 B of DLBL delays and check leave too little for even one fragment
    text = (MISSIONS / "morph.yaml").read_text().replace("frame_bytes: 64", "frame_bytes: 16")
    path = tmp_path / "small.yaml"
    path.write_text(text.replace("auth: {tag_bytes: 4}", "auth: off"))
    result = RUNNER.invoke(app, ["check", str(path)])
    assert result.exit_code == 1
    assert "can never fit" in result.output


def test_check_reports_a_channel_that_travels_in_fragments(tmp_path: Path) -> None:
    text = (MISSIONS / "morph.yaml").read_text().replace("frame_bytes: 64", "frame_bytes: 21")
    text = text.replace("latching: true", "latching: false")  # (a transfer cannot latch)
    path = tmp_path / "small.yaml"
    path.write_text(text.replace("auth: {tag_bytes: 4}", "auth: off"))
    result = RUNNER.invoke(app, ["check", str(path), "--json"])
    data = json.loads(result.output)
    fragmented = [c for c in data["channels"] if c["fragments"]]
    assert result.exit_code == 0 and fragmented
    assert all(c["fragments"]["chunk_bytes"] >= 1 for c in fragmented)
    assert any("fragments of" in w for w in data["warnings"])


def test_check_warns_about_a_short_tdma_slot(tmp_path: Path) -> None:
    text = (MISSIONS / "morph.yaml").read_text().replace("slot_s: 1.5", "slot_s: 0.5")
    path = tmp_path / "short.yaml"
    path.write_text(text)
    result = RUNNER.invoke(app, ["check", str(path), "--json", "--no-key"])
    assert result.exit_code == 0
    assert any("TDMA slot" in w for w in json.loads(result.output)["warnings"])


def test_committed_schema_is_fresh() -> None:
    assert default_schema_path().read_text() == schema_text(), "run `uv run zab schema`"


def test_sim_writes_a_report(tmp_path: Path) -> None:
    data = yaml.safe_load((MISSIONS / "morph.yaml").read_text())
    for node in data["nodes"].values():
        node["zenoh"]["listen"] = [f"tcp/127.0.0.1:{free_port()}"]
    mission = tmp_path / "m.yaml"
    mission.write_text(yaml.safe_dump(data))
    report = tmp_path / "report.json"
    result = zab("sim", str(mission), "--duration", "6", "--report", str(report), "--no-live")
    assert result.returncode == 0, result.stderr
    out = json.loads(report.read_text())
    assert set(out["channels"]) == {c["name"] for c in data["channels"]}
    assert out["links"] and all({"link", "sent", "delivered", "lost"} <= set(link)
                                for link in out["links"])
    assert sum(n["frames_sent"] for n in out["nodes"].values()) >= 2


def test_run_stops_cleanly_on_sigint(tmp_path: Path) -> None:
    mission = tmp_path / "m.yaml"
    mission.write_text(yaml.safe_dump({
        "mission": "solo",
        "modem": {"backend": "udp", "frame_bytes": 16},
        "nodes": {
            "a": {"address": 1, "zenoh": {"listen": [f"tcp/127.0.0.1:{free_port()}"]},
                  "modem": {"options": {"port": free_port()}}},
            "b": {"address": 2, "modem": {"options": {"port": free_port()}}},
        },
    }))
    with zab_run(mission, "a", stop=signal.SIGINT):  # (exit 0 after Ctrl-C, or it fails)
        pass


def test_run_unknown_node_exit_2() -> None:
    result = RUNNER.invoke(app, ["run", str(MISSIONS / "morph.yaml"), "--node", "nemo"])
    assert result.exit_code == 2


def test_wheel_ships_codecs_and_schemas(tmp_path: Path) -> None:
    subprocess.run(["uv", "build", "--wheel", "--out-dir", str(tmp_path), str(REPO)],
                   check=True, capture_output=True, timeout=120)
    wheel = next(tmp_path.glob("*.whl"))
    names = set(zipfile.ZipFile(wheel).namelist())
    assert "bridge/_data/codecs/ccl/bathymetry.yaml" in names
    assert "bridge/_data/schemas/mission.schema.json" in names
    assert "bridge/_data/missions/morph.yaml" in names  # what `zab demo` runs when installed
    assert "bridge/gui/static/app.js" in names


def test_water_and_emulate_serve_a_real_driver(tmp_path: Path) -> None:
    """`zab water` + `zab emulate evologics` as processes; the driver opens the emulated pty."""
    import asyncio

    from bridge.core.loaded import load_mission
    from bridge.modems.evologics.driver import EvologicsBackend
    from bridge.modems.setup import modem_setup

    mission = MISSIONS / "morph_evologics.yaml"
    water_port = free_port()
    link = tmp_path / "lsv.pty"
    procs = [
        subprocess.Popen([sys.executable, "-m", "bridge", "water", str(mission),
                          "--port", str(water_port)], cwd=REPO, stdout=subprocess.DEVNULL,
                         stderr=subprocess.DEVNULL),
    ]
    try:
        time.sleep(1.0)
        procs.append(subprocess.Popen(
            [sys.executable, "-m", "bridge", "emulate", "evologics", str(mission), "--node",
             "lsv", "--link", str(link), "--water", f"127.0.0.1:{water_port}"],
            cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        deadline = time.time() + 15
        while not link.exists() and time.time() < deadline:
            time.sleep(0.1)
        assert link.exists(), "the emulator did not open its pty"
        loaded = load_mission(mission)
        setup = modem_setup(loaded.mission, "lsv", {"device": str(link)})

        async def handshake() -> int:
            async with EvologicsBackend(setup) as modem:
                return modem.address

        assert asyncio.run(handshake()) == loaded.mission.address_of("lsv")
    finally:
        for proc in reversed(procs):
            proc.send_signal(signal.SIGINT)
        for proc in procs:
            try:
                assert proc.wait(timeout=10) == 0
            finally:
                if proc.poll() is None:
                    proc.kill()


def test_check_counts_a_path_waypoint_in_the_slot_warning(tmp_path: Path) -> None:
    mission = yaml.safe_load((MISSIONS / "morph.yaml").read_text())
    result = RUNNER.invoke(app, ["check", str(MISSIONS / "morph.yaml"), "--json", "--no-key"])
    assert not any("TDMA slot" in w for w in json.loads(result.output)["warnings"])
    vehicle = next(n for n in mission["nodes"].values() if n.get("position"))
    start = vehicle["position"]
    vehicle["path"] = {"waypoints": [start, {**start, "x": start["x"] + 1500}], "speed_mps": 1.5}
    path = tmp_path / "far.yaml"
    path.write_text(yaml.safe_dump(mission))
    result = RUNNER.invoke(app, ["check", str(path), "--json", "--no-key"])
    assert result.exit_code == 0, result.output
    assert any("TDMA slot" in w for w in json.loads(result.output)["warnings"])
