"""Two nodes over real Zenoh and a real UDP link, their state directory a small tmpfs that
fills up (then is freed) or turns read-only (then writable) mid-run: the nodes go on hearing,
latest values keep crossing, the failure is in the stats and on ``…/events``, new reliable
commands are refused with the reason while it lasts, traffic resumes after by itself, and
every command ends in exactly one report."""

from __future__ import annotations

import queue
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgpack
import pytest
import zenoh

from tests.conftest import on_free_ports, udp_ports
from tests.harness import outside_session, running_fleet
from tests.runtime.tmpfs import fill, remount, small_tmpfs

MISSION = """\
mission: disk
modem: {backend: udp, frame_bytes: 32}
mac: {type: none, min_gap_s: 0.02}
nodes:
  ops: {address: 1, modem: {options: {port: PORT_A}}}
  auv: {address: 2, modem: {options: {port: PORT_B}}}
channels:
  - name: command
    from: ops
    to: auv
    reliable: true
    retry_s: 0.3
    elements: [{in: cmd, out: ops/cmd, fields: [{field: n, type: int, min: 0, max: 1000}]}]
  - name: status
    from: auv
    to: ops
    elements: [{in: status, out: auv/status, fields: [{field: depth, type: int, min: 0,
                                                      max: 1000}]}]
"""
TERMINAL = ("delivered", "failed")


def wait(condition: Callable[[], Any], what: str, timeout: float = 10.0) -> Any:
    deadline = time.time() + timeout
    while not (result := condition()):
        assert time.time() < deadline, what
        time.sleep(0.02)
    return result


@pytest.mark.parametrize("fault", ["full", "read-only"])
def test_a_state_directory_that_fails_mid_run_is_survived(fault: str, tmp_path: Path) -> None:
    loaded = on_free_ports(udp_ports(MISSION), "disk.yaml")
    with small_tmpfs(tmp_path / "state") as where, \
            running_fleet(loaded, state_dir=str(where)) as fleet:
        ops_app, auv_app = outside_session(loaded, "ops"), outside_session(loaded, "auv")
        try:
            reports: dict[str, list[dict]] = defaultdict(list)
            events: queue.Queue[dict] = queue.Queue()
            commands: queue.Queue[int] = queue.Queue()
            status: queue.Queue[int] = queue.Queue()
            ops_app.declare_subscriber("@zab/disk/ops/delivery/**", lambda s: reports[
                msgpack.unpackb(s.payload.to_bytes())["ref"]].append(
                    msgpack.unpackb(s.payload.to_bytes())))
            ops_app.declare_subscriber("@zab/disk/ops/events", lambda s: events.put(
                msgpack.unpackb(s.payload.to_bytes())))
            auv_app.declare_subscriber("ops/cmd", lambda s: commands.put(
                msgpack.unpackb(s.payload.to_bytes())["n"]))
            ops_app.declare_subscriber("auv/status", lambda s: status.put(
                msgpack.unpackb(s.payload.to_bytes())["depth"]))
            time.sleep(0.3)
            sent: list[int] = []

            def command(n: int) -> None:
                sent.append(n)
                ops_app.put("cmd", msgpack.packb({"n": n}), attachment=f"ref:{n}".encode(),
                            encoding=zenoh.Encoding("application/msgpack"))

            def crosses(depth: int) -> None:
                auv_app.put("status", msgpack.packb({"depth": depth}),
                            encoding=zenoh.Encoding("application/msgpack"))
                wait(lambda: depth in list(status.queue), f"status {depth} crosses")

            def settled(ns: list[int]) -> bool:
                return all(any(r["state"] in TERMINAL for r in reports[str(n)]) for n in ns)

            for n in range(5):
                command(n)
            wait(lambda: settled(list(range(5))), "the first commands end")
            crosses(1)

            filler = fill(where) if fault == "full" else None
            if fault == "read-only":
                remount(where, "ro")
            command(100)  # taken before any save failed: the save after it fails
            ops = fleet.nodes["ops"]
            wait(lambda: not ops.snapshot()["state"]["saved"], "the failure is in the stats")
            for n in range(101, 106):
                command(n)
            wait(lambda: settled(list(range(100, 106))), "the commands during the fault end")
            crosses(2)
            crosses(3)  # latest values keep crossing, both nodes keep hearing
            state = ops.snapshot()["state"]
            assert state["error"] and ("ENOSPC" in state["error"] or "EROFS" in state["error"])
            refused = [reports[str(n)][-1] for n in range(101, 106)]
            assert all(r["state"] == "failed" and "cannot save its state" in r["reason"]
                       for r in refused), refused
            failing = wait(lambda: next((e for e in list(events.queue)
                                         if e["kind"] == "state_saving"), None),
                           "the failure is on …/events")
            assert failing["saved"] is False

            if filler is not None:
                filler.unlink()
            else:
                remount(where, "rw")
            wait(lambda: ops.snapshot()["state"]["saved"], "saves work again by themselves")
            for n in range(200, 205):
                command(n)
            wait(lambda: settled(list(range(200, 205))), "the commands after the fault end")
            crosses(4)
            delivered_after = [reports[str(n)][-1]["state"] for n in range(200, 205)]
            assert delivered_after == ["delivered"] * 5
            assert [e["saved"] for e in list(events.queue) if e["kind"] == "state_saving"] \
                == [False, True]
            time.sleep(0.5)  # anything late would be here by now
            arrived = list(commands.queue)
        finally:
            ops_app.close()
            auv_app.close()
    for n in sent:  # every command: exactly one terminal report, and delivered ones arrived
        terminal = [r for r in reports[str(n)] if r["state"] in TERMINAL]
        assert len(terminal) == 1, (n, reports[str(n)])
        assert (terminal[0]["state"] == "delivered") == (n in arrived), n
    assert sorted(arrived) == sorted(set(arrived))  # never twice
