"""`zab water` that cannot listen (another water on its port, a port no socket has) exits 2
with one clear line, never an `OSError` traceback: real processes on loopback ports."""

from __future__ import annotations

import asyncio
import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from bridge.cli.app import app
from bridge.errors import WaterError
from bridge.sim.service import WaterService
from tests.conftest import REPO, free_port
from tests.two_links import two_links

START_S = 60.0  # generous: a loaded 2-core machine


def mission(tmp_path: Path, water_a: int | None, water_rf: int | None) -> Path:
    path = tmp_path / "waters.yaml"
    path.write_text(two_links(water_a=None if water_a is None else f"127.0.0.1:{water_a}",
                              water_rf=None if water_rf is None else f"127.0.0.1:{water_rf}"))
    return path


def _argv(path: Path, *args: str) -> list[str]:
    return [sys.executable, "-m", "bridge", "water", str(path), *args]


def _one_clear_line(result: subprocess.CompletedProcess[str] | object) -> str:
    if isinstance(result, subprocess.CompletedProcess):
        code, output, stderr = result.returncode, result.stdout + result.stderr, result.stderr
    else:  # a CliRunner result
        code, output = result.exit_code, result.output  # type: ignore[attr-defined]
        stderr = output
    assert code == 2, output
    assert "Traceback" not in output and "Error" not in output, output
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, output
    return lines[0]


def test_a_second_zab_water_on_the_same_ports_exits_2(tmp_path: Path) -> None:
    water_a = free_port()
    path = mission(tmp_path, water_a, free_port())
    env = {**os.environ, "COLUMNS": "300"}
    with subprocess.Popen(_argv(path), cwd=REPO, stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT, text=True, env=env) as first:
        try:
            assert first.stdout is not None
            said = [first.stdout.readline(), first.stdout.readline()]
            assert all("Ctrl-C to stop" in line for line in said), said
            second = subprocess.run(_argv(path), cwd=REPO, capture_output=True, text=True,
                                    timeout=START_S, env=env)
            assert _one_clear_line(second) == (
                f"cannot start: 127.0.0.1:{water_a} is already in use (is another `zab water` "
                "running?)")
            assert first.poll() is None  # the first goes on
            first.send_signal(signal.SIGINT)
            first.communicate(timeout=30)
            assert first.returncode == 0
        finally:
            if first.poll() is None:
                first.kill()
                first.wait()


def test_the_second_links_port_taken_exits_2_and_frees_the_first(tmp_path: Path) -> None:
    water_a, water_rf = free_port(), free_port()
    path = mission(tmp_path, water_a, water_rf)
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", water_rf))
        taken.listen()
        result = CliRunner().invoke(app, ["water", str(path)])
    assert "water (evologics-s2c-im, link acoustic) on" in result.output
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output and result.exception is not None
    assert (f"cannot start: 127.0.0.1:{water_rf} is already in use (is another `zab water` "
            "running?)") in result.output
    with socket.socket() as again:  # the first link's water stopped with it
        again.bind(("127.0.0.1", water_a))


def test_two_links_on_the_default_water_exit_2_before_listening(tmp_path: Path) -> None:
    result = CliRunner().invoke(app, ["water", str(mission(tmp_path, None, None))])
    assert _one_clear_line(result) == (
        "cannot start: links acoustic and rf both have their water at 127.0.0.1:7600 (give "
        "each link's modem its own `water` option)")


def test_a_port_out_of_range_is_refused_by_the_option(tmp_path: Path) -> None:
    path = tmp_path / "one.yaml"
    path.write_text(two_links().split("links:")[0] + """\
modem: {backend: sim, options: {preset: evologics-s2c-im}}
nodes: {a: {address: 1}, b: {address: 2}}
channels:
  - {name: n, from: a, to: b, elements: [{in: n, out: a/n, fields: [{field: n, type: int,
      min: 0, max: 9}]}]}
""")
    result = CliRunner().invoke(app, ["water", "--port", "99999", str(path)])
    output = result.output + (result.stderr if result.stderr_bytes is not None else "")
    assert result.exit_code == 2 and "Traceback" not in output, output
    assert "Invalid value for '--port'" in output, output


@pytest.mark.parametrize(("port", "words"), [
    (None, "is already in use (is another `zab water` running?)"),
    (99999, "the water cannot listen on 127.0.0.1:99999: bind(): port must be 0-65535"),
])
def test_a_water_that_cannot_listen_says_why_in_one_line(port: int | None, words: str) -> None:
    async def main() -> None:
        with socket.socket() as taken:
            taken.bind(("127.0.0.1", 0))
            taken.listen()
            at = taken.getsockname()[1] if port is None else port
            service = WaterService("evologics-s2c-im")
            with pytest.raises(WaterError) as info:
                await service.start("127.0.0.1", at)
            assert words in str(info.value) and "\n" not in str(info.value)
            if port is None:
                assert str(info.value) == f"127.0.0.1:{at} {words}"
            assert service.started_at is None
            await service.stop()  # (nothing to stop)
            assert await service.start("127.0.0.1", 0) > 0  # it can listen elsewhere
            await service.stop()

    asyncio.run(main())
