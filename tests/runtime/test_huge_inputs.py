"""Huge Zenoh payloads leave no memory behind (bench/flood.py --huge measures more): a real
``zab run`` comes back near its idle size after one, because the intake holds no sample while it
waits and the freed C heap goes back to the system (bridge.runtime.heap)."""

from __future__ import annotations

import asyncio
import os
import socket
import sys
import time
import weakref
from pathlib import Path

import pytest
import zenoh

from bridge.runtime.heap import HEAP, HeapTrim, resident_bytes
from bridge.runtime.intake import Intake
from tests.conftest import free_port
from tests.harness import zab_run
from tests.zsim import app, mission_file

MB = 1 << 20


class _Sample:
    """Stands for a zenoh.Sample (whose buffers a reference keeps)."""


class _Subscriber:
    """Gives one sample, then, at the next recv, notes whether it is still referenced and
    ends (as a closed session does)."""

    def __init__(self) -> None:
        self.ref: weakref.ref[_Sample] | None = None
        self.held_while_waiting: bool | None = None

    def recv(self) -> _Sample:
        if self.ref is None:
            sample = _Sample()
            self.ref = weakref.ref(sample)
            return sample
        self.held_while_waiting = self.ref() is not None
        raise RuntimeError("channel is empty and closed")


@pytest.mark.parametrize("fails", [False, True])
def test_the_intake_holds_no_sample_while_it_waits_for_the_next(fails: bool) -> None:
    loop = asyncio.new_event_loop()
    try:
        intake = Intake(None, loop, "a")  # type: ignore[arg-type]  (_drain needs no session)
        subscriber = _Subscriber()
        handled: list[bool] = []
        failed: list[str] = []
        intake.failed = failed.append  # type: ignore[method-assign]  (a logged traceback
        # would keep the sample in pytest's captured records)

        def handle(sample: _Sample) -> None:
            handled.append(True)
            if fails:
                raise ValueError("a bad sample")

        intake._drain(subscriber, "cmd", handle)
    finally:
        loop.close()
    assert handled == [True] and failed == (["cmd"] if fails else [])
    assert subscriber.held_while_waiting is False


class _Process:
    """A resident size the test sets, and the trims asked for."""

    def __init__(self) -> None:
        self.rss = 100 * MB
        self.trims = 0
        self.gives_back = 0  # bytes a trim frees

    def trim(self) -> None:
        self.trims += 1
        self.rss -= self.gives_back


def test_a_trim_comes_once_growth_stops_at_a_bounded_rate() -> None:
    process = _Process()
    heap = HeapTrim(lambda: process.rss, process.trim, growth=16 * MB, every_s=5.0)
    assert heap.check(0.0) is None and heap.lowest == 100 * MB
    process.rss = 115 * MB  # under the growth that makes a trim worth it
    assert heap.check(1.0) is None and process.trims == 0

    process.rss, process.gives_back = 190 * MB, 85 * MB  # a flood
    assert heap.check(2.0) is None  # still growing (a message reassembled is in use)
    assert heap.check(3.0) == 85 * MB and process.rss == 105 * MB and process.trims == 1
    process.rss = 190 * MB  # another flood at once: not before every_s
    assert heap.check(4.0) is None and heap.check(5.0) is None and process.trims == 1
    assert heap.check(8.0) == 85 * MB and process.trims == 2

    process.rss, process.gives_back = 150 * MB, 0  # memory in use while trims run: they go
    trimmed_at = [t for t in range(9, 30) if heap.check(float(t)) is not None]
    assert trimmed_at == [13, 18, 23, 28]  # on every 5 s (no back-off: found by bench/flood.py
    process.gives_back = 50 * MB  # --huge, a message in use at one trim freed before the next,
    assert heap.check(33.0) == 50 * MB  # with no change in the resident size to tell)
    assert heap.trims == 7 and heap.freed == 220 * MB and heap.lowest == 100 * MB
    assert heap.snapshot() == {"trims": 7, "freed_mb": 220.0, "enabled": True}


def test_without_malloc_trim_it_does_nothing() -> None:
    heap = HeapTrim(lambda: 1 << 40, None)
    assert heap.check(0.0) is None and heap.check(100.0) is None
    assert heap.snapshot()["enabled"] is False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc_trim")
def test_freed_heap_kept_by_malloc_goes_back_to_the_system() -> None:
    heap = HeapTrim(growth=0)  # the real resident size and malloc_trim; trims at once
    if not heap.snapshot()["enabled"]:
        pytest.skip("no malloc_trim in this libc")
    chunks = [bytes(64 << 10) for _ in range(800)]  # 50 MB in chunks malloc keeps in its heap
    pin = bytes(64 << 10)  # above them: the heap cannot shrink from its top when they go
    before = resident_bytes()
    del chunks
    kept = resident_bytes()
    freed = heap.check(0.0)
    after = resident_bytes()
    assert before is not None and kept is not None and after is not None and pin
    assert kept > before - 20 * MB  # free() kept most of it
    assert freed is not None and freed >= 30 * MB and after <= kept - 30 * MB



MISSION = """\
mission: huge
modem: {backend: udp, frame_bytes: 48}
mac: {type: tdma, slot_s: 0.5, guard_s: 0.05, order: [a, b]}
nodes:
  a: {address: 1, modem: {options: {port: UDP_A}}}
  b: {address: 2, modem: {options: {port: UDP_B}}}
channels:
  - name: cmd
    from: a
    to: b
    elements: [{in: cmd, out: a/cmd, fields: [{field: n, type: int, min: 0, max: 255}]}]
"""
BACK_S = 60.0  # (a trim comes within seconds; a loaded machine may take longer)


def _rss(pid: int) -> float:
    with open(f"/proc/{pid}/status") as status:
        return next(int(line.split()[1]) << 10 for line in status if line.startswith("VmRSS:"))


@pytest.mark.skipif(not sys.platform.startswith("linux") or not HEAP.snapshot()["enabled"],
                    reason="glibc's malloc_trim, Linux's /proc")
def test_a_bridge_comes_back_near_its_idle_size_after_a_huge_put(tmp_path: Path) -> None:
    text = MISSION.replace("UDP_A", str(free_port(socket.SOCK_DGRAM)))
    mission, endpoints = mission_file(text.replace("UDP_B", str(free_port(socket.SOCK_DGRAM))),
                                      tmp_path)
    with zab_run(mission, "a") as (proc, _):
        client = app(endpoints["a"])
        try:
            client.put("cmd", b"\x81\xa1n\x01")  # (the first sample's allocations, before)
            time.sleep(2.0)
            idle = _rss(proc.pid)
            data = os.urandom(50 * MB)  # (BLOCK: every fragment arrives, the put is whole)
            client.put("cmd", data, congestion_control=zenoh.CongestionControl.BLOCK)
            del data
            most, end = 0, time.monotonic() + BACK_S
            while (rss := _rss(proc.pid)) > idle + 20 * MB and time.monotonic() < end:
                most = max(most, rss)
                time.sleep(0.5)
        finally:
            client.close()
    assert rss <= idle + 20 * MB, f"idle {idle / MB:.0f} MB, {rss / MB:.0f} MB after the put"
