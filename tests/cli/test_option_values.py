"""Output paths and numeric options a command cannot use: refused with one message and exit
2 (1 for a schema that cannot be written, as --payloads), never a traceback.

Found from outside: ``zab schema --out`` a missing folder or a folder, ``zab sim --log`` a
file, ``zab gui --port 70000``, ``zab sim --duration -5``/``0``/``nan``, ``zab log replay
--speed inf``/``1e-300``, ``--wait inf`` and ``zab sim --water bogus`` printed tracebacks, ran
3600 s instead of 0, or reported nothing simulated with exit 0."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from bridge.cli.app import app
from tests.conftest import MISSIONS, free_port

RUNNER = CliRunner()
LINE = str(MISSIONS / "acoustic_line.yaml")


@pytest.fixture(scope="module")
def mission_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("logs")
    result = RUNNER.invoke(app, ["sim", "--fast", "--duration", "120", "--log", str(folder),
                                 LINE])
    assert result.exit_code == 0, result.output
    return next(folder.glob("*.mcap"))


CASES = {  # arguments ({tmp}: a folder, {log}: a mission log, {port}: a free port), exit, text
    "schema in a missing folder": (["schema", "--out", "{tmp}/none/x.json"], 1,
                                   "cannot write the schema:"),
    "schema to a folder": (["schema", "--out", "{tmp}"], 1, "cannot write the schema:"),
    "sim --log a file": (["sim", "--fast", "--duration", "10", "--log", "{tmp}/file", LINE], 2,
                         "cannot write the mission logs:"),
    "gui --port 70000": (["gui", LINE, "--port", "70000"], 2, "'--port'"),
    "gui --port -1": (["gui", LINE, "--port", "-1"], 2, "'--port'"),
    "demo --gui-port 70000": (["demo", "--gui-port", "70000"], 2, "'--gui-port'"),
    "fast --duration -5": (["sim", "--fast", "--duration", "-5", LINE], 2, "'--duration'"),
    "fast --duration 0": (["sim", "--fast", "--duration", "0", LINE], 2, "'--duration'"),
    "fast --duration nan": (["sim", "--fast", "--duration", "nan", LINE], 2, "'--duration'"),
    "fast --duration inf": (["sim", "--fast", "--duration", "inf", LINE], 2, "'--duration'"),
    "real-time --duration -5": (["sim", "--no-live", "--duration", "-5", LINE], 2,
                                "'--duration'"),
    "sim --speed inf": (["sim", "--speed", "inf", LINE], 2, "'--speed'"),
    "replay --speed inf": (["log", "replay", "{log}", "--listen", "tcp/127.0.0.1:{port}",
                            "--speed", "inf", "--wait", "0"], 2, "'--speed'"),
    "replay --speed 1e-300": (["log", "replay", "{log}", "--listen", "tcp/127.0.0.1:{port}",
                               "--speed", "1e-300", "--wait", "0"], 2, "'--speed'"),
    "replay --wait inf": (["log", "replay", "{log}", "--listen", "tcp/127.0.0.1:{port}",
                           "--wait", "inf"], 2, "'--wait'"),
    "replay --listen port 99999": (["log", "replay", "{log}", "--listen", "tcp/127.0.0.1:99999",
                                    "--wait", "0"], 2, "'--listen'"),
    "replay --connect no protocol": (["log", "replay", "{log}", "--connect", "127.0.0.1:{port}",
                                      "--wait", "0"], 2, "'--connect'"),
    "sim --water bogus": (["sim", "--duration", "3", "--no-live", "--water", "bogus", LINE], 2,
                          "'--water'"),
}


@pytest.mark.parametrize("case", CASES)
def test_refused_with_one_message(tmp_path: Path, mission_log: Path, case: str) -> None:
    args, code, text = CASES[case]
    (tmp_path / "file").write_text("not a folder")
    filled = [a.format(tmp=tmp_path, log=mission_log, port=free_port()) for a in args]
    result = RUNNER.invoke(app, filled)
    assert result.exception is None or isinstance(result.exception, SystemExit), \
        (case, result.exception)
    assert "Traceback" not in result.output
    assert result.exit_code == code, (case, result.output)
    assert text in result.output, (case, result.output)
    assert "simulating" not in result.output  # refused before anything ran


def test_a_duration_in_range_still_runs() -> None:
    result = RUNNER.invoke(app, ["sim", "--fast", "--duration", "5", LINE])
    assert result.exit_code == 0, result.output
    assert "5 s simulated" in result.output
