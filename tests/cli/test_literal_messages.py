"""User and exception text in the CLI's messages prints as it is: never read as rich markup
(``[/]``, ``[bold]``) or emoji (``:100:``), never a traceback.

Found from outside: a ``from: "zz[/]"`` raised rich's MarkupError, ``zz[bold]x`` printed as
``zzx``, an error at line 100 as ``💯``, and ``zab put … '[true, x]'`` lost its value."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from bridge.cli.app import app
from tests.conftest import MISSIONS, free_port

RUNNER = CliRunner()

MARKUP = """mission: x
nodes:
  a: {address: 1}
  b: {address: 2}
mac: {type: tdma, slot_s: 2, order: [a, b]}
channels:
  - name: c
    from: "FROM"
    to: b
    elements:
      - in: k
        out: k2
        fields: [{field: v, bits: 8, min: 0, max: 1}]
"""


def _at_line(line: int) -> str:
    """A mission whose one mistake (an unknown key) is at ``line``."""
    return "mission: x\nnodes: {a: {address: 1}}\n" + "#\n" * (line - 3) + "bogus: 1\n"


def _case(tmp_path: Path, case: str) -> tuple[list[str], int, str]:
    """(arguments, exit code, a literal text the output must hold) of one case."""
    line = str(MISSIONS / "acoustic_line.yaml")
    port = free_port()
    if case == "from [/]":
        (tmp_path / "m.yaml").write_text(MARKUP.replace("FROM", "zz[/]"))
        return ["check", str(tmp_path / "m.yaml")], 2, "zz[/]"
    if case == "from [bold]":
        (tmp_path / "m.yaml").write_text(MARKUP.replace("FROM", "zz[bold]x"))
        return ["check", str(tmp_path / "m.yaml")], 2, "zz[bold]x"
    if case in ("line 100", "line 1234"):
        number = int(case.split()[1])
        (tmp_path / "m.yaml").write_text(_at_line(number))
        return ["check", str(tmp_path / "m.yaml")], 2, f"m.yaml:{number}:1:"
    if case == "file name":
        return ["check", str(tmp_path / "line[v2].yaml")], 2, "line[v2].yaml"
    if case == "run --node":
        return ["run", line, "--node", "[/]"], 2, "'[/]'"
    if case == "gui --node":
        return ["gui", line, "--node", "[/]", "--port", "0"], 2, "[/]"
    if case == "log file":
        return ["log", "summary", str(tmp_path / "[/].mcap")], 2, "[/].mcap"
    if case == "put value":
        return ["put", f"tcp/127.0.0.1:{port}", "a", '{"x":[/]1}'], 2, "[/]"
    if case == "put list":
        return ["put", f"tcp/127.0.0.1:{port}", "a", "[true, x]"], 2, "[true, x]"
    assert case == "listen endpoint"
    return ["listen", f"tcp/127.0.0.1:{port}[/]", "a"], 2, "[/]"


@pytest.mark.parametrize("case", ["from [/]", "from [bold]", "line 100", "line 1234",
                                  "file name", "run --node", "gui --node", "log file",
                                  "put value", "put list", "listen endpoint"])
def test_user_text_prints_literally(tmp_path: Path, case: str) -> None:
    args, code, literal = _case(tmp_path, case)
    result = RUNNER.invoke(app, args)
    assert "Traceback" not in result.output, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), \
        result.exception
    assert result.exit_code == code, result.output
    assert literal in result.output, result.output
