"""``zab check``'s DCCL bit budget, laid out like ``dccl --analyze``."""

from __future__ import annotations

from bridge.dccl import load_message
from bridge.dccl.analyze import analyze
from tests.dccl.conftest import PROTOS


def test_sizes_per_field_with_ranges_for_variable_ones() -> None:
    text = analyze(load_message(PROTOS / "golden.proto", "Nested"))
    lines = text.splitlines()
    assert lines[0].strip("=") == " 200: zab.test.Nested "
    assert "Actual maximum size of message: 25 bytes / 200 bits" in lines
    assert "        dccl.id head..........................16" in lines
    assert "        1. seq.................................4 {dccl.default4}" in lines
    # optional embedded message: presence bit alone when absent, up to every field
    assert "        2. a................................1-42 {dccl.default4}" in lines
    assert "                2. raw..............................1-27 {dccl.default4}" in lines
    assert "        4. c[1-2]..........................16-83 {dccl.default4}" in lines
    assert "zab.test.Nested...........................38-172 {dccl.default4}" in lines


def test_oneof_block() -> None:
    lines = analyze(load_message(PROTOS / "golden.proto", "Choice")).splitlines()
    start = lines.index("        0. what [oneof].....................2-28 {")
    depth = "            2. depth..............................10 {dccl.default4}"
    assert lines[start + 1] == depth
    assert lines[start + 4] == "        }"
