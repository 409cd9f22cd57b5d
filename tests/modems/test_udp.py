"""The UDP backend over real loopback sockets."""

from __future__ import annotations

import asyncio
import contextlib
import socket
import threading
import time
from collections.abc import AsyncIterator, Awaitable, Callable
from typing import Any

import pytest

from bridge.errors import BackendError
from bridge.modems.base import ModemSetup, Reception
from bridge.modems.udp import UdpBackend


def arun(main: Callable[[], Awaitable[None]], timeout: float = 10.0) -> None:
    asyncio.run(asyncio.wait_for(main(), timeout))


def free_udp_ports(n: int) -> list[int]:
    socks = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(n)]
    try:
        for s in socks:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


def setups(n: int, **options: Any) -> list[ModemSetup]:
    ports = dict(zip(range(1, n + 1), free_udp_ports(n), strict=True))
    return [
        ModemSetup(
            node=f"n{a}",
            address=a,
            frame_bytes=32,
            options={"port": p, **options},
            peers={b: {"port": q} for b, q in ports.items() if b != a},
        )
        for a, p in ports.items()
    ]


@contextlib.asynccontextmanager
async def nodes(n: int) -> AsyncIterator[list[UdpBackend]]:
    modems = [UdpBackend(s) for s in setups(n)]
    try:
        for m in modems:
            await m.open()
        yield modems
    finally:
        for m in modems:
            await m.close()


async def nothing_within(modem: UdpBackend, seconds: float) -> bool:
    try:
        await asyncio.wait_for(modem.recv(), seconds)
    except TimeoutError:
        return True
    return False


def test_broadcast_and_unicast_between_three_nodes() -> None:
    async def main() -> None:
        async with nodes(3) as (a, b, c):
            await a.send(b"hello all")
            for m in (b, c):
                rx = await m.recv()
                assert (rx.src, rx.data, rx.dest) == (1, b"hello all", None)
            await c.send(b"just you", dest=2)
            rx = await b.recv()
            assert (rx.src, rx.data, rx.dest) == (3, b"just you", 2)
            assert rx.meta["travel_time_s"] == 0.0
            assert await nothing_within(a, 0.1)
            await b.send(b"back", dest=1)
            assert (await a.recv()).src == 2
            assert a.stats == {
                "sent": 1,
                "received": 1,
                "errors": 0,
                "dropped": 0,
                "malformed": 0,
                "unreachable": 0,
            }

    arun(main)


def test_oversize_empty_and_unknown_dest_refused() -> None:
    async def main() -> None:
        async with nodes(2) as (a, _):
            with pytest.raises(BackendError, match="exceeds frame_bytes=32"):
                await a.send(b"x" * 33)
            with pytest.raises(BackendError, match="empty"):
                await a.send(b"")
            with pytest.raises(BackendError, match="no UDP peer with address 9"):
                await a.send(b"x", dest=9)

    arun(main)


def test_malformed_datagram_counted_not_delivered() -> None:
    async def main() -> None:
        async with nodes(1) as (a,):
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                s.sendto(b"\x00garbage", ("127.0.0.1", a.port))
                s.sendto(b"\xa5", ("127.0.0.1", a.port))
            assert await nothing_within(a, 0.1)
            assert a.stats["malformed"] == 2

    arun(main)


def test_on_reception_takes_each_frame_as_it_arrives_and_errors_still_reach_recv() -> None:
    async def main() -> None:
        async with nodes(2) as (a, b):
            await a.send(b"queued", 2)
            assert (await asyncio.wait_for(b.recv(), 2)).data == b"queued"  # none set: queued
            heard: list[Reception] = []
            b.on_reception = heard.append
            waiter = asyncio.create_task(b.recv())
            await a.send(b"first", 2)
            await a.send(b"second")
            for _ in range(200):
                if len(heard) == 2:
                    break
                await asyncio.sleep(0.005)
            assert [(rx.data, rx.src) for rx in heard] == [(b"first", 1), (b"second", 1)]
            assert b.stats["received"] == 3 and not waiter.done()  # recv saw none of them
            await b.close()
            with pytest.raises(BackendError, match="closed"):
                await waiter

    arun(main)


def test_close_twice_and_use_after_close() -> None:
    async def main() -> None:
        async with nodes(2) as (a, _):
            waiter = asyncio.create_task(a.recv())
            await asyncio.sleep(0.01)
            await a.close()
            await a.close()
            with pytest.raises(BackendError, match="closed"):
                await waiter
            with pytest.raises(BackendError):
                await a.send(b"x")

    arun(main)


def test_port_zero_binds_a_free_port() -> None:
    async def main() -> None:
        setup = ModemSetup(node="solo", address=1, frame_bytes=32, options={"port": 0})
        async with UdpBackend(setup) as modem:
            assert isinstance(modem, UdpBackend) and modem.port > 0

    arun(main)


def test_bind_failure_is_a_backend_error() -> None:
    async def main() -> None:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind(("127.0.0.1", 0))
            taken = s.getsockname()[1]
            modem = UdpBackend(
                ModemSetup(node="x", address=1, frame_bytes=32, options={"port": taken})
            )
            with pytest.raises(BackendError, match="cannot bind"):
                await modem.open()
            await modem.close()

    arun(main)


def test_remote_addresses_refused_unless_allowed() -> None:
    with pytest.raises(BackendError, match="not a loopback address"):
        UdpBackend(
            ModemSetup(node="x", address=1, frame_bytes=32, options={"port": 0, "host": "0.0.0.0"})
        )
    with pytest.raises(BackendError, match="not a loopback address"):
        UdpBackend(
            ModemSetup(
                node="x",
                address=1,
                frame_bytes=32,
                options={"port": 0},
                peers={2: {"port": 5000, "host": "10.0.0.2"}},
            )
        )
    # allowed explicitly: only checked, nothing is opened or sent here
    UdpBackend(
        ModemSetup(
            node="x",
            address=1,
            frame_bytes=32,
            options={"port": 0, "allow_remote": True},
            peers={2: {"port": 5000, "host": "10.0.0.2"}},
        )
    )
    with pytest.raises(BackendError, match="'port' is required"):
        UdpBackend(ModemSetup(node="x", address=1, frame_bytes=32))


def test_direct_send_from_any_thread_and_receptions_on_the_reader_thread() -> None:
    async def main() -> None:
        async with nodes(2) as (a, b):
            assert a.direct
            heard: list[tuple[bytes, str]] = []
            got = threading.Event()

            def on_reception(rx: Reception) -> None:
                heard.append((rx.data, threading.current_thread().name))
                got.set()

            b.on_reception = on_reception
            sender = threading.Thread(target=a.send_now, args=(b"from a thread", 2))
            sender.start()
            sender.join(2)
            assert await asyncio.to_thread(got.wait, 2)
            assert heard == [(b"from a thread", "udp-n2")]
            assert a.stats["sent"] == 1 and b.stats["received"] == 1
            with pytest.raises(BackendError, match="exceeds frame_bytes=32"):
                a.send_now(b"x" * 33)
            reader = b._reader
            started = time.monotonic()
            await b.close()
            assert reader is not None and not reader.is_alive()
            assert time.monotonic() - started < 0.5  # the blocked reader is woken, not polled
            with pytest.raises(BackendError, match="not open"):
                b.send_now(b"late", 1)

    arun(main)


def test_a_backend_that_is_not_direct_refuses_send_now() -> None:
    from bridge.modems.sim import SimBackend

    modem = SimBackend(ModemSetup(node="n1", address=1, frame_bytes=32,
                                  options={"water": "127.0.0.1:1"}))
    assert not modem.direct
    with pytest.raises(BackendError, match="only from its event loop"):
        modem.send_now(b"x", 2)
