"""`zab check` says a float field's step when its bits leave it coarser than a quarter of its
range, and `--json` shows every numeric field's step: `{field: x, bits: 1, min: -1000, max:
1000}` (a step of 2000: a 0 arrives as 1000) passed without a word."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from bridge.cli.app import app
from bridge.core.loaded import load_mission, parse_mission
from bridge.report.check import check_mission
from tests.conftest import MISSIONS

MISSION = """\
mission: steps
nodes: {a: {address: 1}, b: {address: 2}}
channels:
  - name: nav
    from: a
    to: b
    elements:
      - in: nav
        out: a/nav
        fields:
          - FIELD
          - {field: depth, bits: 8, min: 0, max: 200}
          - {field: mode, type: int, min: 0, max: 1}
          - {field: ok, type: bool}
"""
COARSE = "a step over a quarter of the range"


def warnings_of(field: str) -> list[str]:
    report = check_mission(parse_mission(MISSION.replace("FIELD", field), "m.yaml"))
    return [w for w in report.warnings if COARSE in w]


def test_one_bit_over_two_thousand_is_said_with_its_step_and_the_bits_that_do() -> None:
    [warning] = warnings_of("{field: x, bits: 1, min: -1000, max: 1000}")
    assert warning == (
        "channel 'nav': field 'x' (key nav): 1 bit over [-1000, 1000] is a step of 2000, only "
        "2 values (a step over a quarter of the range: a value arrives as the nearest of "
        "them); bits: 7 give a step of 15.7, under 1/100 of the range")


@pytest.mark.parametrize(("field", "coarse"), [
    ("{field: x, bits: 2, min: 0, max: 3}", True),  # a step of 1: 4 values
    ("{field: x, bits: 3, min: 0, max: 7}", False),  # a step of 1: 8 values
    ("{field: x, resolution: 500, min: 0, max: 1000}", True),
    ("{field: x, resolution: 250, min: 0, max: 1000}", False),  # a quarter: 5 values
    ("{field: x, bits: 1, min: 0, max: 1, count: 3}", True),  # each value of an array
    ("{field: x, type: int, min: 0, max: 1}", False),  # an int's values are its own
])
def test_only_a_float_step_over_a_quarter_of_its_range_is_coarse(field: str,
                                                                  coarse: bool) -> None:
    assert bool(warnings_of(field)) is coarse


def test_no_shipped_mission_has_a_coarse_field() -> None:
    for path in sorted(MISSIONS.glob("*.yaml")):
        report = check_mission(load_mission(path))
        assert not [w for w in report.warnings if COARSE in w], path.name


def test_check_json_shows_each_numeric_field_s_step(tmp_path: Path) -> None:
    path = tmp_path / "m.yaml"
    path.write_text(MISSION.replace("FIELD", "{field: x, bits: 1, min: -1000, max: 1000}"))
    result = CliRunner().invoke(app, ["check", str(path), "--json"])
    assert result.exit_code == 0, result.output
    data = json.loads(result.output)
    [nav] = data["channels"]
    assert nav["fields"] == [
        {"key": "nav", "field": "x", "bits": 1, "min": -1000, "max": 1000, "step": 2000},
        {"key": "nav", "field": "depth", "bits": 8, "min": 0, "max": 200, "step": 200 / 255},
        {"key": "nav", "field": "mode", "bits": 1, "min": 0, "max": 1, "step": 1}]
    assert any(COARSE in w for w in data["warnings"])
