"""Authentication is never off by accident: `wire.auth` absent while a key is present, or on
without a key, stops `zab run` (exit 2) unless the mission says `auth: off`; `zab check` stops
on a key here that disagrees, and says that `zab run` will need one when there is none;
simulations in one process authenticate with a throwaway key and say so."""

from __future__ import annotations

import json
import os
import secrets
import socket
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from bridge.cli.app import app
from bridge.cli.doctor import mission_findings
from bridge.core.loaded import load_mission, parse_mission
from bridge.errors import MissionError
from bridge.mission.model import Mission
from bridge.mission.schema import schema_text
from bridge.runtime.fleet import Fleet
from bridge.runtime.keys import frame_key, load_key, throwaway_key
from bridge.runtime.virtual_fleet import FastFleet
from tests.conftest import MISSIONS, REPO, free_port
from tests.harness import zab_run

RUNNER = CliRunner()
MORPH = MISSIONS / "morph.yaml"


def lab(auth: object = None, **auth_options: object) -> dict:
    """A two-node UDP mission on free loopback ports; ``auth`` is wire.auth (None: absent)."""
    data: dict = {
        "mission": "keys",
        "modem": {"backend": "udp", "frame_bytes": 32},
        "nodes": {
            "a": {"address": 1, "zenoh": {"listen": [f"tcp/127.0.0.1:{free_port()}"]},
                  "modem": {"options": {"port": free_port(socket.SOCK_DGRAM)}}},
            "b": {"address": 2, "zenoh": {"listen": [f"tcp/127.0.0.1:{free_port()}"]},
                  "modem": {"options": {"port": free_port(socket.SOCK_DGRAM)}}},
        },
        "channels": [{"name": "ping", "from": "a", "to": "b", "elements": [
            {"in": "ping", "out": "a/ping",
             "fields": [{"field": "n", "type": "int", "min": 0, "max": 9}]}]}],
    }
    if auth is not None or auth_options:
        data["wire"] = {"auth": auth if auth is not None else dict(auth_options)}
    return data


def write(tmp_path: Path, data: dict, text: str | None = None) -> Path:
    path = tmp_path / "keys.yaml"
    path.write_text(text if text is not None else yaml.safe_dump(data, sort_keys=False))
    return path


def mission(data: dict) -> Mission:
    return parse_mission(yaml.safe_dump(data, sort_keys=False), "keys.yaml").mission


# -- the mission model -----------------------------------------------------------------------

@pytest.mark.parametrize("written", ["auth: off", "auth: 'off'", "auth: false"])
def test_auth_off_is_said_on_purpose_and_survives_a_dump(written: str) -> None:
    text = yaml.safe_dump(lab(), sort_keys=False) + f"wire:\n  {written}\n"
    loaded = parse_mission(text, "off.yaml")
    assert loaded.mission.wire.auth is None and loaded.mission.wire.auth_off
    assert loaded.table.auth_tag_bytes == 0
    dumped = loaded.mission.model_dump(by_alias=True, mode="json", exclude_unset=True)
    assert dumped["wire"] == {"auth": "off"}
    assert Mission.model_validate(dumped).wire.auth_off
    absent = parse_mission(yaml.safe_dump(lab(), sort_keys=False), "absent.yaml").mission
    assert absent.wire.auth is None and not absent.wire.auth_off


def test_auth_off_is_in_the_schema_and_other_words_are_refused() -> None:
    auth = json.loads(schema_text())["$defs"]["Wire"]["properties"]["auth"]
    assert {"enum": ["off", False], "description": "Frames are not authenticated, on purpose."} \
        in auth["anyOf"]
    for wrong in ("auth: on", "auth: 0", "auth: of"):
        text = yaml.safe_dump(lab(), sort_keys=False) + f"wire:\n  {wrong}\n"
        with pytest.raises(MissionError, match=r"wire\.auth"):
            parse_mission(text, "wrong.yaml")


# -- what the mission says against the keys present --------------------------------------------

def test_a_key_present_but_auth_not_said_is_a_problem(mission_key: str) -> None:
    key = frame_key(mission(lab()))
    assert key.state == "unsaid" and key.source == "$ZAB_KEY"
    assert key.problem is not None and "$ZAB_KEY holds a frame key" in key.problem
    assert "auth: off" in key.problem
    assert frame_key(mission(lab("off"))).problem is None  # said: keys are not looked at
    assert frame_key(mission(lab(tag_bytes=4))).problem is None


def test_auth_on_without_a_key_is_a_problem(tmp_path: Path) -> None:
    key = frame_key(mission(lab(tag_bytes=4)))
    assert key.state == "on" and key.throwaway
    assert key.problem is not None and "no frame key was found in $ZAB_KEY" in key.problem
    missing = tmp_path / "absent.key"
    key = frame_key(mission(lab(key_file=str(missing))))
    assert key.problem is not None and f"$ZAB_KEY or {missing}" in key.problem


def test_the_key_may_come_from_a_file_or_another_variable(tmp_path: Path,
                                                           monkeypatch: pytest.MonkeyPatch
                                                           ) -> None:
    key_file = tmp_path / "mission.key"
    key_file.write_text(secrets.token_hex(32) + "\n")
    key = frame_key(mission(lab(key_file=str(key_file))))
    assert key.problem is None and key.source == str(key_file) and not key.throwaway
    assert load_key("ZAB_KEY", key_file) == key_file.read_bytes().strip()
    monkeypatch.setenv("FLEET_KEY", "k" * 16)
    key = frame_key(mission(lab(key_env="FLEET_KEY")))
    assert key.problem is None and key.source == "$FLEET_KEY"


def test_a_short_key_is_a_problem(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("ZAB_KEY", "short")
    key = frame_key(mission(lab(tag_bytes=4)))
    assert key.problem is not None and "5 bytes; at least 16" in key.problem


def test_nothing_said_and_no_key_runs_with_a_warning() -> None:
    key = frame_key(mission(lab()))
    assert key.problem is None and key.state == "unsaid"
    assert "NOT authenticated" in key.describe()
    findings = [f for f in mission_findings(parse_mission(yaml.safe_dump(lab()), "m.yaml"))
                if f.check == "key"]
    assert [f.status for f in findings] == ["warn"]


def test_doctor_fails_on_auth_without_a_key() -> None:
    findings = [f for f in mission_findings(load_mission(MORPH)) if f.check == "key"]
    assert [f.status for f in findings] == ["fail"]
    assert "no frame key was found in $ZAB_KEY" in findings[0].message


def test_doctor_fails_on_a_key_the_mission_would_ignore(mission_key: str) -> None:
    findings = [f for f in mission_findings(parse_mission(yaml.safe_dump(lab()), "m.yaml"))
                if f.check == "key"]
    assert [f.status for f in findings] == ["fail"]


# -- zab check --------------------------------------------------------------------------------

def test_check_exits_2_on_a_key_present_and_auth_not_said(tmp_path: Path,
                                                          mission_key: str) -> None:
    path = write(tmp_path, lab())
    result = RUNNER.invoke(app, ["check", str(path)])
    assert result.exit_code == 2, result.output
    assert "error: $ZAB_KEY holds a frame key, but the mission does not authenticate" in \
        result.output
    as_json = RUNNER.invoke(app, ["check", str(path), "--json"])
    assert as_json.exit_code == 2
    assert json.loads(as_json.stdout)["frame_key"]["state"] == "unsaid"
    off = write(tmp_path, lab("off"))
    said = RUNNER.invoke(app, ["check", str(off)])
    assert said.exit_code == 0, said.output
    assert "frames are not authenticated (wire.auth: off, on purpose)" in said.output


def test_check_without_a_key_passes_and_says_run_will_need_one() -> None:
    """Checking a file is not running a vehicle: no key here is one line, exit 0."""
    result = RUNNER.invoke(app, ["check", str(MORPH)])
    assert result.exit_code == 0, result.output
    flat = " ".join(result.output.split())
    assert "frames authenticated (4-byte tag, no key on this machine): `zab run` and `zab " \
        "doctor` will need the mission key in $ZAB_KEY" in flat
    assert "error" not in result.output
    as_json = RUNNER.invoke(app, ["check", str(MORPH), "--json"])
    assert as_json.exit_code == 0
    data = json.loads(as_json.stdout)
    assert data["ok"] is True and data["errors"] == []
    assert data["frame_key"]["problem"] is None and "zab run" in data["frame_key"]["note"]
    alone = RUNNER.invoke(app, ["check", str(MORPH), "--no-key"])  # the file alone
    assert alone.exit_code == 0, alone.output
    assert "frames authenticated (4-byte tag, key not looked for)" in alone.output


def test_check_exits_2_on_an_empty_key_file_and_json_says_not_ok(tmp_path: Path) -> None:
    empty = tmp_path / "mission.key"
    empty.write_text("\n")
    path = write(tmp_path, lab(key_file=str(empty)))
    result = RUNNER.invoke(app, ["check", str(path)])
    assert result.exit_code == 2, result.output
    assert f"no frame key was found in $ZAB_KEY or {empty}" in " ".join(result.output.split())
    as_json = RUNNER.invoke(app, ["check", str(path), "--json"])
    data = json.loads(as_json.stdout)
    assert as_json.exit_code == 2 and data["ok"] is False
    assert data["errors"] == [data["frame_key"]["problem"]]


def test_check_json_ok_matches_the_exit_code_for_every_outcome(tmp_path: Path,
                                                                monkeypatch: pytest.MonkeyPatch
                                                                ) -> None:
    (tmp_path / "off").mkdir()
    (tmp_path / "unsaid").mkdir()
    cases = {"auth off": (write(tmp_path / "off", lab("off")), None, 0),
             "no key": (MORPH, None, 0), "short key": (MORPH, "short", 2),
             "key, auth unsaid": (write(tmp_path / "unsaid", lab()), secrets.token_hex(32), 2)}
    for name, (path, key, code) in cases.items():
        if key is None:
            monkeypatch.delenv("ZAB_KEY", raising=False)
        else:
            monkeypatch.setenv("ZAB_KEY", key)
        result = RUNNER.invoke(app, ["check", str(path), "--json"])
        assert result.exit_code == code, name
        assert json.loads(result.stdout)["ok"] is (code == 0), name


def test_check_with_the_key_says_where_it_came_from(mission_key: str) -> None:
    result = RUNNER.invoke(app, ["check", str(MORPH)])
    assert result.exit_code == 0, result.output
    assert "frames authenticated (4-byte tag, key from $ZAB_KEY)" in result.output


def test_check_warns_plainly_when_nothing_is_said(tmp_path: Path) -> None:
    result = RUNNER.invoke(app, ["check", str(write(tmp_path, lab()))])
    assert result.exit_code == 0, result.output
    assert "frames are NOT authenticated" in result.output


def test_shipped_missions_authenticate_or_say_why_not() -> None:
    for path in sorted(MISSIONS.glob("*.yaml")):
        wire = load_mission(path).mission.wire
        assert wire.auth is not None or wire.auth_off, path.name
        if wire.auth_off:
            line = next(line for line in path.read_text().splitlines() if "auth: off" in line)
            assert "on purpose" in line, path.name
    assert load_mission(MORPH).mission.wire.auth is not None


# -- zab run: real processes ------------------------------------------------------------------

def _run(path: Path, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "bridge", "run", str(path), "--node", "a"],
                          cwd=REPO, capture_output=True, text=True, timeout=60,
                          env={**env, "COLUMNS": "80"})


def _clean_env() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if k != "ZAB_KEY"}


def _starts(path: Path, env: dict[str, str]) -> str:
    """`zab run` starts; SIGTERM stops it (exit 0). Its output up to the start."""
    with zab_run(path, "a", env=env) as (_, lines):
        started = "".join(lines)
    return started


def test_run_refuses_a_key_when_the_mission_does_not_say_auth(tmp_path: Path) -> None:
    path = write(tmp_path, lab())
    result = _run(path, {**_clean_env(), "ZAB_KEY": secrets.token_hex(32)})
    assert result.returncode == 2, result.stdout + result.stderr
    assert "Traceback" not in result.stderr
    assert result.stderr.startswith("cannot start: a: $ZAB_KEY holds a frame key, but the "
                                    "mission does not authenticate frames")
    assert len(result.stderr.strip().splitlines()) == 1


def test_run_refuses_auth_without_a_key(tmp_path: Path) -> None:
    path = write(tmp_path, lab(tag_bytes=4))
    result = _run(path, _clean_env())
    assert result.returncode == 2, result.stdout + result.stderr
    assert "Traceback" not in result.stderr
    assert result.stderr.startswith("cannot start: a: wire.auth is on but no frame key was "
                                    "found in $ZAB_KEY")


def test_run_starts_with_auth_off_on_purpose_even_with_a_key(tmp_path: Path) -> None:
    output = _starts(write(tmp_path, lab("off")),
                     {**_clean_env(), "ZAB_KEY": secrets.token_hex(32)})
    assert "frames are not authenticated (wire.auth: off, on purpose)" in output


def test_run_starts_with_auth_and_its_key(tmp_path: Path) -> None:
    output = _starts(write(tmp_path, lab(tag_bytes=4)),
                     {**_clean_env(), "ZAB_KEY": secrets.token_hex(32)})
    assert "frames authenticated (4-byte tag, key from $ZAB_KEY)" in output


def test_run_with_nothing_said_and_no_key_warns(tmp_path: Path) -> None:
    output = _starts(write(tmp_path, lab()), _clean_env())
    assert "WARNING" in output and "frames are NOT authenticated" in output


# -- simulations: a throwaway key, said out loud ------------------------------------------------

def test_fleets_in_one_process_share_a_throwaway_key_and_hear_each_other() -> None:
    loaded = load_mission(MORPH)
    one, two = Fleet(loaded, only=["ssv"]), Fleet(loaded, only=["lsv"])
    assert one.throwaway_key and two.throwaway_key
    assert one.key == two.key == throwaway_key() and len(throwaway_key()) >= 32
    fast = FastFleet(loaded, seed=1)
    assert fast.throwaway_key and fast.key == throwaway_key()
    for i in range(8):
        fast.put("lsv", "target_reference", {"vector": {"x": 0.1 * i, "y": 0.0}}, at=i * 15.0)
    fast.run_until(120.0)
    assert fast.published("gcv", "lsv/target_reference")
    assert all(not core.stats.frames_dropped["forged"] for core in fast.cores.values())


def test_fleets_use_the_mission_key_when_there_is_one(mission_key: str) -> None:
    loaded = load_mission(MORPH)
    fleet = Fleet(loaded)
    assert not fleet.throwaway_key and fleet.key == mission_key.encode()
    given = FastFleet(loaded, key=b"g" * 32)
    assert not given.throwaway_key and given.key == b"g" * 32


def test_sim_says_it_uses_a_throwaway_key() -> None:
    result = RUNNER.invoke(app, ["sim", str(MORPH), "--fast", "--duration", "30"])
    assert result.exit_code == 0, result.output
    assert "frames authenticated with a throwaway key for this run (no key in $ZAB_KEY)" in \
        " ".join(result.output.split())


def test_check_shows_what_sealed_frames_cost_and_wants_the_next_key(
        tmp_path: Path, mission_key: str, monkeypatch: pytest.MonkeyPatch) -> None:
    path = write(tmp_path, lab(tag_bytes=6, encrypt=True,
                               next_key={"at": "2026-06-01T12:00:00Z", "overlap_s": 30}))
    result = RUNNER.invoke(app, ["check", str(path)])
    assert result.exit_code == 2  # the next key is named and absent
    assert "no key was found in $ZAB_NEXT_KEY" in result.output
    monkeypatch.setenv("ZAB_NEXT_KEY", secrets.token_hex(32))
    result = RUNNER.invoke(app, ["check", str(path), "--json"])
    assert result.exit_code == 0, result.output
    data = json.loads(result.output)
    assert data["auth"]["bits_per_frame"] == 32 + 48 and data["auth"]["cipher"] == "AES-CCM"
    assert data["frame_key"]["encrypted"] and data["overhead_bytes"] == 2 + 4 + 6
    text = RUNNER.invoke(app, ["check", str(path)]).output
    assert "frames encrypted and authenticated (AES-CCM, 6-byte tag" in text
    assert "+80 bits a frame (32-bit counter + 48-bit tag)" in text
def test_every_shipped_mission_checks_on_a_fresh_machine(tmp_path: Path) -> None:
    """The README's promise: `uv run zab check` passes every example mission with no key on
    the machine (a bare environment, an empty home), saying so when `zab run` will need one."""
    zab = Path(sys.executable).parent / "zab"
    env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "HOME": str(tmp_path),
           "LANG": "C.UTF-8"}
    paths = sorted(MISSIONS.glob("*.yaml"))
    runs = {path.name: subprocess.Popen([str(zab), "check", str(path)], cwd=tmp_path, env=env,
                                        stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                        text=True) for path in paths}
    for name, run in runs.items():
        out, errors = run.communicate(timeout=120)
        assert run.returncode == 0, (name, out, errors)
        flat = " ".join(out.split())
        if load_mission(MISSIONS / name).mission.wire.auth is not None:
            assert "no key on this machine): `zab run` and `zab doctor` will need the mission " \
                "key in $ZAB_KEY" in flat, name
    assert len(runs) >= 9  # morph, morph_evologics, ros2_odometry among them: authenticated
