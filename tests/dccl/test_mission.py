"""DCCL messages as channel elements: mission loading, bad .proto files, the frame bytes."""

from __future__ import annotations

from pathlib import Path
from typing import get_args

import pytest

from bridge.core.loaded import load_mission, parse_mission
from bridge.dccl import DEFAULT_RULE, RULES, load_message
from bridge.dccl.layout import DcclLayout
from bridge.errors import MissionError
from bridge.mission.model import Dccl
from bridge.report.check import check_mission
from tests.dccl.conftest import PROTOS

EXAMPLE = Path(__file__).parents[2] / "deploy" / "missions" / "goby_dccl.yaml"
NAV = {"lat": 41.52, "lon": -70.67, "depth": 12.3, "heading": 271.5, "speed": 1.25,
       "battery": 87, "mode": "survey", "time": 43210}


def _mission(element: str) -> str:
    return f"""
mission: m
nodes:
  a: {{address: 0}}
  b: {{address: 1}}
channels:
  - name: c
    from: a
    to: b
    elements:
      - in: x
        out: y
{element}
"""


def test_example_mission_passes_check_and_reports_the_bit_budget() -> None:
    loaded = load_mission(EXAMPLE)
    report = check_mission(loaded)
    assert report.ok
    nav = next(d for d in report.data["dccl"] if d["channel"] == "nav")
    assert "1. lat................................28 {dccl.default4}" in nav["analysis"]
    assert nav["max_bytes"] == 17


def test_element_bytes_are_libdccls() -> None:
    """The channel's bits are the DCCL message bytes (zero-padded to its maximum size)."""
    table = load_mission(EXAMPLE).table
    channel = table.by_name("nav")
    layout = channel.elements[0].layout
    assert isinstance(layout, DcclLayout)
    dccl = load_message(EXAMPLE.parent / "dccl" / "auv.proto", "NavStatus").encode(NAV)
    n = channel.pack([NAV])
    assert n.to_bytes(channel.bits // 8, "big") == dccl.ljust(layout.nbytes, b"\0")
    assert channel.unpack(n)[0] == {**NAV, "lat": pytest.approx(41.52), "lon": -70.67}


def test_relative_proto_path_is_from_the_mission_file(tmp_path: Path) -> None:
    (tmp_path / "defs").mkdir()
    (tmp_path / "defs" / "g.proto").write_text((PROTOS / "golden.proto").read_text())
    text = _mission("        dccl: defs/g.proto:Golden")
    (tmp_path / "m.yaml").write_text(text)
    loaded = load_mission(tmp_path / "m.yaml")
    assert loaded.table.channels[0].bits == 8 * 18


@pytest.mark.parametrize(("element", "expected"), [
    (f"        dccl: {PROTOS}/bad.proto:NoBounds", "bad.proto:7: missing (dccl.field).max"),
    (f"        dccl: {PROTOS}/unknown_option.proto:M",
     'unknown_option.proto:7: Option "(dccl.field).minimum" unknown'),
    (f"        dccl: {PROTOS}/golden.proto", "expected 'file.proto:Message'"),
    ("        dccl: nowhere.proto:M", "no such .proto file"),
    (f"        dccl: {PROTOS}/golden.proto:Golden\n        fields: [{{field: a, type: bool}}]",
     "give either fields"),
])
def test_bad_dccl_elements_fail_with_location(element: str, expected: str) -> None:
    with pytest.raises(MissionError) as info:
        parse_mission(_mission(element), "m.yaml")
    text = str(info.value)
    assert expected in text
    assert text.startswith("m.yaml:13:") or "give either" in text


def test_synthetic_values_for_simulations_are_valid() -> None:
    import random

    from bridge.cli.sim_fast import synthetic_value

    rng = random.Random(3)
    for channel in load_mission(EXAMPLE).table.channels:
        layout = channel.elements[0].layout
        for _ in range(20):
            value = synthetic_value(layout, rng)
            assert layout.message.decode(layout.message.encode(value, strict=True)) == value


def test_payload_schema_accepts_what_the_message_encodes() -> None:
    import jsonschema

    from bridge.wire.payload_schema import adapt_schema

    table = load_mission(EXAMPLE).table
    nav = adapt_schema(table.by_name("nav").elements[0].layout.json_schema(), "in")
    jsonschema.validate(NAV, nav)
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({**NAV, "mode": "sideways"}, nav)
    command = adapt_schema(table.by_name("command").elements[0].layout.json_schema(), "in")
    jsonschema.validate({"mode": 3, "note": "hi"}, command)  # enums also by value number
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({"note": "hi"}, command)  # mode is required


def test_reject_is_dccl_strict_mode() -> None:
    """on_out_of_range: reject → libdccl's strict mode (the value is refused, not zeroed)."""
    from bridge.errors import EncodeError

    table = load_mission(EXAMPLE).table
    command = table.by_name("command").elements[0].layout
    nav = table.by_name("nav").elements[0].layout
    with pytest.raises(EncodeError):
        command.pack({"mode": "dive", "goto_lat": 91.0})
    assert "lat" in nav.unpack(nav.pack({**NAV, "lat": 91.0}))  # clamp: required → its min
    assert nav.unpack(nav.pack({**NAV, "lat": 91.0}))["lat"] == -90.0


def test_json_schema_of_every_codec_kind() -> None:
    """Every field codec has a schema (version 3 strings and fixed bytes included)."""
    for name in ("Golden", "Nested", "Choice", "V3Msg", "Coarse"):
        layout = DcclLayout(load_message(PROTOS / "golden.proto", name))
        schema = layout.json_schema()
        assert schema["type"] == "object" and schema["properties"]


def test_fingerprint_depends_on_the_bits_not_on_where_the_proto_is(tmp_path: Path) -> None:
    """Two nodes with the same .proto in different folders agree on the mission fingerprint;
    a changed bound changes it."""
    text = (PROTOS / "golden.proto").read_text()
    prints = []
    for folder, body in (("a", text), ("b/c", "\n\n" + text),
                         ("d", text.replace("max: 3000", "max: 3001"))):
        (tmp_path / folder).mkdir(parents=True)
        (tmp_path / folder / "g.proto").write_text(body)
        loaded = parse_mission(_mission(f"        dccl: {tmp_path / folder}/g.proto:Golden"),
                               "m.yaml")
        prints.append(loaded.table.fingerprint)
    assert prints[0] == prints[1] != prints[2]


def _with_dccl(dccl: str, element: str) -> str:
    """A mission whose `dccl:` section is ``dccl`` (YAML lines) and whose element is
    ``element``."""
    return _mission(element).replace("channels:", f"dccl:\n{dccl}\nchannels:", 1)


def test_the_mission_picks_the_numeric_rule_and_check_says_it() -> None:
    """dccl-4.2 (the latest release's rule) unless the mission says dccl-2026; the two write
    Tie{x: 0.25} differently, so they are different wires (fingerprints)."""
    element = f"        dccl: {PROTOS}/golden.proto:Tie"
    default = parse_mission(_mission(element), "m.yaml")
    chosen = parse_mission(_with_dccl("  numeric: dccl-2026", element), "m.yaml")
    layouts = [m.table.channels[0].elements[0].layout for m in (default, chosen)]
    assert [lay.message.rule for lay in layouts] == ["dccl-4.2", "dccl-2026"]
    assert [lay.encode({"x": 0.25}).hex() for lay in layouts] == ["0c03", "0c02"]
    assert default.table.fingerprint != chosen.table.fingerprint
    numeric = check_mission(chosen).data["dccl_numeric"]
    assert numeric == {"rule": "dccl-2026", "libdccl": RULES["dccl-2026"]}


def test_the_cli_check_prints_the_rule() -> None:
    from typer.testing import CliRunner

    from bridge.cli.app import app

    result = CliRunner().invoke(app, ["check", str(EXAMPLE), "--no-key"])
    assert f"DCCL numeric rule: dccl-4.2, as {RULES['dccl-4.2']}" in result.output


def test_an_unknown_rule_is_refused_with_the_choices() -> None:
    with pytest.raises(MissionError) as info:
        parse_mission(_with_dccl("  numeric: dccl-5", f"        dccl: {PROTOS}/golden.proto:Tie"),
                      "m.yaml")
    assert "m.yaml:" in str(info.value) and "dccl.numeric" in str(info.value)
    assert "'dccl-4.2' or 'dccl-2026'" in str(info.value)


def test_the_mission_model_offers_exactly_the_rules() -> None:
    """The mission file's choices and default are bridge.dccl's rules (the model stays free of
    DCCL imports)."""
    field = Dccl.model_fields["numeric"]
    assert set(get_args(field.annotation)) == set(RULES)
    assert field.default == DEFAULT_RULE


def test_proto_path_is_an_include_path_from_the_mission_file(tmp_path: Path) -> None:
    """An import found only in a proto_path folder (relative to the mission file) loads; without
    proto_path, protoc's own message at the importing line."""
    (tmp_path / "defs").mkdir()
    (tmp_path / "inc" / "lab").mkdir(parents=True)
    (tmp_path / "inc" / "lab" / "units.proto").write_text(
        'syntax = "proto2";\npackage lab;\nenum Unit { METRE = 0; FOOT = 1; }\n')
    (tmp_path / "defs" / "m.proto").write_text(
        'syntax = "proto2";\nimport "dccl/option_extensions.proto";\nimport "lab/units.proto";\n'
        "message M {\n  option (dccl.msg) = { id: 3 max_bytes: 4 codec_version: 4 };\n"
        "  required lab.Unit unit = 1;\n}\n")
    element = "        dccl: defs/m.proto:M"
    (tmp_path / "ok.yaml").write_text(_with_dccl("  proto_path: [inc]", element))
    layout = load_mission(tmp_path / "ok.yaml").table.channels[0].elements[0].layout
    assert layout.message.decode(layout.encode({"unit": "FOOT"})) == {"unit": "FOOT"}
    (tmp_path / "bad.yaml").write_text(_mission(element))
    with pytest.raises(MissionError, match=r'm.proto:3: Import "lab/units.proto" was not found'):
        load_mission(tmp_path / "bad.yaml")
    (tmp_path / "gone.yaml").write_text(_with_dccl("  proto_path: [nowhere]", element))
    with pytest.raises(MissionError, match=r"proto_path .*nowhere.* is not a folder"):
        load_mission(tmp_path / "gone.yaml")
