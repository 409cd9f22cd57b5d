"""A modem that refuses every frame, through real ``zab water`` and ``zab run`` processes: the
node tries again about once a second, not at once. Under ``mac: none`` it used to ask again
the moment the refusal came back: 1842 warnings in 6 s here (each retry a round trip to the
water), or, with a refusal that needs no I/O (Goby's empty heartbeats), a loop that never
yielded and no longer heard Ctrl-C. The pure cores: tests/runtime/test_virtual_fleet.py."""

from __future__ import annotations

import signal
import time
from pathlib import Path

from tests.conftest import free_port
from tests.harness import zab_run
from tests.zsim import mission_file, zab_water

MISSION = """\
mission: refused
modem:
  backend: sim
  frame_bytes: 32
  # every frame's start already a second past when the water gets it: refused ("expired")
  options: {preset: micromodem-rate0, water: "127.0.0.1:WATER", tx_lead_s: -1.0}
mac: {type: none}
link: {heartbeat_s: 1.0}
nodes:
  topside: {address: 0, position: {x: 0, y: 0, depth: 2}}
  auv1: {address: 1, position: {x: 800, y: 0, depth: 30}}
channels:
  - name: x
    from: topside
    to: auv1
    elements: [{in: x, out: topside/x, fields: [{field: v, type: int, min: 0, max: 100}]}]
"""
RUN_S = 6.0


def test_a_node_whose_modem_refuses_every_frame_tries_again_once_a_second(
        tmp_path: Path) -> None:
    port = free_port()
    mission, _ = mission_file(MISSION.replace("WATER", str(port)), tmp_path)
    with zab_water(mission, port), zab_run(mission, "topside", "--state-dir",
                                               str(tmp_path / "state"),
                                               stop=signal.SIGINT) as (_, lines):
        time.sleep(RUN_S)
    refused = [line for line in "".join(lines).splitlines() if "send failed" in line]
    assert refused and "expired" in refused[0]
    assert 2 <= len(refused) <= RUN_S + 3, f"{len(refused)} refusals in {RUN_S:g} s"
