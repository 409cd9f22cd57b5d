"""A latched value survives its bridge's ``kill -9``, through real processes: ``zab water``,
``zab run`` of a surface and of a vehicle (with its ``--state-dir``), and plain Zenoh
applications (``zenoh`` and ``msgpack`` only). The vehicle's application puts its status once
and goes away; the vehicle's bridge is killed with SIGKILL and started again on the same state
directory; the surface still gets the status, stamped with when it was really taken. The
pure cores: tests/core/test_latched_restarts.py."""

from __future__ import annotations

import queue
import subprocess
import sys
import threading
import time
from pathlib import Path

import msgpack
import zenoh

from tests.conftest import REPO, free_port
from tests.harness import put, zab_run
from tests.zsim import app, interrupt, mission_file, zab_water

MISSION = """\
mission: latchp
modem:
  backend: sim
  frame_bytes: 32
  options: {preset: evologics-s2c-im, water: "127.0.0.1:WATER", seed: 1}
mac: {type: tdma, slot_s: 0.8, guard_s: 0.05, order: [ops, auv]}
nodes:
  ops: {address: 1, role: surface, position: {x: 0, y: 0, depth: 0}}
  auv: {address: 2, position: {x: 100, y: 0, depth: 10}}
channels:
  - name: status
    from: auv
    to: ops
    latching: true
    age: {step_s: 0.5, max_s: 600}
    elements:
      - {in: status, out: auv/status, fields: [{field: mode, type: int, min: 0, max: 15}]}
"""
WAIT_S = 15.0  # for a value to cross (a TDMA cycle is 1.6 s; start-up on a loaded machine)


def started(mission: Path, node: str, state: Path) -> subprocess.Popen[str]:
    """A ``zab run`` of ``node`` on ``state``, once it says it runs (its output read on)."""
    proc = subprocess.Popen([sys.executable, "-m", "bridge", "run", str(mission), "--node", node,
                             "--state-dir", str(state)], cwd=REPO, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    assert proc.stdout is not None
    lines = []
    for line in proc.stdout:
        lines.append(line)
        if "bridge running" in line:
            break
    else:
        proc.wait()
        raise AssertionError("zab run did not start:\n" + "".join(lines))
    threading.Thread(target=proc.stdout.read, daemon=True).start()  # (a full pipe would stop it)
    return proc


def test_a_value_put_once_crosses_again_after_its_vehicle_bridge_is_killed(
        tmp_path: Path) -> None:
    port = free_port()
    mission, endpoints = mission_file(MISSION.replace("WATER", str(port)), tmp_path)
    arrivals: queue.Queue[tuple[float, dict, float]] = queue.Queue()

    def on_status(sample: zenoh.Sample) -> None:
        stamp = sample.timestamp
        arrivals.put((time.time(), msgpack.unpackb(sample.payload.to_bytes()),
                      stamp.get_time().timestamp() if stamp is not None else float("nan")))

    with zab_water(mission, port), zab_run(mission, "ops", "--state-dir",
                                               str(tmp_path / "ops")):
        surface = app(endpoints["ops"])
        surface.declare_subscriber("auv/status", on_status)
        auv = started(mission, "auv", tmp_path / "auv")
        try:
            vehicle = app(endpoints["auv"])
            put(vehicle, "status", {"mode": 5})  # once, as an application puts a latched value
            put_at = time.time()
            vehicle.close()  # and never again
            _, value, _ = arrivals.get(timeout=WAIT_S)
            assert value == {"mode": 5}

            auv.kill()  # SIGKILL: no clean-up, no last save
            auv.wait()
            auv = started(mission, "auv", tmp_path / "auv")
            restarted = time.time()
            while True:  # (what was on its way before the kill may still come)
                try:
                    arrived, value, taken = arrivals.get(timeout=max(0.0, restarted + WAIT_S
                                                                     - time.time()))
                except queue.Empty:
                    raise AssertionError(f"nothing crossed in the {WAIT_S:g} s after the "
                                         "restart: the latched value was lost") from None
                if arrived > restarted:
                    break
            assert value == {"mode": 5}
            assert abs(taken - put_at) < 2.0, (taken - put_at)  # its age: from the put
        finally:
            interrupt(auv)
            surface.close()
