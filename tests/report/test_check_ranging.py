"""`zab check` says what the nodes range and localise by: anchors, live ones' keys, and the sound
speed the bridges assume with where it comes from (a tester set ``sound_speed_mps`` beside
``water`` and nothing said which one the bridges used)."""

from __future__ import annotations

import json
from pathlib import Path

from typer.testing import CliRunner

from bridge.cli.app import app
from tests.conftest import MISSIONS

RUNNER = CliRunner()


def _check(path: Path, *options: str) -> str:
    result = RUNNER.invoke(app, ["check", str(path), *options], env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output
    return " ".join(result.output.split())  # (as one line: the console wraps at its width)


def test_anchors_live_keys_and_the_water_s_sound_speed() -> None:
    said = _check(MISSIONS / "morph.yaml", "--no-key")
    assert "ranging (DLBL): anchors ssv, gcv (live on gcv/nav); sound speed 1513.42 m/s " \
           "(ranging.water)" in said, said
    ranging = json.loads(_check(MISSIONS / "morph.yaml", "--json", "--no-key"))["ranging"]
    assert ranging["by"] == ["DLBL"]
    assert ranging["anchors"] == [{"node": "ssv", "live_key": None},
                                  {"node": "gcv", "live_key": "gcv/nav"}]
    assert ranging["sound_speed_from"] == "ranging.water"


def test_a_fixed_sound_speed_beside_the_water_is_the_one_assumed(tmp_path: Path) -> None:
    text = (MISSIONS / "hippocampus.yaml").read_text()
    path = tmp_path / "hippo.yaml"
    path.write_text(text.replace("ranging:\n  water:", "ranging:\n  sound_speed_mps: 1400\n"
                                 "  water:", 1))
    said = _check(path)
    assert "sound speed 1400 m/s (ranging.sound_speed_mps; ranging.water gives 1466.55 m/s, " \
           "which zab sim's water uses)" in said, said


def test_a_mission_that_does_not_range_says_nothing_of_it() -> None:
    assert "ranging" not in _check(MISSIONS / "bluerov_rf.yaml")
    assert json.loads(_check(MISSIONS / "bluerov_rf.yaml", "--json"))["ranging"] is None
