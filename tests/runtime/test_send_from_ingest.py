"""A sample that finds its MAC's opportunity open leaves on the ingest call itself (no hop
through the transmit loop); one send at a time however it was started."""

from __future__ import annotations

import asyncio

import msgpack

from bridge.core.loaded import parse_mission
from bridge.modems.base import ModemBackend, ModemSetup, Reception
from bridge.runtime.zenoh_node import BridgeNode

MISSION = """\
mission: eager
modem: {backend: udp, frame_bytes: 32}
mac: %s
nodes:
  a: {address: 1}
  b: {address: 2}
channels:
  - name: cmd
    from: a
    to: b
    elements: [{in: cmd, out: a/cmd, fields: [{field: n, type: int, min: 0, max: 255}]}]
"""


class GatedModem(ModemBackend):
    """Records sends; while ``gate`` is set, each send waits for it (a modem awaiting OK)."""

    name = "gated"

    def __init__(self) -> None:
        super().__init__(ModemSetup(node="a", address=1, frame_bytes=32))
        self.sent: list[bytes] = []
        self.gate: asyncio.Future[None] | None = None

    async def _open(self) -> None:
        pass

    async def _send(self, data: bytes, dest: int | None, ack: bool,
                    deadline: float | None) -> None:
        self.sent.append(data)
        if self.gate is not None:
            await self.gate

    async def _recv(self) -> Reception:
        await asyncio.Future()
        raise AssertionError

    async def _close(self) -> None:
        pass


async def node_with(mac: str, modem: GatedModem, clock: float | None = None) -> BridgeNode:
    loaded = parse_mission(MISSION % mac, "eager.yaml")
    if clock is None:
        node = BridgeNode(loaded, "a", lambda: modem)
    else:
        node = BridgeNode(loaded, "a", lambda: modem, clock=lambda: clock)
    node.backend = modem
    await modem.open()
    node.port.modem_up.set()  # what the modem loop does once the modem is open
    return node


def value(n: int) -> bytes:
    return msgpack.packb({"n": n})


def test_without_a_mac_the_frame_is_sent_before_ingest_returns() -> None:
    async def scenario() -> None:
        modem = GatedModem()
        node = await node_with("{type: none}", modem)
        node.ingest("cmd", value(7), "application/msgpack")
        assert len(modem.sent) == 1
        await modem.close()

    asyncio.run(scenario())


def test_a_send_in_flight_is_not_doubled_by_a_new_sample() -> None:
    async def scenario() -> None:
        modem = GatedModem()
        modem.gate = asyncio.get_running_loop().create_future()
        node = await node_with("{type: none}", modem)
        node.ingest("cmd", value(1), "application/msgpack")
        node.ingest("cmd", value(2), "application/msgpack")  # the first send still waits
        assert len(modem.sent) == 1
        gate, modem.gate = modem.gate, None
        gate.set_result(None)
        loop = asyncio.create_task(node.port.transmit_loop())  # the newer value goes next
        for _ in range(100):
            if len(modem.sent) == 2:
                break
            await asyncio.sleep(0.01)
        loop.cancel()
        assert len(modem.sent) == 2
        await modem.close()

    asyncio.run(scenario())


def test_outside_its_slot_the_sample_waits_for_the_transmit_loop() -> None:
    async def scenario() -> None:
        modem = GatedModem()
        node = await node_with("{type: tdma, slot_s: 10, order: [b, a]}", modem, clock=1000.5)
        node.ingest("cmd", value(7), "application/msgpack")  # b's slot
        assert modem.sent == []
        await modem.close()

    asyncio.run(scenario())
