"""Key families: a wildcard input carries each concrete key on its own, with an index of
⌈log2 n⌉ bits, its own value, age and output key; learned families stop at their bound."""

from __future__ import annotations

import asyncio
import json
import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

from bridge.cli.app import app
from bridge.cli.sim_fast import run_fast
from bridge.core.loaded import load_mission, parse_mission
from bridge.core.node import NodeCore
from bridge.errors import FrameError, MissionError
from bridge.modems.base import Reception
from bridge.runtime.logbook import FleetLogs, read_log, received_values
from bridge.runtime.virtual_fleet import FastFleet
from bridge.wire.frame import FrameCodec
from tests.conftest import MISSIONS

ZSPACE = MISSIONS / "zspace.yaml"


def wanting(seed: int = 1) -> FastFleet:
    """The example fleet with an application subscribing to everything at every node."""
    fleet = FastFleet(load_mission(ZSPACE), seed=seed)
    for node in fleet.cores:
        fleet.subscribe(node, "**")
    return fleet


def values(fleet: FastFleet, node: str) -> dict[str, list]:
    out: dict[str, list] = {}
    for _, p in fleet.published(node):
        out.setdefault(p.key, []).append(p.value)
    return out


def test_listed_members_arrive_on_their_own_keys_with_their_own_values() -> None:
    fleet = wanting()
    fleet.put("auv1", "auv1/sensors/a/temp", {"celsius": 10.0}, at=0.5)
    fleet.put("auv1", "auv1/sensors/b/temp", {"celsius": 20.0}, at=0.6)
    fleet.put("auv2", "auv2/sensors/a/temp", {"celsius": 5.0}, at=0.7)
    fleet.put("auv1", "auv1/sensors/zz/temp", {"celsius": 1.0}, at=0.8)  # not a member
    fleet.put("auv1", "auv1/sensors/a/temp", {"celsius": 11.0}, at=4.0)
    fleet.run_until(12.0)
    got = values(fleet, "top")
    assert got["auv1/sensors/a/temp"] == [{"celsius": 10.0}, {"celsius": 11.0}]
    assert got["auv1/sensors/b/temp"] == [{"celsius": 20.0}]
    assert got["auv2/sensors/a/temp"] == [{"celsius": 5.0}]
    assert not any("zz" in key for key in got)
    assert fleet.cores["auv1"].stats.payloads_dropped["auv1/sensors/zz/temp"] == 1
    snap = fleet.cores["auv1"].snapshot(12.0)["families"]
    assert set(snap["members"]["temps"]) == {"a", "b"}  # each member keeps its own age
    assert snap["members"]["temps"]["a"] == pytest.approx(8.0)
    assert snap["members"]["temps"]["b"] == pytest.approx(11.4)
    ages = fleet.cores["top"].snapshot(12.0)["families"]["member_age_s"]
    assert ages["auv1/sensors/a/temp"] < ages["auv1/sensors/b/temp"]


def test_node_members_reach_each_vehicle() -> None:
    fleet = wanting()
    fleet.put("top", "fleet/auv1/depth_order", {"depth_m": 12.5})
    fleet.put("top", "fleet/auv2/depth_order", {"depth_m": 30.0})
    fleet.run_until(5.0)
    for auv in ("auv1", "auv2"):
        got = values(fleet, auv)
        assert got["fleet/auv1/depth_order"][0] == {"depth_m": 12.5}
        assert got["fleet/auv2/depth_order"][0] == {"depth_m": 30.0}


def test_learned_family_names_members_and_stops_at_its_bound() -> None:
    fleet = wanting()
    names = [f"c{i}" for i in range(10)]
    for i, name in enumerate(names):
        fleet.put("auv1", f"auv1/contacts/{name}", {"range_m": 100 + i, "bearing_deg": 2 * i})
    fleet.run_until(30.0)
    got = values(fleet, "top")
    learned = {k for k in got if k.startswith("auv1/contacts/")}
    assert learned == {f"auv1/contacts/c{i}" for i in range(8)}
    assert got["auv1/contacts/c3"][0] == {"range_m": 103, "bearing_deg": 6}
    auv1 = fleet.cores["auv1"]
    assert auv1.snapshot(30.0)["families"]["keys_refused"] == {"contacts": 2}
    assert auv1.stats.payloads_dropped["auv1/contacts/c8"] == 1
    assert auv1.stats.payloads_dropped["auv1/contacts/c9"] == 1


def test_a_value_of_an_unnamed_member_is_dropped_until_its_name_arrives() -> None:
    loaded = load_mission(ZSPACE)
    auv1, top = NodeCore(loaded, "auv1"), NodeCore(loaded, "top")
    assert auv1.interest is not None
    auv1.interest.on_heard("top", range(len(loaded.table)), 0.0)  # top wants everything
    auv1.ingest("auv1/contacts/buoy", b'{"range_m": 7, "bearing_deg": 4}', "application/json", 0.0)
    first = auv1.outbound.build(0.0, 0.0)
    assert first is not None and [x.channel.name for x in first.extras] == ["@want", "@key"]
    auv1.outbound.sent(first, 0.0)
    # a receiver that missed the names: the member's values are refused, counted
    entry = FrameCodec(loaded.table).decode(first.data)
    bare = [e for e in entry.entries if e.channel.name == "contacts"]
    data = FrameCodec(loaded.table).encode([(bare[0].channel, auv1.families.senders[1]
                                             .states[0].payload())])
    top.receive(Reception(data, 2, 0.5), 0.5)
    assert top.stats.frames_dropped["unknown_member"] == 1 and not top.take()[0:0]
    top.receive(Reception(first.data, 2, 1.0), 1.0)
    published = [o for o in top.take() if o.__class__.__name__ == "Publish"]
    assert [(p.key, p.value) for p in published] == [("auv1/contacts/buoy",
                                                      {"range_m": 7, "bearing_deg": 4})]


def test_entry_bits_and_mismatched_families_are_refused() -> None:
    loaded = load_mission(ZSPACE)
    codec = FrameCodec(loaded.table)
    temps = loaded.table.by_name("temps")
    assert temps.family is not None and temps.family.index_bits == 2
    assert codec.channel_cost_bits(temps) == codec.index_bits + 2 + temps.bits
    data = codec.encode([(temps, (2 << temps.bits) | 5)])
    (entry,) = codec.decode(data).entries
    assert entry.header == (2,)
    with pytest.raises(FrameError):  # member 3 of 3 does not exist
        codec.decode(codec.encode([(temps, (3 << temps.bits) | 5)]))
    other = parse_mission(ZSPACE.read_text().replace("keys: [a, b, c]", "keys: [a, b, d]"))
    assert other.table.fingerprint != loaded.table.fingerprint
    with pytest.raises(FrameError):
        FrameCodec(other.table).decode(data)


def test_mission_errors_name_the_element() -> None:
    text = ZSPACE.read_text()
    with pytest.raises(MissionError, match=r"elements\[0\]\.out.*\{key\}"):
        parse_mission(text.replace('out: "{src}/sensors/{key}/temp"', 'out: "{src}/temp"'))
    with pytest.raises(MissionError, match=r"elements\[0\]\.in"):
        parse_mission(text.replace('in: "{node}/sensors/*/temp"', 'in: "{node}/sensors/temp"'))
    with pytest.raises(MissionError, match="twice"):
        parse_mission(text.replace("keys: [a, b, c]", "keys: [a, b, a]"))
    # each form's mistake in that form's terms (before: "Input should be a valid list" first,
    # then one line per other form)
    for keys, said in [("{learn: 0}", r"channels\[1\]\.keys\.learn: Input should be greater "
                        r"than or equal to 1 \(got 0\)$"),
                       ("{learn: 2, nodes: auv1}", r"channels\[1\]\.keys\.learn: unknown key"),
                       ("5", r"channels\[1\]\.keys: keys are a list of member names, "
                        r"\{nodes: pattern\} or \{learn: n\} \(got 5\)$")]:
        with pytest.raises(MissionError) as info:
            parse_mission(text.replace("keys: {learn: 8, name_bytes: 8}", f"keys: {keys}"))
        (line,) = str(info.value).splitlines()
        assert re.search(said, line), line


def test_check_shows_the_index_bits_and_warns_about_a_bare_wildcard(tmp_path: Path) -> None:
    runner = CliRunner()
    data = json.loads(runner.invoke(app, ["check", str(ZSPACE), "--json"]).output)
    keys = {c["name"]: c["keys"] for c in data["channels"]}
    assert keys["temps"]["index_bits"] == 2 and keys["temps"]["members"] == ["a", "b", "c"]
    assert keys["contacts"] == {"members": None, "bound": 8, "learned": True, "index_bits": 3,
                                "name_bytes": 8}
    assert keys["fleet_depth"]["members"] == ["auv1", "auv2"]
    assert data["key_entry_bits"] == data["index_bits"] + 3 + 64
    text = runner.invoke(app, ["check", str(ZSPACE)]).output
    assert "+2 bits (3 keys)" in text and "+3 bits (learned ≤ 8)" in text
    bare = tmp_path / "bare.yaml"
    bare.write_text(ZSPACE.read_text().replace("    keys: [a, b, c]\n", "")
                    .replace('"{src}/sensors/{key}/temp"', '"{src}/temp"'))
    bare_data = json.loads(runner.invoke(app, ["check", str(bare), "--json"]).output)
    assert any("wildcard" in w for w in bare_data["warnings"])


def test_fast_sim_feeds_every_member(tmp_path: Path) -> None:
    report = tmp_path / "r.json"
    result = CliRunner().invoke(app, ["sim", str(ZSPACE), "--fast", "--duration", "60",
                                      "--report", str(report)])
    assert result.exit_code == 0, result.output
    top = json.loads(report.read_text())["nodes"]["top"]["families"]["member_age_s"]
    assert {f"auv{i}/sensors/{m}/temp" for i in (1, 2) for m in "abc"} <= set(top)
    assert {f"auv1/contacts/k{i}" for i in range(8)} <= set(top)


def test_a_mission_log_replays_each_member_on_its_own_key(tmp_path: Path) -> None:
    loaded = load_mission(ZSPACE)
    logs = FleetLogs(tmp_path, loaded)
    try:
        asyncio.run(run_fast(loaded, duration=30.0, record=logs))
    finally:
        logs.close()
    keys = {got.key for got in received_values(read_log(logs.path_of("top")))}
    assert {f"auv1/sensors/{m}/temp" for m in "abc"} <= keys
    assert not any("*" in key for key in keys)
