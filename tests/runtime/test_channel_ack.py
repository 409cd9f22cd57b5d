"""A channel that asks for delivery confirmation makes the node ask its modem for an ack."""

from __future__ import annotations

import asyncio

import msgpack

from bridge.core.loaded import parse_mission
from bridge.modems.base import ModemBackend, ModemSetup, Reception
from bridge.runtime.zenoh_node import BridgeNode

MISSION = """\
mission: acks
modem: {backend: udp, frame_bytes: 32}
nodes:
  a: {address: 1}
  b: {address: 2}
  c: {address: 3}
channels:
  - name: command
    from: a
    to: b
    ack: true
    elements: [{in: command, out: a/command, fields: [{field: go, type: bool}]}]
  - name: chatter
    from: a
    to: "b|c"
    elements: [{in: chatter, out: a/chatter, fields: [{field: n, type: int, min: 0, max: 9}]}]
"""


class RecordingModem(ModemBackend):
    """A modem that records what it is asked to send (the node's decisions are under test)."""

    name = "recording"

    def __init__(self, setup: ModemSetup) -> None:
        super().__init__(setup)
        self.sent: list[tuple[int | None, bool]] = []

    async def _open(self) -> None:
        pass

    async def _send(self, data: bytes, dest: int | None, ack: bool,
                    deadline: float | None) -> None:
        self.sent.append((dest, ack))

    async def _recv(self) -> Reception:
        await asyncio.Future()
        raise AssertionError

    async def _close(self) -> None:
        pass


def test_ack_only_for_unicast_frames_of_ack_channels() -> None:
    loaded = parse_mission(MISSION, "acks.yaml")
    modem = RecordingModem(ModemSetup(node="a", address=1, frame_bytes=32))

    async def scenario() -> list[tuple[int | None, bool]]:
        node = BridgeNode(loaded, "a", lambda: modem)
        node.backend = modem
        await modem.open()
        node.ingest("command", msgpack.packb({"go": True}), "application/msgpack")
        assert await node.transmit()
        node.ingest("chatter", msgpack.packb({"n": 3}), "application/msgpack")
        assert await node.transmit()
        node.ingest("command", msgpack.packb({"go": False}), "application/msgpack")
        node.ingest("chatter", msgpack.packb({"n": 4}), "application/msgpack")
        assert await node.transmit()
        await modem.close()
        return modem.sent

    assert asyncio.run(scenario()) == [(2, True), (None, False), (None, False)]
