"""A latching channel whose value needs fragments: before, ``zab check`` passed it and the
sender packed the whole value into one frame entry (the store made it due, latching, beside
the stream that fragments it), so building the frame raised ``OverflowError`` and ended the
transmit task. Now the mission is refused at load, located at the channel's ``latching``
(a transfer is sent until acknowledged, once: it cannot latch); the same channel without
``latching`` crosses in fragments. And an entry that does not fit its place in a frame (a bug)
is left out, a counted drop, never the end of the transmit task."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from bridge.cli.app import app
from bridge.core.loaded import parse_mission
from bridge.errors import MissionError
from bridge.runtime.virtual_fleet import FastFleet

MISSION = """\
mission: fr
wire: {auth: off}
modem: {backend: sim, frame_bytes: 64, options: {preset: evologics-s2c-im}}
mac: {type: tdma, slot_s: 2, order: [op, rov]}
nodes:
  op: {address: 1, role: surface, position: {x: 0, y: 0, depth: 0.5}}
  rov: {address: 2, position: {x: 1, y: 0, depth: 0.8}}
channels:
  - name: image
    from: rov
    to: op
    latching: LATCHING
    elements:
      - in: rov/a
        out: rov/a
        fields: [{field: t, type: int, min: 0, max: 255, count: 70}]
"""

SMALL = """\
  - name: depth
    from: rov
    to: op
    latching: true
    elements:
      - {in: rov/d, out: rov/d, fields: [{field: d, type: int, min: 0, max: 255}]}
  - name: heading
    from: rov
    to: op
    elements:
      - {in: rov/h, out: rov/h, fields: [{field: h, type: int, min: 0, max: 255}]}
"""

VALUE = {"t": list(range(70))}


def mission(latching: bool) -> str:
    return MISSION.replace("LATCHING", "true" if latching else "false")


def test_a_latching_channel_that_needs_fragments_is_refused_at_its_latching() -> None:
    with pytest.raises(MissionError) as info:
        parse_mission(mission(latching=True), "m.yaml")
    message = str(info.value)
    assert message.startswith("m.yaml:12:5: channels[0].latching: a latching channel's value "
                              "must fit in one frame: this one (560 bits) needs 2 fragments"), \
        message
    assert "set latching: false" in message, message


def test_zab_check_refuses_it_with_exit_2(tmp_path: Path) -> None:
    path = tmp_path / "fr.yaml"
    path.write_text(mission(latching=True))
    result = CliRunner().invoke(app, ["check", str(path), "--no-key"])
    assert result.exit_code == 2, result.output
    assert "fr.yaml:12:5: channels[0].latching: a latching channel's value must fit" \
        in result.output, result.output


def test_without_latching_the_value_crosses_in_fragments() -> None:
    loaded = parse_mission(mission(latching=False), "m.yaml")
    assert loaded.table.channels[0].fragmented
    fleet = FastFleet(loaded, seed=0)
    fleet.put("rov", "rov/a", VALUE, at=1.0)
    fleet.run_until(60.0)
    assert [p.value for _, p in fleet.published("op", "rov/a")] == [VALUE]


def test_an_entry_that_does_not_fit_its_frame_is_a_counted_drop() -> None:
    fleet = FastFleet(parse_mission(MISSION.split("  - name: image")[0] + SMALL, "m.yaml"),
                      seed=0)
    fleet.put("rov", "rov/d", {"d": 7}, at=0.5)
    fleet.put("rov", "rov/h", {"h": 9}, at=0.5)
    fleet.run_until(1.0)
    rov = fleet.cores["rov"]
    rov.outbound.store.states[0].packed[0] = 1 << 600  # a bug: far wider than its 8 bits
    fleet.run_until(30.0)  # the transmit side goes on
    assert [p.value for _, p in fleet.published("op", "rov/h")] == [{"h": 9}]
    assert fleet.published("op", "rov/d") == []
    assert rov.outbound.drops.by_cause[("depth", "unbuildable")] >= 1
    fleet.put("rov", "rov/d", {"d": 8})  # a good value goes again (and latches)
    fleet.run_until(60.0)
    got = [p.value for _, p in fleet.published("op", "rov/d")]
    assert got and all(v == {"d": 8} for v in got), got
