"""Frames nobody can read (issue 32), end to end: plain Zenoh applications (``zenoh`` and
``msgpack`` only) at two nodes of ``zab sim``, on a ``zab water`` where a hydrophone (a raw
socket speaking the water's protocol) hears every frame. What it captures reveals no field
value, a replayed or tampered copy is refused, and the mission key rotates in the middle of
the run without losing a value."""

from __future__ import annotations

import contextlib
import os
import secrets
import socket
import struct
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import msgpack
import pytest
import yaml
import zenoh

from bridge.core.loaded import load_mission
from bridge.core.node import NodeCore
from bridge.core.reception import Reception
from bridge.wire.seal import KeyRing, frame_authenticator
from tests.conftest import free_port
from tests.zsim import app, mission_file, zab_sim, zab_water

LONG = True  # half a minute of zab sim, to the key switch and past it: handed out first
ROTATE_AFTER_S = 22.0  # the next key takes over this long after the test starts

MISSION = """
mission: zseal
wire: {auth: {tag_bytes: 4, encrypt: true}}
link: {heartbeat_s: 2}
modem:
  backend: sim
  frame_bytes: 48
  options: {preset: evologics-s2c-im, seed: 1}
mac: {type: tdma, slot_s: 0.8, guard_s: 0.05, order: [top, auv1]}
nodes:
  top: {address: 1, role: surface, position: {x: 0, y: 0, depth: 0.5}}
  auv1: {address: 2, position: {x: 40, y: 30, depth: 10}}
channels:
  - name: log
    from: auv1
    to: top
    reliable: true
    elements:
      - {in: log, out: auv1/log, fields: [{field: n, type: int, min: 0, max: 1023}]}
  - name: nav
    from: auv1
    to: top
    elements:
      - {in: nav, out: auv1/nav, fields: [{field: depth_m, min: 0, max: 200, resolution: 0.01}]}
"""


class Hydrophone:
    """A listener in the water: every frame any modem sends, as (src, bytes)."""

    def __init__(self, port: int, address: int = 99) -> None:
        self.frames: list[tuple[int, bytes]] = []
        self.sock = socket.create_connection(("127.0.0.1", port))
        self._send({"t": "hello", "v": 1, "addr": address, "name": "hydrophone"})
        self.thread = threading.Thread(target=self._listen, daemon=True)
        self.thread.start()

    def _send(self, message: dict[str, Any]) -> None:
        data = msgpack.packb(message)
        self.sock.sendall(struct.pack(">I", len(data)) + data)

    def _read(self, n: int) -> bytes:
        out = b""
        while len(out) < n:
            chunk = self.sock.recv(n - len(out))
            if not chunk:
                raise ConnectionError("water closed")
            out += chunk
        return out

    def _listen(self) -> None:
        with contextlib.suppress(OSError, ConnectionError):
            while True:
                (size,) = struct.unpack(">I", self._read(4))
                message = msgpack.unpackb(self._read(size))
                if message.get("t") == "rx":
                    self.frames.append((message["src"], message["data"]))

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_RDWR)
        self.sock.close()
        self.thread.join(5)


@dataclass
class Sea:
    mission: Path
    keys: KeyRing
    top: zenoh.Session
    auv1: zenoh.Session
    hydrophone: Hydrophone
    started: float = field(default_factory=time.time)


@pytest.fixture(scope="module")
def sea(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Sea]:
    folder = tmp_path_factory.mktemp("zseal")
    data = yaml.safe_load(MISSION)
    switch = time.time() + ROTATE_AFTER_S
    data["wire"]["auth"]["next_key"] = {
        "at": datetime.fromtimestamp(switch, UTC).isoformat(), "overlap_s": 5}
    mission, endpoints = mission_file(yaml.safe_dump(data, sort_keys=False), folder)
    keys = KeyRing(secrets.token_hex(32).encode(), secrets.token_hex(32).encode(), switch, 5)
    env = {**os.environ, "ZAB_KEY": keys.current.decode(), "ZAB_NEXT_KEY": keys.next.decode()}
    port = free_port()
    with zab_water(mission, port, env):
        hydrophone = Hydrophone(port)
        os.environ.update(ZAB_KEY=env["ZAB_KEY"], ZAB_NEXT_KEY=env["ZAB_NEXT_KEY"])
        try:
            with zab_sim(mission, endpoints, "--water", f"127.0.0.1:{port}", timeout=300):
                top, auv1 = app(endpoints["top"]), app(endpoints["auv1"])
                try:
                    yield Sea(mission, keys, top, auv1, hydrophone)
                finally:
                    top.close()
                    auv1.close()
        finally:
            for name in ("ZAB_KEY", "ZAB_NEXT_KEY"):
                os.environ.pop(name, None)
            hydrophone.close()


def test_a_frame_heard_on_the_water_reveals_no_value_and_a_copy_is_refused(sea: Sea) -> None:
    got: list[Any] = []
    subscriber = sea.top.declare_subscriber(
        "auv1/nav", lambda s: got.append(msgpack.unpackb(s.payload.to_bytes())))
    try:
        deadline = time.time() + 20
        while not got and time.time() < deadline:  # until the link is up and it crossed
            sea.auv1.put("nav", msgpack.packb({"depth_m": 123.45}))
            time.sleep(1.0)
        assert got and got[-1] == {"depth_m": pytest.approx(123.45)}
    finally:
        subscriber.undeclare()
    listener = NodeCore(load_mission(sea.mission), "top", key=sea.keys)  # with the key
    now = time.time()
    carried = []
    for src, frame in [f for f in sea.hydrophone.frames if f[0] == 2]:
        listener.receive(Reception(frame, src, now), now)
        outputs = listener.take()
        if any(getattr(o, "key", None) == "auv1/nav" for o in outputs):
            carried.append(frame)
    assert carried, "the hydrophone heard the frames that carried the value"
    table = load_mission(sea.mission).table
    packed = table.by_name("nav").pack([{"depth_m": 123.45}])
    opener = frame_authenticator(table, sea.keys, 1)
    for frame in carried:
        body = opener.open(frame[:-2], 2, now)  # the plaintext: count, index, fields
        assert _holds(body, packed, table.by_name("nav").bits)  # the value's bits are in it
        assert len(body) >= 3 and body not in frame  # and nowhere in what crossed
    dropped = dict(listener.stats.frames_dropped)
    listener.receive(Reception(carried[0], 2, now), now)  # a replay
    tampered = bytearray(carried[-1])
    tampered[len(tampered) // 2] ^= 0x10
    listener.receive(Reception(bytes(tampered), 2, now), now)
    after = listener.stats.frames_dropped
    assert after["replayed"] == dropped.get("replayed", 0) + 1
    assert after["check"] + after["forged"] == dropped.get("check", 0) \
        + dropped.get("forged", 0) + 1


def _holds(data: bytes, pattern: int, bits: int) -> bool:
    """Whether ``data`` holds the ``bits``-bit ``pattern`` at some bit offset."""
    n, width, mask = int.from_bytes(data, "big"), 8 * len(data), (1 << bits) - 1
    return any((n >> shift) & mask == pattern for shift in range(width - bits + 1))


def test_the_key_rotates_in_the_middle_of_the_run_and_nothing_is_lost(sea: Sea) -> None:
    got: list[int] = []
    subscriber = sea.top.declare_subscriber(
        "auv1/log", lambda s: got.append(msgpack.unpackb(s.payload.to_bytes())["n"]))
    try:
        switch = sea.keys.switch_at
        assert switch is not None and time.time() < switch - 4, "the run took too long"
        n = 0
        while time.time() < switch + 6:  # a value every half second, across the switch
            sea.auv1.put("log", msgpack.packb({"n": n}))
            n += 1
            time.sleep(0.5)
        deadline = time.time() + 20
        while len(got) < n and time.time() < deadline:
            time.sleep(0.2)
        assert got == list(range(n))
    finally:
        subscriber.undeclare()
