"""What a newcomer reads first: help screens and `zab check` messages, one error per cause."""

from __future__ import annotations

import json
import re
from importlib.metadata import version
from pathlib import Path

import pytest
from typer.testing import CliRunner

from bridge.cli.app import app
from tests.mission.test_mission_file import GOOD, error_of

COMMANDS = ["check", "schema", "run", "water", "emulate", "sim", "demo", "gui", "doctor",
            "listen", "put", "log summary", "log replay"]


def help_of(*args: str) -> str:
    result = CliRunner().invoke(app, [*args, "-h"], terminal_width=100)
    assert result.exit_code == 0, result.output
    return result.output


@pytest.mark.parametrize("command", COMMANDS)
def test_flags_are_shown_as_flags(command: str) -> None:
    text = help_of(*command.split())
    assert "<bool>" not in text
    assert "--help" in text and "-h" in text


def test_root_help_lists_whole_sentences_and_the_version() -> None:
    text = help_of()
    rows = [line for line in text.splitlines() if line.startswith("│ ")]
    for row in rows:  # a summary never stops mid-sentence at a source line break
        assert not re.search(r"\b(can|the|and|or|with|Zenoh)\s*│$", row), row
    assert "check    Validate a mission; show channel sizes, frame fill and airtime." in text
    result = CliRunner().invoke(app, ["--version"])
    assert result.exit_code == 0
    assert result.output.strip() == f"zab {version('zenoh-acoustic-bridge')}"


def test_paragraphs_flow_and_every_option_has_help() -> None:
    text = help_of("log", "replay")
    assert "Without --connect/--listen it listens on tcp/127.0.0.1:7447." in text
    for command in ("sim", "run", "gui"):
        verbose = next(line for line in help_of(command).splitlines() if "--verbose" in line)
        assert "Log debug messages too." in verbose


def test_sim_log_help_is_not_cut() -> None:
    text = " ".join(line.strip("│ ") for line in help_of("sim").splitlines())
    assert "…" not in text
    assert "one MCAP file per node in this folder." in re.sub(r"\s+", " ", text)


def test_readme_lists_every_command() -> None:
    readme = (Path(__file__).parents[2] / "README.md").read_text(encoding="utf-8")
    for command in COMMANDS:
        assert f"zab {command}" in readme, command


def test_min_above_max_is_one_error_at_max() -> None:
    message = error_of(GOOD.replace("{field: x, bits: 8, min: 0, max: 10}",
                                    "{field: x, resolution: 1, min: 10, max: 0}"))
    assert message.splitlines() == [
        "m.yaml:15:48: channels[0].elements[0].fields[0].max: max must be > min "
        "(min=10.0, max=0.0)"]


def test_bits_out_of_range_says_got_once() -> None:
    message = error_of(GOOD.replace("bits: 8", "bits: 600"))
    assert message == "m.yaml:15:24: channels[0].elements[0].fields[0].bits: bits must be " \
                      "1..64 (got 600)"


def test_a_global_frame_size_is_reported_once_where_it_is_set() -> None:
    text = GOOD.replace("mac: {type", "wire: {auth: {tag_bytes: 8}}\nmodem: {frame_bytes: 14}\n"
                        "mac: {type")
    message = error_of(text)
    assert message.splitlines() == [
        "m.yaml:6:9: modem.frame_bytes: 14 bytes cannot hold the 14-byte frame overhead"]


def test_check_json_on_an_invalid_file_prints_the_errors(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text(GOOD.replace("bits: 8", "bits: 600"), encoding="utf-8")
    result = CliRunner().invoke(app, ["check", str(bad), "--json"])
    assert result.exit_code == 2
    data = json.loads(result.stdout)
    assert data == {"ok": False, "errors": [{
        "file": str(bad), "line": 15, "column": 24,
        "path": "channels[0].elements[0].fields[0].bits",
        "message": "bits must be 1..64 (got 600)"}]}
    missing = CliRunner().invoke(app, ["check", str(tmp_path / "nope.yaml"), "--json"])
    assert missing.exit_code == 2
    assert "no such mission file" in json.loads(missing.stdout)["errors"][0]["message"]


def test_markdown_help_keeps_placeholders() -> None:
    text = help_of("schema")
    assert "schemas/payloads/MISSION/" in text.replace("│", "").replace("\n", "").replace(" ", "")


def test_version_and_help_have_their_usual_spellings() -> None:
    short = CliRunner().invoke(app, ["-V"])
    assert short.exit_code == 0
    assert short.output.strip() == f"zab {version('zenoh-acoustic-bridge')}"
    assert CliRunner().invoke(app, ["help"], terminal_width=100).output == help_of()
    assert CliRunner().invoke(app, ["help", "sim"], terminal_width=100).output == help_of("sim")
    assert CliRunner().invoke(app, ["help", "log", "replay"], terminal_width=100).output == \
        help_of("log", "replay")
    unknown = CliRunner().invoke(app, ["help", "nope"])
    assert unknown.exit_code == 2 and "No such command 'nope'" in unknown.output


def test_put_help_shows_a_value_the_shipped_missions_take() -> None:
    text = " ".join(help_of("put").replace("│", "").split())
    assert """'{"vector": {"x": 1.5, "y": 0.01}}'""" in text  # target_reference's fields


def test_check_help_says_fragments_are_no_failure() -> None:
    text = " ".join(help_of("check").replace("│", "").split())
    assert "Exit 1 if something can never be sent" in text
    assert "a value larger than a frame travels in fragments and is only a warning" in text
    assert "it says that zab run will need one" in text


def test_counts_agree_with_their_number() -> None:
    from bridge.words import counted

    assert [counted(n, "bit") for n in (0, 1, 2)] == ["0 bits", "1 bit", "2 bits"]
    assert counted(1, "value") == "1 value" and counted(3, "query", "queries") == "3 queries"
