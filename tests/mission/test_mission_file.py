"""Mission-file mistakes: each gives a message with file:line:column and the field path."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

from bridge.cli.app import app
from bridge.core.loaded import load_mission, parse_mission
from bridge.errors import MissionError

GOOD = """\
mission: tiny
nodes:
  a: {address: 1, zenoh: {listen: [tcp/127.0.0.1:7001]}}
  b: {address: 2}
mac: {type: tdma, slot_s: 2.0, guard_s: 0.1, order: [a, b]}
channels:
  - name: pose
    from: a
    to: b
    interval_s: 5
    elements:
      - in: pose
        out: a/pose
        fields:
          - {field: x, bits: 8, min: 0, max: 10}
"""


def error_of(text: str) -> str:
    with pytest.raises(MissionError) as info:
        parse_mission(text, "m.yaml")
    return str(info.value)


def test_good_mission_loads() -> None:
    loaded = parse_mission(GOOD, "m.yaml")
    assert loaded.table.by_name("pose").bits == 8
    assert loaded.table.by_name("pose").receivers == ("b",)


@pytest.mark.parametrize(
    ("old", "new", "line", "path", "words"),
    [
        ("    interval_s: 5", "    interval_s: 5\n    latchin: true", 11, "channels[0].latchin",
         "unknown key"),
        ("bits: 8", "bits: eight", 15, "channels[0].elements[0].fields[0].bits", "integer"),
        ("    to: b\n", "", 7, "channels[0].to", "required"),
        ("    from: a", "    from: z+", 8, "channels[0].from", "matches no node"),
        ("    from: a", "    from: '('", 8, "channels[0].from", "regex"),
        ("order: [a, b]", "order: [a, c]", 5, "mac.order[1]", "unknown node 'c'"),
        ("slot_s: 2.0", "slot_s: -1", 5, "mac.slot_s", "greater than 0"),
        ("  b: {address: 2}", "  b: {address: 1}", 4, "nodes.b.address", "already used"),
        ("bits: 8, min: 0, max: 10", "bits: 8", 15, "channels[0].elements[0].fields[0]",
         "min"),
        ("out: a/pose", "out: '{who}/pose'", 13, "channels[0].elements[0].out", "{who}"),
        ("{field: x, bits: 8, min: 0, max: 10}", "{field: x, codec: no.such}", 15,
         "channels[0].elements[0].fields[0]", "no.such"),
        ("mac: {type: tdma", "mac: {type: csma", 5, "mac", "type"),
    ],
)
def test_mistakes_are_located(old: str, new: str, line: int, path: str, words: str) -> None:
    assert old in GOOD
    message = error_of(GOOD.replace(old, new, 1))
    first = message.splitlines()[0]
    assert first.startswith(f"m.yaml:{line}:"), message
    assert path in first, message
    assert words.lower() in message.lower(), message


def test_duplicate_channel_name() -> None:
    text = GOOD + GOOD[GOOD.index("  - name: pose"):]
    message = error_of(text)
    assert re.match(r"m\.yaml:16:\d+: channels\[1\]\.name: .*already used", message), message


def test_yaml_syntax_and_duplicate_keys() -> None:
    assert error_of(GOOD.replace("to: b", "to: [b")).startswith("m.yaml:")
    message = error_of(GOOD.replace("    to: b\n", "    to: b\n    to: a\n"))
    assert message.startswith("m.yaml:10:") and "duplicate key 'to'" in message


def test_not_a_mapping_and_empty() -> None:
    assert "mapping" in error_of("- a\n- b\n")
    assert "empty" in error_of("")


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(MissionError, match="no such mission file"):
        load_mission(tmp_path / "nope.yaml")


def test_cli_exit_2_without_traceback(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text(GOOD.replace("bits: 8", "bits: eight"))
    result = CliRunner().invoke(app, ["check", str(bad)])
    assert result.exit_code == 2
    output = result.output + (result.stderr if result.stderr_bytes is not None else "")
    assert "Traceback" not in output
    assert f"{bad}:15:" in output.replace("\n", "")


def test_zenoh_extra_keys_pass_through() -> None:
    loaded = parse_mission(GOOD.replace(
        "zenoh: {listen: [tcp/127.0.0.1:7001]}",
        'zenoh: {listen: [tcp/127.0.0.1:7001], "transport/link/tx/lease": 2000}'), "m.yaml")
    assert loaded.mission.nodes["a"].zenoh.passthrough() == {"transport/link/tx/lease": 2000}


def test_frame_too_small_for_the_overhead_counts_the_auth_tag() -> None:
    text = GOOD.replace("mac: {type", "wire: {auth: {tag_bytes: 8}}\nmac: {type").replace(
        "  a: {address: 1,", "  a: {address: 1, modem: {frame_bytes: 14},")
    message = error_of(text)  # 2 B check + 4 B counter + 8 B tag = 14 B
    assert "nodes.a.modem.frame_bytes" in message and "14-byte frame overhead" in message


@pytest.mark.parametrize(
    ("old", "new", "line", "path"),
    [
        ("    interval_s: 5", "    interval_s: .inf", 10, "channels[0].interval_s"),
        ("slot_s: 2.0", "slot_s: .inf", 5, "mac.slot_s"),
        ("guard_s: 0.1", "guard_s: .nan", 5, "mac.guard_s"),
        ("  b: {address: 2}", "  b: {address: 2, position: {x: .nan}}", 4,
         "nodes.b.position.x"),
        ("min: 0, max: 10", "min: -.inf, max: 10", 15,
         "channels[0].elements[0].fields[0].min"),
        ("min: 0, max: 10", "min: 0, max: .nan", 15, "channels[0].elements[0].fields[0].max"),
        ("    interval_s: 5", "    interval_s: 5\n    age: {step_s: 1, max_s: .inf}", 11,
         "channels[0].age.max_s"),
    ],
)
def test_inf_and_nan_are_refused_wherever_a_number_is(old: str, new: str, line: int,
                                                        path: str) -> None:
    """`.inf`/`.nan` (YAML) are no time, bound or position: every mission model refuses them,
    at the key that has one (an infinite interval_s or age.max_s passed before)."""
    assert old in GOOD
    message = error_of(GOOD.replace(old, new))
    assert f"m.yaml:{line}:" in message
    assert f"{path}: must be a finite number" in message
    assert "write the number meant" in message


@pytest.mark.parametrize(("old", "new", "line", "path"), [
    ("    from: a", "    from: []", 8, "channels[0].from"),
    ("    to: b", "    to: []", 9, "channels[0].to"),
])
def test_an_empty_node_list_is_told_where_it_is(old: str, new: str, line: int,
                                                 path: str) -> None:
    """`from: []` was reported at channels[0].to ("must reach a node other than its
    sender"): the empty list is the mistake, and it is said there."""
    message = error_of(GOOD.replace(old, new))
    assert f"m.yaml:{line}:5: {path}: an empty list names no node" in message
    assert "give at least one node name" in message


@pytest.mark.parametrize(("old", "new", "line", "path", "words"), [
    ("    interval_s: 5", "    interval_s: 5\n    queue: 100", 11, "channels[0].queue",
     "queue is a reliable channel's setting"),
    ("    interval_s: 5", "    interval_s: 5\n    overflow: drop_oldest", 11,
     "channels[0].overflow", "give reliable: true, or remove overflow"),
    ("    interval_s: 5", "    interval_s: 5\n    age: {step_s: 2, max_s: 1}", 11,
     "channels[0].age.max_s", "max_s 1 is shorter than one step (2 s)"),
])
def test_settings_that_would_do_nothing_are_refused(old: str, new: str, line: int, path: str,
                                                    words: str) -> None:
    """A queue on a channel that is not reliable (it holds only its latest value), and an
    age that cannot count one step, were accepted without a word."""
    message = error_of(GOOD.replace(old, new))
    assert f"m.yaml:{line}:" in message and f"{path}: " in message and words in message


def test_queue_settings_of_a_reliable_channel_load() -> None:
    text = GOOD.replace("    interval_s: 5",
                        "    interval_s: 5\n    reliable: true\n    queue: 100\n"
                        "    overflow: drop_oldest")
    channel = parse_mission(text, "m.yaml").mission.channels[0]
    assert (channel.queue, channel.overflow) == (100, "drop_oldest")
