"""The runtime hands a frame's ``until`` (the end of its TDMA slot, on the node's clock) to the
backend's ``send`` on the backend's clock, which the backend turns into a deadline on the event
loop's; a frame the backend drops as too late stays due, and the node goes on."""

from __future__ import annotations

import asyncio
import logging

import msgpack
import pytest

from bridge.core.loaded import parse_mission
from bridge.errors import SendTooLate
from bridge.modems.base import ModemBackend, ModemSetup, Reception
from bridge.runtime.zenoh_node import BridgeNode

MISSION = """\
mission: until
modem: {backend: udp, frame_bytes: 32}
mac: {type: tdma, slot_s: SLOT, guard_s: GUARD, order: [a, b]}
nodes:
  a: {address: 1}
  b: {address: 2}
channels:
  - name: cmd
    from: a
    to: b
    elements: [{in: cmd, out: a/cmd, fields: [{field: n, type: int, min: 0, max: 255}]}]
"""


class SlowModem(ModemBackend):
    """Records how long each frame's turn has left; with ``stall``, waits for the modem past
    the turn's end, and drops the frame as a real backend does."""

    name = "slow"

    def __init__(self, stall: bool = False) -> None:
        super().__init__(ModemSetup(node="a", address=1, frame_bytes=32))
        self.stall = stall
        self.left: list[float | None] = []

    async def _open(self) -> None:
        pass

    async def _send(self, data: bytes, dest: int | None, ack: bool,
                    deadline: float | None) -> None:
        loop = asyncio.get_running_loop()
        self.left.append(None if deadline is None else deadline - loop.time())
        if self.stall and deadline is not None:
            await asyncio.sleep(deadline - loop.time() + 0.01)  # a modem that does not answer
            self._check_turn(deadline, "a retry")  # (raises: the turn is over)
            raise AssertionError("a retry after the turn's end was not refused")

    async def _recv(self) -> Reception:
        await asyncio.Future()
        raise AssertionError

    async def _close(self) -> None:
        pass


async def node_at(modem: SlowModem, slot_s: float, guard_s: float, clock: float) -> BridgeNode:
    text = MISSION.replace("SLOT", str(slot_s)).replace("GUARD", str(guard_s))
    node = BridgeNode(parse_mission(text, "until.yaml"), "a", lambda: modem,
                      clock=lambda: clock)  # the node's clock: decades behind the modem's
    node.backend = modem
    await modem.open()
    node.port.modem_up.set()
    return node


def test_the_slots_end_reaches_the_backend_on_its_own_clock() -> None:
    async def scenario() -> None:
        modem = SlowModem()
        node = await node_at(modem, 10.0, 1.0, clock=1000.01)  # a's slot [1000, 1010)
        node.ingest("cmd", msgpack.packb({"n": 1}), "application/msgpack")
        for _ in range(100):
            if modem.left:
                break
            await asyncio.sleep(0.01)
        [left] = modem.left
        assert left == pytest.approx(1009.0 - 1000.01, abs=0.05)  # silent from 1009
        await modem.close()

    asyncio.run(scenario())


def test_a_frame_dropped_at_the_turns_end_stays_due(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO)

    async def scenario() -> None:
        modem = SlowModem(stall=True)
        node = await node_at(modem, 1.0, 0.5, clock=1000.01)  # a's slot: silent from 1000.5
        node.core.ingest("cmd", msgpack.packb({"n": 1}), "application/msgpack", 1000.01)
        with pytest.raises(SendTooLate):  # (what the port catches)
            await modem.send(b"x", 2, until=modem.clock() - 1.0)
        assert not await node.port.transmit()  # nothing went out: the frame's turn ended
        assert modem.stats["late"] == 2 and modem.stats["errors"] == 0
        assert node.core.stats.send_errors == 1 and node.core.stats.frames_sent == 0
        assert node.core.next_due(1000.6) is not None  # its value waits for the next slot
        assert node.port.modem_up.is_set()  # the modem is not taken for dead
        await modem.close()

    asyncio.run(scenario())
    drops = [r for r in caplog.records if r.name == "zab.modem"]
    assert [r.levelno for r in drops] == [logging.WARNING] * 2  # the backend's, one a frame
    told = [r for r in caplog.records if r.name == "zab.node" and "send failed" in r.getMessage()]
    assert [r.levelno for r in told] == [logging.INFO]  # the port's, not a second warning
