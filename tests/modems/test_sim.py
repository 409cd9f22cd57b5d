"""The water service and sim modems over real loopback TCP."""

from __future__ import annotations

import asyncio
import contextlib
import json
import socket
import time
from collections.abc import AsyncIterator, Awaitable, Callable
from typing import Any

import pytest

from bridge.errors import BackendError
from bridge.mission.presets import Preset
from bridge.modems.base import ModemSetup, Reception
from bridge.modems.sim import SimBackend
from bridge.sim.ocean import LossCurve
from bridge.sim.service import WaterService, serve_water

# 50 ms overhead + 1 ms per byte, sound at 1500 m/s: fast enough for tests, slow enough to measure.
FAST = Preset(
    name="test-fast",
    frame_bytes=64,
    bitrate_bps=8000.0,
    overhead_s=0.05,
    sound_speed_mps=1500.0,
    max_range_m=3000.0,
)
POSITIONS = {1: (0.0, 0.0, 0.0), 2: (150.0, 0.0, 0.0), 3: (300.0, 0.0, 0.0)}
TOL = 0.04
LATE = 0.5
"""What a loaded machine may add to a wall-clock wait (CI saw 0.116 s for a 0.06 s send)."""


def about(elapsed: float, expected: float) -> bool:
    """``elapsed`` wall-clock seconds are ``expected`` ones: never much early, late only as
    much as a loaded machine makes them."""
    return expected - TOL <= elapsed <= expected + LATE


def arun(main: Callable[[], Awaitable[None]], timeout: float = 10.0) -> None:
    """Run an async test body with a hard timeout."""
    asyncio.run(asyncio.wait_for(main(), timeout))


def setup(addr: int, port: int, **options: Any) -> ModemSetup:
    return ModemSetup(
        node=f"n{addr}",
        address=addr,
        frame_bytes=64,
        options={"water": f"127.0.0.1:{port}", **options},
        position=POSITIONS.get(addr),
    )


@contextlib.asynccontextmanager
async def water_and_modems(
    *addrs: int, **kwargs: Any
) -> AsyncIterator[tuple[WaterService, list[SimBackend]]]:
    service = WaterService(FAST, seed=1, loss_curve=LossCurve(edge_loss=0.0), **kwargs)
    port = await service.start()
    modems = [SimBackend(setup(a, port)) for a in addrs]
    try:
        for m in modems:
            await m.open()
        yield service, modems
    finally:
        for m in modems:
            await m.close()
        await service.stop()


async def nothing_within(modem: SimBackend, seconds: float) -> bool:
    try:
        await asyncio.wait_for(modem.recv(), seconds)
    except TimeoutError:
        return True
    return False


def free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_broadcast_reaches_both_with_travel_time() -> None:
    async def main() -> None:
        async with water_and_modems(1, 2, 3) as (_, (a, b, c)):
            t0 = time.time()
            await a.send(b"0123456789")  # airtime 0.06 s
            assert about(time.time() - t0, 0.06)  # returns at TxDone
            rb, rc = await b.recv(), await c.recv()
            for rx, metres in ((rb, 150.0), (rc, 300.0)):
                assert isinstance(rx, Reception)
                assert (rx.src, rx.data, rx.dest) == (1, b"0123456789", None)
                assert about(rx.time - t0, 0.06 + metres / 1500.0)
                assert rx.meta["travel_time_s"] == pytest.approx(metres / 1500.0)
                assert rx.meta["start"] == pytest.approx(rx.time - 0.06)
            assert await nothing_within(a, 0.1)  # no echo of its own frame
            assert (a.stats["sent"], b.stats["received"]) == (1, 1)

    arun(main)


def test_unicast_is_heard_promiscuously_with_dest() -> None:
    async def main() -> None:
        async with water_and_modems(1, 2, 3) as (_, (a, b, c)):
            await a.send(b"for-3", dest=3)
            rb, rc = await b.recv(), await c.recv()
            assert rb.dest == 3 and rc.dest == 3 and rb.data == b"for-3"

    arun(main)


def test_collision_over_the_service() -> None:
    async def main() -> None:
        async with water_and_modems(1, 2, 3) as (service, (a, b, c)):
            await asyncio.gather(a.send(b"from-a" * 5), c.send(b"from-c" * 5))
            assert (await a.recv()).src == 3
            assert (await c.recv()).src == 1
            assert await nothing_within(b, 0.3)
            stats = json.loads(json.dumps(service.stats()))
            lost = {(s["src"], s["dst"]): s["lost"] for s in stats["links"]}
            assert lost[(1, 2)] == {"collision": 1} and lost[(3, 2)] == {"collision": 1}
            assert stats["total"]["delivered"] == 2

    arun(main)


def test_positions_from_service_and_moving() -> None:
    async def main() -> None:
        service = WaterService(
            FAST, seed=1, positions={7: (0.0, 0.0, 750.0)}, loss_curve=LossCurve(edge_loss=0.0)
        )
        port = await service.start()
        a = SimBackend(setup(1, port))
        far = SimBackend(
            ModemSetup(
                node="far", address=7, frame_bytes=64, options={"water": f"127.0.0.1:{port}"}
            )
        )
        try:
            await a.open()
            await far.open()
            await a.send(b"x")
            assert (await far.recv()).meta["travel_time_s"] == pytest.approx(0.5)
            far.set_position(0.0, 0.0, 1500.0)
            await asyncio.sleep(0.05)  # the move travels over TCP
            await a.send(b"y")
            assert (await far.recv()).meta["travel_time_s"] == pytest.approx(1.0)
        finally:
            await a.close()
            await far.close()
            await service.stop()

    arun(main)


def test_close_twice_and_use_after_close() -> None:
    async def main() -> None:
        async with water_and_modems(1, 2) as (_, (a, b)):
            waiter = asyncio.create_task(b.recv())
            await asyncio.sleep(0.01)
            await b.close()
            await b.close()
            with pytest.raises(BackendError, match="closed"):
                await waiter
            with pytest.raises(BackendError):
                await b.send(b"x")
            with pytest.raises(BackendError):
                await b.recv()
            await a.send(b"nobody listens")  # the water drops it without fuss

    arun(main)


def test_oversize_frame_refused() -> None:
    async def main() -> None:
        async with water_and_modems(1) as (_, (a,)):
            with pytest.raises(BackendError, match="exceeds"):
                await a.send(b"x" * 65)
            assert a.stats["errors"] == 0 and a.stats["sent"] == 0

    arun(main)


def test_a_timed_frame_starts_on_time_or_expires() -> None:
    """Scheduled ahead, the frame starts exactly then; asked for a start already past, the
    water refuses it as a timed modem does, and nothing is heard (no frame stamped for a start
    that did not happen)."""
    async def main() -> None:
        async with water_and_modems(1, 2) as (_, (a, b)):
            at = a.clock() + a.tx_lead_s
            await a.send(b"on time", at=at)
            rx = await b.recv()
            assert rx.meta["start"] - rx.meta["travel_time_s"] == pytest.approx(at, abs=1e-6)
            with pytest.raises(BackendError, match="expired"):
                await a.send(b"too late", at=a.clock() - 0.02)
            assert await nothing_within(b, 0.3)
            assert a.tx_lead_s == 0.05

    arun(main)


def test_water_not_running_fails_fast() -> None:
    async def main() -> None:
        modem = SimBackend(setup(1, free_tcp_port()))
        t0 = time.monotonic()
        with pytest.raises(BackendError, match="cannot reach the water"):
            await modem.open()
        assert time.monotonic() - t0 < 1.0
        assert not modem.is_open
        await modem.close()

    arun(main)


def test_missing_water_option() -> None:
    with pytest.raises(BackendError, match="'water'"):
        SimBackend(ModemSetup(node="x", address=1, frame_bytes=64))


def test_duplicate_address_refused() -> None:
    async def main() -> None:
        async with water_and_modems(1) as (service, _):
            twin = SimBackend(setup(1, service.port or 0))
            with pytest.raises(BackendError, match="already in the water"):
                await twin.open()
            await twin.close()

    arun(main)


def test_water_going_away_raises_instead_of_hanging() -> None:
    async def main() -> None:
        service = WaterService(FAST, seed=1)
        port = await service.start()
        modem = SimBackend(setup(1, port))
        await modem.open()
        try:
            waiter = asyncio.create_task(modem.recv())
            await asyncio.sleep(0.01)
            await service.stop()
            with pytest.raises(BackendError, match=r"closed the connection|lost the water"):
                await waiter
            with pytest.raises(BackendError):
                await modem.send(b"x")
        finally:
            await modem.close()

    arun(main)


def test_serve_water_runs_until_cancelled() -> None:
    async def main() -> None:
        ready: asyncio.Future[int] = asyncio.get_running_loop().create_future()
        task = asyncio.create_task(
            serve_water(FAST, 0, POSITIONS, "127.0.0.1", 0, ready=ready.set_result)
        )
        port = await ready
        async with SimBackend(setup(1, port)) as a, SimBackend(setup(2, port)) as b:
            await a.send(b"hi")
            assert (await b.recv()).data == b"hi"
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task

    arun(main)
