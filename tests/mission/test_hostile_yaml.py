"""Tiny hostile mission files: a clear "not a mission" message and exit 2, quickly and in
bounded memory, never a traceback.

Found from outside: an integer of 4301 digits raised ValueError, 1000 levels of nested lists
RecursionError, and a 9-line alias bomb (7 levels of ``&a [*b, *b, ...]``) built for minutes
at gigabytes."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from bridge.cli.app import app
from bridge.core.loaded import parse_mission
from bridge.errors import MissionError

HEAD = "mission: x\nnodes: {a: {address: 1}}\n"


def _bomb(levels: int) -> str:
    lines = ["  l0: &l0 [x,x,x,x,x,x,x,x,x]"]
    lines += [f"  l{i}: &l{i} [{','.join([f'*l{i - 1}'] * 9)}]" for i in range(1, levels)]
    return HEAD + "zz:\n" + "\n".join(lines) + "\n"


CASES = {
    "huge integer": ("mission: x\nnodes:\n  a: {address: " + "9" * 4301 + "}\n",
                     "m.yaml:3:16: nodes.a.address: cannot read this value: Exceeds the limit "
                     "(4300 digits)"),
    "deep lists": (HEAD + "zz: " + "[" * 1000 + "]" * 1000 + "\n",
                   "m.yaml:3:105: zz: nested deeper than 100 levels"),
    "deep in a value": ("mission: x\nnodes: {a: {address: 1, position: " + "[" * 1000
                        + "]" * 1000 + "}}\n", "nested deeper than 100 levels"),
    "self alias": (HEAD + "zz: &a [*a]\n", "nested deeper than 100 levels"),
    "alias bomb": (_bomb(7), "m.yaml: invalid YAML: more than 1,000,000 values"),
    "list as a key": (HEAD + "? [1, 2]\n: 3\n", "unsupported key"),
}


@pytest.mark.parametrize("case", CASES)
def test_hostile_files_are_refused_quickly(case: str) -> None:
    text, message = CASES[case]
    start = time.monotonic()
    with pytest.raises(MissionError) as info:
        parse_mission(text, "m.yaml")
    assert time.monotonic() - start < 5, case
    assert message in str(info.value)


def test_cli_says_so_with_exit_2(tmp_path: Path) -> None:
    for case, (text, message) in CASES.items():
        (tmp_path / "m.yaml").write_text(text)
        result = CliRunner().invoke(app, ["check", str(tmp_path / "m.yaml")])
        assert result.exit_code == 2, (case, result.output)
        assert message.removeprefix("m.yaml") in result.output, (case, result.output)
        assert result.exception is None or isinstance(result.exception, SystemExit), case

