"""The authentication counter counts frames: no clock, no repeats, no wrap, and restarts keep it.

The issue's cases: two frames in the same instant, a clock stepping back, the date the former
clock-based 32-bit counter wrapped (2029-07-18 05:49:52 UTC), a restart of the sender, and a
replay after the receiver restarts, this one over a real UDP link between two cores.
"""

from __future__ import annotations

import asyncio
import socket
from datetime import UTC, datetime
from pathlib import Path

import pytest

from bridge.core.loaded import parse_mission
from bridge.core.node import NodeCore, Publish
from bridge.core.reception import Reception
from bridge.errors import FrameError
from bridge.modems.base import ModemSetup
from bridge.modems.udp import UdpBackend
from bridge.runtime.state_file import StateFile
from bridge.wire.auth import RESERVE_BLOCK, Authenticator

KEY = b"a-mission-key-of-32-bytes-000000"
MISSION = """\
mission: sealed
wire: {auth: {tag_bytes: 4}}
mac: {type: none}
nodes:
  a: {address: 1}
  b: {address: 2}
channels:
  - name: n
    from: a
    to: b
    elements: [{in: n, out: a/n, fields: [{field: v, type: int, min: 0, max: 1000}]}]
"""
LOADED = parse_mission(MISSION, "sealed.yaml")
WRAP_2029 = datetime(2029, 7, 18, 5, 49, 52, tzinfo=UTC).timestamp()


def core(node: str, state: dict | None = None) -> NodeCore:
    return NodeCore(LOADED, node, key=KEY, state=state)


def frame(sender: NodeCore, v: int, now: float) -> bytes:
    """A frame of ``sender`` carrying ``v``, sealed at ``now`` (which the counter ignores)."""
    channel = LOADED.table.by_name("n")
    return sender.codec.encode([(channel, channel.pack([{"v": v}]))], [], sender.epoch)


def published(receiver: NodeCore) -> list[int]:
    return [o.value["v"] for o in receiver.take() if isinstance(o, Publish)]


@pytest.mark.parametrize("times", [
    [1000.0, 1000.0, 1000.0],  # the same instant (was: the second refused as replayed)
    [1000.0, 995.0, 990.0],  # the clock steps back 5 s at a time (was: refused)
    [WRAP_2029 - 1, WRAP_2029, WRAP_2029 + 1],  # (was: everything after it refused)
])
def test_frames_are_accepted_whatever_the_clock_says(times: list[float]) -> None:
    a, b = core("a"), core("b")
    for v, now in enumerate(times):
        b.receive(Reception(frame(a, v, now), 1, now, {}), now)
    assert published(b) == [0, 1, 2]
    assert not b.stats.frames_dropped


def test_the_counter_is_64_bits_and_crosses_its_low_half() -> None:
    near = (1 << 32) - 2
    sender = Authenticator(KEY, b"f" * 8, 1, 4, {"reserved": near})
    receiver = Authenticator(KEY, b"f" * 8, 2, 4, {"seen": {"1": near - 1}})
    for _ in range(5):  # 2**32 - 2 ... 2**32 + 2: the low half wraps, the counter does not
        assert receiver.open(sender.seal(b"x"), 1) == b"x"
    assert receiver.seen[1] == (1 << 32) + 2


def test_counters_are_reserved_in_blocks_and_saved_once_a_block() -> None:
    sender = Authenticator(KEY, b"f" * 8, 1, 4)
    saves = 0
    for _ in range(3 * RESERVE_BLOCK):
        sender.seal(b"x")
        saves += sender.changed
        sender.changed = False
    assert saves == 3 and sender.state()["reserved"] == 3 * RESERVE_BLOCK


def test_a_restarted_sender_never_reuses_a_counter(tmp_path: Path) -> None:
    a, b = core("a"), core("b")
    state = StateFile(tmp_path, "sealed", "a")
    first = frame(a, 1, 10.0)
    state.save(a.state())  # the runtime saves the reservation before the frame leaves
    b.receive(Reception(first, 1, 10.0, {}), 10.0)
    again = core("a", state.load())  # kill -9 and restart
    b.receive(Reception(frame(again, 2, 11.0), 1, 11.0, {}), 11.0)
    assert published(b) == [1, 2]
    forgetful = core("a")  # a sender that lost its state starts its counter again: refused
    b.receive(Reception(frame(forgetful, 3, 12.0), 1, 12.0, {}), 12.0)
    assert published(b) == [] and b.stats.frames_dropped["replayed"] == 1


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_a_restarted_receiver_refuses_frames_recorded_before(tmp_path: Path) -> None:
    """Frames cross a real UDP link; the receiver is restarted from its state file, then an
    attacker replays every frame it recorded: none is published again."""
    port_a, port_b = free_udp_port(), free_udp_port()

    def setup(node: str, address: int, port: int, peer: int, peer_port: int) -> ModemSetup:
        return ModemSetup(node=node, address=address, frame_bytes=64,
                          options={"port": port}, peers={peer: {"port": peer_port}})

    async def scenario() -> tuple[list[int], list[int], dict[str, int]]:
        a, b = core("a"), core("b")
        state = StateFile(tmp_path, "sealed", "b")
        recorded: list[bytes] = []
        async with UdpBackend(setup("a", 1, port_a, 2, port_b)) as modem_a, \
                UdpBackend(setup("b", 2, port_b, 1, port_a)) as modem_b:

            async def hear(receiver: NodeCore) -> None:
                rx = await asyncio.wait_for(modem_b.recv(), 5)
                receiver.receive(rx, rx.time)
                state.save(receiver.state())  # before publishing, as the runtime does

            for v in (1, 2, 3):
                data = frame(a, v, float(v))
                recorded.append(data)
                await modem_a.send(data, 2)
                await hear(b)
            before = published(b)
            restarted = core("b", state.load())
            for data in recorded:  # the replay
                await modem_a.send(data, 2)
                await hear(restarted)
            await modem_a.send(frame(a, 4, 4.0), 2)  # and the sender goes on
            await hear(restarted)
        return before, published(restarted), dict(restarted.stats.frames_dropped)

    before, after, dropped = asyncio.run(scenario())
    assert before == [1, 2, 3]
    assert after == [4] and dropped == {"replayed": 3}


def test_a_forged_counter_does_not_move_the_window() -> None:
    a, b = core("a"), core("b")
    data = bytearray(frame(a, 1, 1.0))
    data[-7] ^= 0xFF  # inside the counter: the tag no longer matches
    with pytest.raises(FrameError):
        b.codec.auth.open(bytes(data[:-2]), 1)  # type: ignore[union-attr]
    assert b.codec.auth.seen == {}  # type: ignore[union-attr]
