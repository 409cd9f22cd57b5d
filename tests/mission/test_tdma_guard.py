"""A TDMA guard as long as the slot: the guard is the silent end of each slot, so nothing could
ever be sent. Before, ``zab check`` passed it (exit 0, a warning that the slot leaves
-96.000 s) and ``zab sim --fast`` sent no frame; now it is refused at ``mac.guard_s``."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from bridge.cli.app import app
from bridge.core.loaded import parse_mission
from bridge.errors import MissionError

MISSION = """\
mission: guard
wire: {auth: off}
modem: {backend: sim, frame_bytes: 64, options: {preset: evologics-s2c-im}}
mac:
  type: tdma
  slot_s: 4.0
  guard_s: GUARD
  order: [a, b]
nodes:
  a: {address: 1, position: {x: 0, y: 0, depth: 0}}
  b: {address: 2, position: {x: 2000, y: 0, depth: 50}}
channels:
  - name: pose
    from: b
    to: a
    elements:
      - {in: pose, out: b/pose, fields: [{field: x, type: int, min: 0, max: 9}]}
"""


def mission(guard: str) -> str:
    return MISSION.replace("GUARD", guard)


@pytest.mark.parametrize("guard", ["100", "4", "4.0"])
def test_a_guard_that_fills_the_slot_is_refused_at_guard_s(guard: str) -> None:
    with pytest.raises(MissionError) as info:
        parse_mission(mission(guard), "m.yaml")
    message = str(info.value)
    assert message.startswith(f"m.yaml:7:3: mac.guard_s: a guard of {float(guard):g} s leaves "
                              "nothing of a 4 s slot"), message
    assert "make guard_s shorter than slot_s" in message, message


def test_a_guard_shorter_than_the_slot_loads() -> None:
    parse_mission(mission("1.5"), "m.yaml")


def test_zab_check_refuses_it_with_exit_2(tmp_path: Path) -> None:
    path = tmp_path / "guard.yaml"
    path.write_text(mission("100"))
    result = CliRunner().invoke(app, ["check", str(path), "--no-key"])
    assert result.exit_code == 2, result.output
    assert "guard.yaml:7:3: mac.guard_s: a guard of 100 s leaves nothing" in \
        result.output.replace("\n", ""), result.output
