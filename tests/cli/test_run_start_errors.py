"""`zab run` that cannot open its Zenoh session (its port taken, its router not there) exits 2
with one clear line, never a `zenoh.ZError` traceback: real processes on loopback ports."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from bridge.mission.model import ZenohSettings
from bridge.runtime.session import session_problem
from tests.conftest import REPO, free_port
from tests.harness import zab_run

MISSION = """\
mission: start
wire: {{auth: off}}
modem: {{backend: udp, frame_bytes: 16}}
nodes:
  a: {{address: 1, modem: {{options: {{port: {udp_a}}}}}, zenoh: {{listen: [tcp/127.0.0.1:{za}]}}}}
  b: {{address: 2, modem: {{options: {{port: {udp_b}}}}},
      zenoh: {{mode: client, connect: [tcp/127.0.0.1:{router}]}}}}
channels:
  - {{name: ping, from: a, to: b, elements: [{{in: ping, out: a/ping, fields: [{{field: n,
      type: int, min: 0, max: 9}}]}}]}}
"""
START_S = 60.0  # generous: a loaded 2-core machine


@pytest.fixture
def mission(tmp_path: Path) -> tuple[Path, int, int]:
    """The mission, node a's Zenoh port, and the port of b's (absent) router."""
    za, router = free_port(), free_port()
    path = tmp_path / "start.yaml"
    path.write_text(MISSION.format(udp_a=free_port(socket.SOCK_DGRAM),
                                   udp_b=free_port(socket.SOCK_DGRAM), za=za, router=router))
    return path, za, router


def _argv(path: Path, node: str) -> list[str]:
    return [sys.executable, "-m", "bridge", "run", str(path), "--node", node]


def _run(path: Path, node: str, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*_argv(path, node), *args], cwd=REPO, capture_output=True, text=True,
                          timeout=START_S, env={**os.environ, "COLUMNS": "80"})


@contextmanager
def _running(path: Path, node: str) -> Iterator[subprocess.Popen[str]]:
    """`zab run` until it says it runs; SIGTERM on exit (it must stop cleanly, exit 0)."""
    with zab_run(path, node) as (proc, _):
        yield proc


def _one_clear_line(result: subprocess.CompletedProcess[str]) -> str:
    output = result.stdout + result.stderr
    assert result.returncode == 2, output
    assert "Traceback" not in output and "ZError" not in output and ".rs:" not in output, output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, output
    assert "bridge running" not in output
    return lines[0]


def test_port_taken_by_another_zab_run_exits_2(mission: tuple[Path, int, int],
                                              tmp_path: Path) -> None:
    path, za, _ = mission
    with _running(path, "a"):  # (the second on a state of its own: its port is what it meets)
        line = _one_clear_line(_run(path, "a", "--state-dir", str(tmp_path / "other")))
    assert line == (f"cannot start: a: tcp/127.0.0.1:{za} is already in use (is another "
                    "`zab run`, `zab sim`, `zab demo` or zenohd listening there?)")


def test_a_second_bridge_of_the_node_on_the_same_state_exits_2(
        mission: tuple[Path, int, int], tmp_path: Path) -> None:
    """Two `zab run` of one node on one state directory (here on Zenoh ports of their own,
    so only the state is shared): the second says another bridge holds the state and exits 2
    before anything runs; the first goes on, and saves as before."""
    path, _, _ = mission
    second = tmp_path / "second.yaml"  # the same mission and node, other ports
    second.write_text(MISSION.format(udp_a=free_port(socket.SOCK_DGRAM),
                                     udp_b=free_port(socket.SOCK_DGRAM), za=free_port(),
                                     router=free_port()))
    state = Path(os.environ["STATE_DIRECTORY"]) / "start.a.state"
    with _running(path, "a") as first:
        line = _one_clear_line(_run(second, "a"))
        assert first.poll() is None
        saved = state.stat().st_mtime_ns
    assert line == (f"cannot start: a: another bridge holds this node's state ({state}.lock "
                    f"is locked by process {first.pid}): stop it first, or give this one a "
                    "--state-dir of its own")
    assert state.stat().st_mtime_ns >= saved  # (the first saved at its stop)
    with _running(second, "a"):  # the first gone, the node's state is free again
        pass


def test_port_taken_by_any_listener_exits_2_and_starts_once_free(
        mission: tuple[Path, int, int]) -> None:
    path, za, _ = mission
    with socket.socket() as holder:
        holder.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        holder.bind(("127.0.0.1", za))
        holder.listen()
        assert f"tcp/127.0.0.1:{za} is already in use" in _one_clear_line(_run(path, "a"))
    with _running(path, "a"):
        pass


def test_unreachable_router_exits_2(mission: tuple[Path, int, int]) -> None:
    path, _, router = mission
    line = _one_clear_line(_run(path, "b"))
    assert line.startswith(f"cannot start: b: no Zenoh router answers at tcp/127.0.0.1:{router}")


def test_session_problem_keeps_other_zenoh_errors_readable() -> None:
    """A listen address this host does not have: Zenoh's reason, without its source paths."""
    text = ("Can not create a new TCP listener bound to tcp/10.9.9.9:7447: [10.9.9.9:7447: Cannot "
            "assign requested address (os error 99) at /root/.cargo/git/x/tcp.rs:61.] at "
            "/root/.cargo/git/y/unicast.rs:338.")
    assert session_problem(text, ZenohSettings()) == (
        "cannot listen on tcp/10.9.9.9:7447: 10.9.9.9:7447: Cannot assign requested address "
        "(os error 99)")
    assert session_problem("something new at /src/a.rs:1.", ZenohSettings()) == (
        "cannot open the Zenoh session: something new")
    json5 = ('Json5Err(Message { msg: "Endpoints must be of the form <protocol>/<address>'
             '[?<metadata>]: notanendpoint", location: Some(Location { line: 1, column: 2 }) })')
    assert session_problem(json5, ZenohSettings()) == (
        "invalid endpoint 'notanendpoint': expected a Zenoh endpoint <protocol>/<host>:<port>, "
        "such as tcp/127.0.0.1:7447")


def test_zab_sim_with_a_taken_port_stops_every_node_and_says_it_once(
        mission: tuple[Path, int, int]) -> None:
    """Every node of `zab sim` starts in one process: one that cannot open its session stops
    the others, and the command says why once (no unretrieved task exceptions)."""
    path, za, _ = mission
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", za))
        taken.listen()
        result = subprocess.run([sys.executable, "-m", "bridge", "sim", str(path), "--duration",
                                 "3", "--no-live"], cwd=REPO, capture_output=True, text=True,
                                timeout=START_S, env={**os.environ, "COLUMNS": "200"})
    assert result.returncode == 2, result.stdout + result.stderr
    assert "Traceback" not in result.stderr and "never retrieved" not in result.stderr
    assert result.stderr.count("cannot start") == 1 and f"127.0.0.1:{za}" in result.stderr


def test_a_full_state_disk_at_start_exits_2(mission: tuple[Path, int, int],
                                            tmp_path: Path) -> None:
    """A state directory whose filesystem is full (a real tmpfs): one line, exit 2."""
    from tests.runtime.tmpfs import fill, small_tmpfs

    path, _, _ = mission
    with small_tmpfs(tmp_path / "state") as where:
        fill(where)
        result = subprocess.run([*_argv(path, "a"), "--state-dir", str(where)], cwd=REPO,
                                capture_output=True, text=True, timeout=START_S,
                                env={**os.environ, "COLUMNS": "80"})
        line = _one_clear_line(result)
    assert line == (f"cannot start: a: cannot save its state in {where}: No space left on "
                    "device (ENOSPC)")


def test_a_fleet_with_a_port_taken_exits_2_and_does_not_hang(tmp_path: Path) -> None:
    """`zab sim` (and `zab demo`: the same fleet) whose surface node finds its Zenoh port
    taken says so and exits 2. The other nodes, stopped while their simulated modems were
    still greeting the water, once swallowed that stop (`asyncio.wait_for` on Python 3.11
    returns a result that lands with the cancellation) and the fleet hung, Ctrl-C too."""
    text = (REPO / "deploy/missions/umci_relay.yaml").read_text(encoding="utf-8")
    ports = {port: free_port() for port in ("7622", "7623", "7624")}
    for port, free in ports.items():
        text = text.replace(f"tcp/127.0.0.1:{port}", f"tcp/127.0.0.1:{free}")
    path = tmp_path / "relay.yaml"
    path.write_text(text, encoding="utf-8")
    with socket.socket() as holder:
        holder.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        holder.bind(("127.0.0.1", ports["7622"]))
        holder.listen()
        result = subprocess.run(
            [sys.executable, "-m", "bridge", "sim", str(path), "--duration", "5", "--no-live"],
            cwd=REPO, capture_output=True, text=True, timeout=START_S,
            env={**os.environ, "COLUMNS": "200", "ZAB_KEY": "ab" * 32})
    output = result.stdout + result.stderr
    assert result.returncode == 2, output
    assert f"cannot start: surface: tcp/127.0.0.1:{ports['7622']} is already in use" in output


def test_a_node_that_never_gets_a_turn_is_warned_at_start(mission: tuple[Path, int, int]
                                                          ) -> None:
    """`zab check` refuses a sender without a TDMA slot; `zab run` of such a mission still
    runs (the node may receive), but says at start, once, that its values would never leave."""
    path, _, _ = mission
    text = path.read_text()
    said = {}
    for order in ("[b]", "[a, b]"):
        path.write_text(text.replace(
            "channels:", f"mac: {{type: tdma, slot_s: 1.0, order: {order}}}\nchannels:"))
        with zab_run(path, "a") as (_, lines):
            pass
        said[order] = " ".join("".join(lines).split())  # (the log's lines wrap)
    assert "never gets a turn" not in said["[a, b]"], said
    assert said["[b]"].count("never gets a turn") == 1, said
    assert "node a sends channel 'ping' but never gets a turn to send" in said["[b]"], said
    assert "add a to mac.order" in said["[b]"], said
