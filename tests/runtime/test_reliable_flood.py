"""A plain Zenoh application flooding a full reliable channel's input key: every put gets its
report, and the node does not save its state once a put (which had kept its event loop saving,
not sending: under a 30 s flood from four publishers, one navigation value of 60 crossed, and
none for 20 s after it). A refusal costs a save once a block of ids (bridge.core.ids); values
taken (``overflow: drop_oldest``) are saved once for all those taken until the loop's next
turn (BridgeNode.settle_soon)."""

from __future__ import annotations

import queue
import signal
import threading
import time
from pathlib import Path
from typing import Any

import msgpack
import pytest
import zenoh

from bridge.core.ids import BLOCK
from tests.conftest import on_free_ports, udp_ports
from tests.harness import Inbox, outside_session, running_fleet, zab_run
from tests.zsim import app, mission_file

MISSION = """\
mission: flood
modem: {backend: sim, frame_bytes: 64, options: {preset: evologics-s2c-im}}
mac: {type: tdma, slot_s: 1.0, guard_s: 0.2, order: [ops, auv]}
nodes:
  ops: {address: 1, role: surface, position: {x: 0, y: 0, depth: 0}}
  auv: {address: 2, position: {x: 300, y: 0, depth: 20}}
channels:
  - name: command
    from: ops
    to: auv
    reliable: true
    queue: 40
    overflow: %s
    elements:
      - in: cmd
        out: ops/cmd
        fields: [{field: n, type: int, min: 0, max: 65535}]
  - name: nav
    from: ops
    to: auv
    interval_s: 2
    latching: true         # (sent again each cycle: the water loses frames)
    elements:
      - in: nav
        out: ops/nav
        fields: [{field: depth, type: float, min: 0, max: 100, bits: 10}]
"""
FLOOD = 600  # (enough to tell: a save a put would be 600; a lighter load on the suite)


@pytest.mark.parametrize("overflow", ["reject", "drop_oldest"])
def test_a_flood_on_a_full_reliable_channel_costs_no_save_a_put(overflow: str) -> None:
    loaded = on_free_ports(MISSION % overflow)
    with running_fleet(loaded) as fleet:
        node = fleet.nodes["ops"]
        saves: list[float] = []
        save = node.persistence.save

        def counted(*args: Any, **kwargs: Any) -> bool | None:
            saves.append(time.monotonic())
            return save(*args, **kwargs)

        node.persistence.save = counted  # type: ignore[method-assign]
        ops, auv = outside_session(loaded, "ops"), outside_session(loaded, "auv")
        try:
            reports, navs = Inbox(), Inbox()
            ops.declare_subscriber("@zab/flood/ops/delivery/command", reports)
            auv.declare_subscriber("ops/nav", navs)
            time.sleep(0.5)  # the subscribers declared at the bridges
            for n in range(FLOOD):  # (BLOCK: the application's Zenoh drops none)
                ops.put("cmd", msgpack.packb({"n": n}),
                        encoding=zenoh.Encoding("application/msgpack"),
                        congestion_control=zenoh.CongestionControl.BLOCK,
                        attachment=f"ref:{n}".encode())
            ops.put("nav", msgpack.packb({"depth": 42.0}),
                    encoding=zenoh.Encoding("application/msgpack"))
            first: dict[str, dict[str, Any]] = {}  # each put's first report
            end = time.time() + 60
            while len(first) < FLOOD and time.time() < end:
                try:
                    _, report, _ = reports.get(timeout=max(0.01, end - time.time()))
                except queue.Empty:
                    break
                first.setdefault(report["ref"], report)
            assert set(first) == {str(n) for n in range(FLOOD)}, \
                f"{FLOOD - len(first)} of {FLOOD} puts never reported"
            assert len({r["id"] for r in first.values()}) == FLOOD  # an id each
            states = [r["state"] for r in first.values()]
            if overflow == "reject":  # a save for each value taken and each frame, one a
                refused = [r for r in first.values() if r["state"] == "failed"]  # block of
                assert states.count("queued") >= 40 and len(refused) > FLOOD - 100  # refusals
                assert all(r["reason"] == "queue full (40 values)" for r in refused)
                assert len(saves) < 60 + FLOOD // BLOCK, f"{len(saves)} saves for {FLOOD} puts"
            else:  # every put taken (the oldest queued one given up): a save a batch
                assert states == ["queued"] * FLOOD
                assert len(saves) < FLOOD // 2, f"{len(saves)} saves for {FLOOD} puts"
            print(f"{overflow}: {len(saves)} saves for {FLOOD} puts")
            # and the node goes on sending: the navigation put after the flood crosses
            _, nav, _ = navs.get(timeout=15)
            assert abs(nav["depth"] - 42.0) < 0.1
        finally:
            ops.close()
            auv.close()


UDP = """\
mission: stopflood
modem: {backend: udp, frame_bytes: 32}
mac: {type: tdma, slot_s: 0.5, order: [ops, auv]}
nodes:
  ops: {address: 1, modem: {options: {port: PORT_A}}}
  auv: {address: 2, modem: {options: {port: PORT_B}}}
channels:
  - name: command
    from: ops
    to: auv
    reliable: true
    queue: 40
    overflow: drop_oldest
    elements: [{in: cmd, out: ops/cmd, fields: [{field: n, type: int, min: 0, max: 65535}]}]
"""


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM])
def test_a_node_stopped_in_the_middle_of_a_flood_stops_cleanly(stop: signal.Signals,
                                                              tmp_path: Path) -> None:
    """Its last outputs, taken as it stopped, found the session closed: a traceback (an
    asyncio callback's) where a clean stop was due."""
    mission, endpoints = mission_file(udp_ports(UDP), tmp_path)
    flooding = threading.Event()
    done = threading.Event()

    def flood() -> None:
        session = app(endpoints["ops"])
        try:
            payload = msgpack.packb({"n": 7})
            while not done.is_set():
                session.put("cmd", payload)
                flooding.set()
        finally:
            session.close()

    with zab_run(mission, "ops", "--state-dir", str(tmp_path / "state"),
                 stop=stop) as (_, lines):
        threads = [threading.Thread(target=flood)]
        for thread in threads:
            thread.start()
        try:
            assert flooding.wait(10)
            time.sleep(1.0)
        except BaseException:
            done.set()
            raise
    done.set()  # (zab_run checked the exit status: 0)
    for thread in threads:
        thread.join(15)
    text = "".join(lines)
    assert "Traceback" not in text and "ERROR" not in text, text
