"""The ``evologics`` driver against emulated modems: real ptys, real pyserial, real water."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import AsyncIterator, Awaitable, Callable
from pathlib import Path
from typing import Any

import pytest

from bridge.errors import BackendError, SendTooLate
from bridge.mission.presets import get_preset
from bridge.modems.base import ModemFix, ModemRange, ModemSetup
from bridge.modems.evologics.driver import EvologicsBackend
from bridge.modems.evologics.emulator import EvologicsEmulator
from bridge.modems.pty_host import PtyHost
from bridge.modems.transport import ByteTransport
from bridge.sim.ocean import LossCurve
from bridge.sim.service import WaterService

# airtime 20 ms + 1 ms/byte, sound at 1500 m/s: 150 m is 100 ms
FAST = get_preset("evologics-s2c-im").replace(name="test-evologics", overhead_s=0.02,
                                              per_byte_s=0.001)
POSITIONS = {1: (0.0, 0.0, 0.0), 2: (150.0, 0.0, 0.0), 3: (300.0, 0.0, 0.0)}

LEAD_S = 1.0
"""How far ahead of the modem's clock the tests time a send: two suites at once on two cores
(load 8) took over 0.3 s, and once over 0.6 s, to hand an AT*SENDIMS to the emulator, which
then expired it."""


def arun(main: Callable[[], Awaitable[None]], timeout: float = 15.0) -> None:
    asyncio.run(asyncio.wait_for(main(), timeout))


@contextlib.asynccontextmanager
async def modems(tmp_path: Path, *addrs: int, **emu: Any) -> AsyncIterator[
        tuple[WaterService, dict[int, EvologicsEmulator]]]:
    water = WaterService(FAST, seed=1, loss_curve=LossCurve(edge_loss=0.0))
    port = await water.start()
    emulators: dict[int, EvologicsEmulator] = {}
    try:
        for a in addrs:
            setup = ModemSetup(node=f"n{a}", address=a, frame_bytes=64,
                               options={"water": f"127.0.0.1:{port}"}, position=POSITIONS[a])
            emulators[a] = EvologicsEmulator(setup, link=tmp_path / f"modem{a}",
                                             positions=POSITIONS, tcp_port=0, **emu)
            await emulators[a].start()
        yield water, emulators
    finally:
        for e in emulators.values():
            await e.stop()
        await water.stop()


def driver(emulator: EvologicsEmulator, **options: Any) -> EvologicsBackend:
    options.setdefault("device", str(emulator.pty.link))  # the stable link, as at sea
    options.setdefault("timeout_s", 0.5)
    options.setdefault("send_timeout_s", 2.0)
    return EvologicsBackend(ModemSetup(node=emulator.setup.node, address=emulator.setup.address,
                                       frame_bytes=64, options=options))


PAYLOAD = b"a,b\r\n+++AT:3:x\r\n\x00\xff"  # separators, CRLF, a fake TIES packet, binary


@pytest.mark.parametrize("mode", ["data", "command"])
def test_send_and_receive_between_two_modems(tmp_path: Path, mode: str) -> None:
    async def main() -> None:
        async with modems(tmp_path, 1, 2) as (_, emu), driver(emu[1], mode=mode) as a, \
                driver(emu[2], mode=mode) as b:
            loop = asyncio.get_running_loop()
            t0 = loop.time()
            await a.send(PAYLOAD, 2)
            took = loop.time() - t0
            assert FAST.airtime(len(PAYLOAD)) <= took < 0.5  # returns at SENDEND
            rx = await asyncio.wait_for(b.recv(), 2)
            assert (rx.data, rx.src, rx.dest) == (PAYLOAD, 1, 2)
            assert rx.meta["duration_s"] == pytest.approx(FAST.airtime(len(PAYLOAD)), abs=1e-3)
            assert rx.meta["rssi_db"] < 0 and rx.meta["integrity"] > 0
            assert "rx_timestamp_us" in rx.meta and rx.meta["flag"] == "noack"
            assert rx.time - rx.meta["start"] == pytest.approx(rx.meta["duration_s"], abs=1e-6)
            await b.send(b"x" * 64, None)  # broadcast, 255, noack
            rx = await asyncio.wait_for(a.recv(), 2)
            assert (rx.data, rx.src, rx.dest) == (b"x" * 64, 2, None)
            # the modems really are in the mode asked for
            assert {s.mode.value for s in [emu[1]._pty_session]} == {mode}

    arun(main)


def test_over_tcp_and_from_command_mode(tmp_path: Path) -> None:
    async def main() -> None:
        async with modems(tmp_path, 1, 2) as (_, emu):
            emu[1]._pty_session.mode = emu[1]._pty_session.mode.COMMAND  # left in command mode
            async with driver(emu[1]) as a, driver(
                    emu[2], device=f"socket://127.0.0.1:{emu[2].tcp.port}") as b:  # type: ignore
                assert emu[1]._pty_session.mode.value == "data"  # ATO at start-up
                await b.send(b"over tcp", 1)
                rx = await asyncio.wait_for(a.recv(), 2)
                assert rx.data == b"over tcp" and rx.src == 2
                emu[2].drop_tcp()
                with pytest.raises(BackendError, match="lost port"):
                    await asyncio.wait_for(b.recv(), 2)
                with pytest.raises(BackendError):
                    await b.send(b"x", 1)

    arun(main)


def test_ack_delivered_with_range_and_failed(tmp_path: Path) -> None:
    async def main() -> None:
        async with modems(tmp_path, 1, 2, usbl=True) as (_, emu), \
                driver(emu[1], ack=True, usbl=True) as a, driver(emu[2]) as b:
            heard: list[ModemRange] = []
            a.on_range = heard.append
            fixes: list[ModemFix] = []
            a.on_fix = fixes.append
            assert a.ranging == "ack"
            await a.send(b"ping", 2)
            assert a.stats["delivered"] == 1
            assert a.propagation[2][1] == pytest.approx(0.1, abs=1e-3)  # 150 m at 1500 m/s
            (rng,) = heard  # AT?T after DELIVEREDIM: a range, reported like a ping
            assert (rng.peer, rng.method) == (2, "propagation")
            assert rng.travel_time_s == pytest.approx(0.1, abs=1e-3)
            assert a.fixes[2]["e"] == pytest.approx(150.0)  # USBLLONG from the ack
            (fix,) = fixes  # ... handed on, published by the runtime as usbl/<peer>
            assert (fix.peer, fix.range_m, fix.azimuth_deg) == (2, pytest.approx(150.0), 90.0)
            assert fix.covariance == pytest.approx((0.01, 0, 0, 0, 0.01, 0, 0, 0, 0.01))
            await asyncio.wait_for(b.recv(), 2)
            await b.close()
            await emu[2].stop()  # nobody answers any more
            emu[1].settings["RT"] = 500
            await a.send(b"ping", 2)
            assert a.stats["failed"] == 1 and a.stats["sent"] == 2
            assert len(heard) == 1  # no delivery, no range
            emu[2].settings["RP"] = 1

    arun(main)


def test_timed_sends_make_a_two_way_exchange_exact(tmp_path: Path) -> None:
    """AT*SENDIMS on each modem's clock and the modems' own reception stamps: the round trip
    a ↔ b (150 m) comes out to the µs, as DLBL needs, though host and modem clocks differ."""

    async def main() -> None:
        async with modems(tmp_path, 1, 2) as (_, emu), driver(emu[1]) as a, \
                driver(emu[2], tx_lead_s=0.05) as b:
            assert a.timed_send and b.timed_send and (a.tx_lead_s, b.tx_lead_s) == (0.1, 0.05)
            assert abs(a.clock() - time.time()) < 0.05  # the modem clock, near host time
            at_a = a.clock() + LEAD_S
            await a.send(b"request", 2, at=at_a)
            rx_b = await asyncio.wait_for(b.recv(), 2)
            assert rx_b.data == b"request" and "rx_timestamp_us" in rx_b.meta  # RECVIMS
            at_b = b.clock() + LEAD_S
            await b.send(b"reply", 1, at=at_b)
            rx_a = await asyncio.wait_for(a.recv(), 2)
            turnaround = at_b - rx_b.meta["start"]  # b's clock only
            round_trip = rx_a.meta["start"] - at_a  # a's clock only
            assert (round_trip - turnaround) / 2 == pytest.approx(0.1, abs=5e-6)
            duration = rx_a.time - rx_a.meta["start"]
            assert duration == pytest.approx(rx_a.meta["duration_s"], abs=1e-6)
            assert a.stats["expired"] == 0

    arun(main)


def test_a_late_ims_is_reported_and_the_modem_stays_up(tmp_path: Path) -> None:
    async def main() -> None:
        async with modems(tmp_path, 1, 2) as (_, emu), driver(emu[1]) as a, \
                driver(emu[2]) as b:
            with pytest.raises(BackendError, match="EXPIREDIMS"):
                await a.send(b"too late", 2, at=a.clock() - 0.5)
            assert a.stats["expired"] == 1 and a.is_open
            await a.send(b"on time", 2, at=a.clock() + LEAD_S)
            assert (await asyncio.wait_for(b.recv(), 2)).data == b"on time"
            heard: list[ModemRange] = []
            a.on_range = heard.append
            await a.send(b"acked", 2, at=a.clock() + LEAD_S, ack=True)  # SENDIMS has no ack
            assert a.stats["delivered"] == 1 and heard[0].method == "propagation"
            assert (await asyncio.wait_for(b.recv(), 2)).meta["flag"] == "ack"

    arun(main)


def test_untimed_when_asked_or_when_the_clock_is_unreadable(tmp_path: Path) -> None:
    async def main() -> None:
        async with modems(tmp_path, 1, 2) as (_, emu):
            async with driver(emu[1], timed_send=False) as a:
                assert not a.timed_send and abs(a.clock() - time.time()) < 1e-3
            original = emu[1]._query
            emu[1]._query = lambda what: "ERROR WRONG FORMAT" if what == "CLOCK" \
                else original(what)  # type: ignore[method-assign]
            async with driver(emu[1]) as a, driver(emu[2]) as b:
                assert not a.timed_send
                await a.send(b"plain", 2, at=a.clock() + 5.0)  # sent at once: AT*SENDIM
                assert (await asyncio.wait_for(b.recv(), 1)).data == b"plain"

    arun(main)


def test_clock_is_read_again_while_busy(tmp_path: Path) -> None:
    async def main() -> None:
        async with modems(tmp_path, 1, 2) as (_, emu), \
                driver(emu[1], clock_sync_s=0.2, keepalive_s=0) as a:
            first = a.modem_clock.readings
            for _ in range(4):
                await a.send(b"x", 2, at=a.clock() + LEAD_S)
                await asyncio.sleep(0.1)
            assert a.modem_clock.readings > first
            assert abs(a.clock() - time.time()) < 0.05

    arun(main)


def test_unplug_and_replug(tmp_path: Path) -> None:
    async def main() -> None:
        async with modems(tmp_path, 1, 2) as (_, emu):
            a = driver(emu[1])
            await a.open()
            await emu[1].unplug()
            with pytest.raises(BackendError, match="lost port"):
                await asyncio.wait_for(a.recv(), 2)
            with pytest.raises(BackendError):
                await a.send(b"x", 2)
            await a.close()
            fresh = driver(emu[1])
            with pytest.raises(BackendError, match="absent"):
                await fresh.open()  # the cable is still out: the device is gone
            await fresh.close()
            await emu[1].replug()
            async with driver(emu[1]) as again, driver(emu[2]) as b:
                await again.send(b"back", 2)
                assert (await asyncio.wait_for(b.recv(), 2)).data == b"back"

    arun(main)


def test_modem_reboot_mid_transfer(tmp_path: Path) -> None:
    async def main() -> None:
        async with modems(tmp_path, 1, 2) as (_, emu):
            a = driver(emu[1], send_timeout_s=0.5)
            await a.open()
            sending = asyncio.ensure_future(a.send(b"y" * 64, 2))
            await asyncio.sleep(0.03)  # the modem accepted the IM
            await emu[1].reboot(boot_s=0.2)
            with pytest.raises(BackendError, match=r"no SENDEND|no reply"):
                await sending  # the frame is reported failed, never silently lost
            with pytest.raises(BackendError):
                await a.recv()
            await a.close()
            assert emu[1].flags["ZX"] == 0  # the reboot lost the runtime settings
            async with driver(emu[1]) as again, driver(emu[2]) as b:  # re-initialised
                assert emu[1].flags["ZX"] == 1
                await again.send(b"after reboot", 2)
                assert (await asyncio.wait_for(b.recv(), 2)).data == b"after reboot"

    arun(main)


def test_busy_replies_are_retried_then_fail(tmp_path: Path) -> None:
    async def main() -> None:
        async with modems(tmp_path, 1, 2) as (_, emu), \
                driver(emu[1], busy_retries=3, busy_backoff_s=0.01) as a:
            emu[1].inject_busy(2, "BACKOFF STATE")
            await a.send(b"eventually", 2)
            assert a.stats["busy"] == 2 and a.stats["sent"] == 1
            emu[1].inject_busy(4, "DELIVERING")
            with pytest.raises(BackendError, match="BUSY DELIVERING"):
                await a.send(b"never", 2)
            with pytest.raises(BackendError):  # the backend is down: the runtime reopens
                await a.recv()

    arun(main)


def test_busy_retries_end_with_the_turn(tmp_path: Path) -> None:
    """A BUSY modem is asked again only while the retry still ends in the frame's MAC turn
    (``until``): one that would not is a counted drop, and the backend stays up."""
    async def main() -> None:
        async with modems(tmp_path, 1, 2) as (_, emu), \
                driver(emu[1], busy_retries=5, busy_backoff_s=0.2) as a, driver(emu[2]) as b:
            emu[1].inject_busy(2, "BACKOFF STATE")
            loop = asyncio.get_running_loop()
            t0 = loop.time()
            # BUSY at 0, retry at 0.2 s, BUSY; the next would come at 0.6 s, past the turn
            with pytest.raises(SendTooLate, match="retry of AT\\*SENDIM"):
                await a.send(b"my slot", 2, until=a.clock() + 0.5)
            assert loop.time() - t0 < 0.5
            assert a.stats["busy"] == 2 and a.stats["late"] == 1
            assert a.stats["errors"] == 0 and a.stats["sent"] == 0
            assert emu[1].stats["sent"] == 0  # nothing went on the air
            with pytest.raises(TimeoutError):
                await asyncio.wait_for(b.recv(), 0.5)
            await a.send(b"next slot", 2, until=a.clock() + 2.0)  # not failed: still up
            assert (await asyncio.wait_for(b.recv(), 2)).data == b"next slot"
            with pytest.raises(SendTooLate, match="first try would begin"):
                await a.send(b"late", 2, until=a.clock() - 0.01)
            assert a.stats["late"] == 2 and emu[1].stats["sent"] == 1

    arun(main)


def test_no_reply_and_absent_port(tmp_path: Path) -> None:
    async def main() -> None:
        async with modems(tmp_path, 1) as (_, emu):
            emu[1].deaf = True
            a = driver(emu[1], probe_retries=2, timeout_s=0.2)
            with pytest.raises(BackendError, match="no answer"):
                await a.open()
            await a.close()
        missing = driver(emu[1], device=str(tmp_path / "nothing"))
        with pytest.raises(BackendError, match="absent"):
            await missing.open()
        with pytest.raises(BackendError, match="device"):
            EvologicsBackend(ModemSetup(node="x", address=1, frame_bytes=64))

    arun(main)


async def read_line(port: ByteTransport) -> bytes:
    """Bytes up to and including CRLF (a serial read may return any part of a line)."""
    data = b""
    while not data.endswith(b"\r\n"):
        data += await asyncio.wait_for(port.read(), 2)
    return data


def test_guard_time_escape_and_commands(tmp_path: Path) -> None:
    async def main() -> None:
        async with modems(tmp_path, 1, guard_s=0.2) as (_, emu):
            port = ByteTransport(emu[1].pty.device or "", name="raw")
            await port.open()
            try:
                await asyncio.sleep(0.25)
                await port.write(b"+++")
                assert await read_line(port) == b"OK\r\n"
                await port.write(b"AT?AL\r")
                assert await read_line(port) == b"1\r\n"
                await port.write(b"AT*SENDIM,65,2,ack," + b"z" * 65 + b"\r")
                assert await read_line(port) == b"ERROR WRONG FORMAT\r\n"
            finally:
                await port.close()

    arun(main)


def test_pty_host_and_transport_close_cleanly(tmp_path: Path) -> None:
    async def main() -> None:
        got: list[bytes] = []
        host = PtyHost(got.append, link=tmp_path / "link")
        device = await host.open()
        port = ByteTransport(device)
        await port.open()
        pending = asyncio.ensure_future(port.read())
        await asyncio.sleep(0.05)
        await port.close()
        with pytest.raises(BackendError, match="closed"):
            await pending
        await port.close()  # idempotent
        await host.close()
        await host.close()
        assert not (tmp_path / "link").exists()

    arun(main)


def test_corrupt_packets_are_logged_once_per_kind_with_their_bytes(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """A noisy line gives one WARNING per kind, naming the bad packet (it was a WARNING for
    every one), and receptions behind a corrupt length still arrive."""
    caplog.set_level(logging.DEBUG, logger="zab.evologics")

    async def main() -> None:
        async with modems(tmp_path, 1) as (_, emu), driver(emu[1]) as a:
            for n in (999, 998):
                emu[1].pty.write(b"+++AT:%d:RECVIM,3,2,1,ack,1000,-50,100,0.0,abc\r\n" % n)
            emu[1].pty.write(b"+++AT:37:RECVIM,3,2,1,ack,1000,-50,100,0.0,xyz\r\n")
            rx = await asyncio.wait_for(a.recv(), 2)
            assert rx.data == b"xyz" and a.stats["malformed"] == 2

    arun(main)
    warned = [r.getMessage() for r in caplog.records
              if r.levelno == logging.WARNING and "bad modem input" in r.getMessage()]
    assert len(warned) == 1 and "b'+++AT:999:RECVIM,3" in warned[0]


@pytest.mark.parametrize("firmware", ["1.6", "1.7", "1.9"])
def test_the_driver_asks_ati0_and_reads_each_firmwares_recvim(tmp_path: Path,
                                                              firmware: str) -> None:
    """A modem started as firmware 1.6 prints the older RECVIM layout (bitrate, ptime); the
    driver asks ATI0 and parses it, so instant messages arrive from either firmware."""
    async def main() -> None:
        async with modems(tmp_path, 1, 2, firmware=firmware) as (_, emu), \
                driver(emu[1]) as a, driver(emu[2]) as b:
            assert (a.firmware, a.protocol.legacy_recvim) == (firmware, firmware == "1.6")
            await a.send(PAYLOAD, 2)
            rx = await asyncio.wait_for(b.recv(), 2)
            assert (rx.data, rx.src, rx.dest) == (PAYLOAD, 1, 2)
            if firmware == "1.6":  # the propagation time rides in the line itself
                assert rx.meta["propagation_s"] == pytest.approx(150 / 1500, abs=1e-5)
            assert b.stats["malformed"] == 0

    arun(main)


@pytest.mark.parametrize(("firmware", "label"), [("1.7", "IM Rerty Count"),
                                                 ("1.9", "IM Retry Count")])
def test_settings_dump_as_a_real_one_shows_it(tmp_path: Path, firmware: str, label: str
                                              ) -> None:
    """AT&V lists what the real dump (BIR) lists, in its order, with its 1.7 misspelling."""
    async def main() -> None:
        async with modems(tmp_path, 1, firmware=firmware) as (_, emu), driver(emu[1]) as a:
            reply = await a._command("&V")
            keys = [line.split(":")[0] for line in reply.text.splitlines() if line]  # type: ignore[union-attr]
            assert keys == ["Source Level", "Source Level Control", "Gain",
                            "Carrier Waveform ID", "Local Address", "Highest Address",
                            "Cluster Size", "Packet Time", "Retry Count", "Retry Timeout",
                            "Wake Up Active Time", "Wake Up Period", "Promiscuous Mode",
                            "Sound Speed", label, "Pool Size", "Hold Timeout", "Idle Timeout"]

    arun(main)


def test_the_start_line_names_what_is_open(tmp_path: Path,
                                           caplog: pytest.LogCaptureFixture) -> None:
    """`zab emulate` without a TCP port says where its pty is, not "(tcp None)"."""
    async def main() -> None:
        water = WaterService(FAST, seed=1, loss_curve=LossCurve(edge_loss=0.0))
        port = await water.start()
        emulator = EvologicsEmulator(
            ModemSetup(node="n1", address=1, frame_bytes=64,
                       options={"water": f"127.0.0.1:{port}"}, position=POSITIONS[1]),
            link=tmp_path / "modem1", positions=POSITIONS)
        try:
            await emulator.start()
        finally:
            await emulator.stop()
            await water.stop()

    caplog.set_level("INFO", logger="zab.emulate.evologics")
    arun(main)
    line = next(r.getMessage() for r in caplog.records if "emulator n1@1" in r.getMessage())
    assert "None" not in line and line.startswith("evologics emulator n1@1 on /"), line
