"""zab check says when a fragmented channel's bytes field before other fields makes every value
go at its whole length (a transfer drops only a value's trailing zero bytes). Found from
outside: a 600 B blob before an id went as 1.5 kB in 41 fragments."""

from __future__ import annotations

import pytest

from bridge.core.loaded import parse_mission
from bridge.report.check import check_mission

MISSION = """\
mission: blob
modem: {backend: sim, frame_bytes: 64, options: {preset: evologics-s2c-im}}
mac: {type: tdma, slot_s: 1.5, guard_s: 0.2, order: [a, b]}
nodes:
  a: {address: 1, role: surface, position: {x: 0, y: 0, depth: 0}}
  b: {address: 2, position: {x: 100, y: 0, depth: 10}}
channels:
  - name: blob
    from: a
    to: b
    reliable: true
    elements:
      - in: blob
        out: a/blob
        fields: FIELDS
"""
DATA = "{field: data, type: KIND, max_length: 1500}"
ID = "{field: id, type: int, min: 0, max: 255}"


def fragment_warning(fields: str) -> str:
    report = check_mission(parse_mission(MISSION.replace("FIELDS", fields), "blob.yaml"))
    (warning,) = [w for w in report.warnings if "larger than a frame" in w]
    return warning


@pytest.mark.parametrize("kind", ["bytes", "string"])
def test_a_long_field_before_others_is_said_to_go_whole(kind: str) -> None:
    said = fragment_warning(f"[{DATA.replace('KIND', kind)}, {ID}]")
    assert "'data' comes before other fields: put it last" in said


def test_a_long_field_last_says_nothing_more() -> None:
    said = fragment_warning(f"[{ID}, {DATA.replace('KIND', 'bytes')}]")
    assert said.endswith("fragments of 43 B")
