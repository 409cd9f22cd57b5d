"""The micromodem backend against emulated modems in the simulated water, through real ptys."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import AsyncIterator, Awaitable, Callable
from pathlib import Path
from typing import Any

import pytest
import serial

from bridge.errors import BackendError, SendTooLate
from bridge.mission.presets import get_preset
from bridge.modems.base import ModemRange, ModemSetup
from bridge.modems.micromodem.driver import MicromodemBackend
from bridge.modems.micromodem.emulator import MicromodemEmulator
from bridge.modems.pty_host import PtyHost
from bridge.sim.service import WaterService

INDEPENDENT = True  # each test starts its own emulators: xdist may spread them

# rate-0 figures sped up 40x so that a test takes well under a second; real sound speed
FAST = get_preset("micromodem-rate0").replace(
    name="micromodem-fast", bitrate_bps=3200.0, overhead_s=0.05, frame_bytes=256
)
POSITIONS = {1: (0.0, 0.0, 10.0), 2: (300.0, 0.0, 10.0), 3: (0.0, 450.0, 10.0)}


class Bench:
    """A water, one emulator per address, and drivers on their ptys."""

    def __init__(self, water: WaterService, emulators: dict[int, MicromodemEmulator],
                 devices: dict[int, str]) -> None:
        self.water, self.emulators, self.devices = water, emulators, devices
        self.backends: list[MicromodemBackend] = []

    def backend(self, address: int, frame_bytes: int = 32, **options: Any) -> MicromodemBackend:
        opts = {"device": self.devices[address], "timeout_s": 1.0, "tx_timeout_s": 3.0,
                **options}
        backend = MicromodemBackend(ModemSetup(node=f"n{address}", address=address,
                                               frame_bytes=frame_bytes, options=opts))
        self.backends.append(backend)
        return backend

    async def modem(self, address: int, **options: Any) -> MicromodemBackend:
        backend = self.backend(address, **options)
        await backend.open()
        return backend


@contextlib.asynccontextmanager
async def bench(tmp_path: Path, addresses: tuple[int, ...] = (1, 2),
                transponders: dict[int, str] | None = None,
                **emulator_options: Any) -> AsyncIterator[Bench]:
    water = WaterService(FAST, seed=1, positions={a: POSITIONS[a] for a in addresses})
    await water.start()
    emulators: dict[int, MicromodemEmulator] = {}
    devices: dict[int, str] = {}
    b = Bench(water, emulators, devices)
    try:
        for a in addresses:
            options = {"water": f"127.0.0.1:{water.port}"}
            if transponders and a in transponders:  # the node stands for an LBL transponder
                options["transponder"] = transponders[a]
            setup = ModemSetup(node=f"n{a}", address=a, frame_bytes=32, options=options,
                               position=POSITIONS[a])
            emulators[a] = MicromodemEmulator(setup, link=tmp_path / f"mm{a}",
                                              dto_s=1.0, **emulator_options)
            devices[a] = await emulators[a].open()
        yield b
    finally:
        for backend in b.backends:
            await backend.close()
        for emulator in emulators.values():
            await emulator.close()
        await water.stop()


def run(test: Callable[[], Awaitable[None]]) -> None:
    asyncio.run(asyncio.wait_for(test(), 20))


def test_send_and_receive_rate0(tmp_path: Path) -> None:
    async def main() -> None:
        async with bench(tmp_path, (1, 2, 3)) as b:
            a, c, d = await b.modem(1), await b.modem(2), await b.modem(3)
            t0 = time.time()
            await a.send(b"hello, ocean", 2)
            took = time.time() - t0
            rx = await asyncio.wait_for(c.recv(), 2)
            assert (rx.data, rx.src, rx.dest) == (b"hello, ocean", 1, 2)
            assert rx.meta["rate"] == 0 and rx.meta["frames"] == 1
            assert rx.meta["start"] <= rx.time
            overheard = await asyncio.wait_for(d.recv(), 2)  # every modem passes every packet
            assert overheard.data == b"hello, ocean" and overheard.dest == 2
            # cycle-init mini-packet then data: two airtimes and a DRQ round trip at least
            assert took >= FAST.airtime(2) + FAST.airtime(12)
            await a.send(b"to all", None)
            rx = await asyncio.wait_for(c.recv(), 2)
            assert rx.data == b"to all" and rx.dest is None
            assert a.stats["sent"] == 2 and a.stats["bad_lines"] == 0

    run(main)


def test_ack_and_failed_ack(tmp_path: Path) -> None:
    async def main() -> None:
        async with bench(tmp_path) as b:
            a = await b.modem(1, ack=True, send_retries=1, tx_timeout_s=0.8)
            c = await b.modem(2)
            await a.send(b"\x01\x02", 2)  # returns once node 2 acknowledged
            assert (await asyncio.wait_for(c.recv(), 2)).data == b"\x01\x02"
            with pytest.raises(BackendError, match="not sent after 2 tries"):
                await a.send(b"nobody", 9)  # no modem 9: no ack
            assert a.stats["retries"] == 1 and a.stats["errors"] == 1
            await a.send(b"again", 2)  # the backend still works

    run(main)


def test_multi_frame_packet_at_rate1_and_rate_limits(tmp_path: Path) -> None:
    async def main() -> None:
        async with bench(tmp_path) as b:
            a = await b.modem(1, rate=1, frame_bytes=192)
            c = await b.modem(2, rate=1, frame_bytes=192)
            data = bytes(range(150))  # three 64-byte frames
            await a.send(data, 2)
            rx = await asyncio.wait_for(c.recv(), 2)
            assert rx.data == data and rx.meta["frames"] == 3 and rx.meta["rate"] == 1
            with pytest.raises(BackendError, match="exceeds"):
                await a.send(bytes(193), 2)
            small = b.backend(1, rate=0, frame_bytes=64)
            assert small.frame_bytes == 32  # rate 0 carries 32 B whatever the mission says
            with pytest.raises(BackendError, match="option rate: Input should be 0, 1, 2, 3, 4"):
                b.backend(1, rate=7)

    run(main)


def test_ping_range(tmp_path: Path) -> None:
    async def main() -> None:
        async with bench(tmp_path, (1, 2, 3)) as b:
            a = await b.modem(1, ping_timeout_s=1.0)
            c = await b.modem(2)
            heard: list[ModemRange] = []
            a.on_range = heard.append
            assert a.ranging == "ping"
            rng = await a.ping(2)
            assert (rng.peer, rng.method) == (2, "ping")
            assert rng.travel_time_s == pytest.approx(300.0 / 1500.0, abs=2e-4)
            assert abs(rng.time - a.clock()) < 1.0
            assert (await a.ping(3)).travel_time_s == pytest.approx(450.0 / 1500.0, abs=2e-4)
            assert heard == [rng, heard[1]] and a.stats["ranges"] == 2
            with pytest.raises(BackendError, match="no ping reply"):
                await a.ping(9)
            with pytest.raises(BackendError, match="address 300"):
                await a.ping(300)
            assert len(heard) == 2  # failures report nothing
            await a.send(b"still fine", 2)  # a missing reply leaves the modem usable
            assert (await asyncio.wait_for(c.recv(), 2)).data == b"still fine"

    run(main)


def test_fdp_ping_range(tmp_path: Path) -> None:
    """``ping: fdp``: MM2's FDP ping ($CCCMD,PNG → $CACMR,PNR) gives the same ranges."""
    async def main() -> None:
        async with bench(tmp_path, (1, 2, 3)) as b:
            a = await b.modem(1, ping="fdp", ping_timeout_s=1.0)
            await b.modem(2)
            rng = await a.ping(2)
            assert (rng.peer, rng.method) == (2, "ping")
            assert rng.travel_time_s == pytest.approx(300.0 / 1500.0, abs=2e-4)
            assert (await a.ping(3)).travel_time_s == pytest.approx(450.0 / 1500.0, abs=2e-4)
            with pytest.raises(BackendError, match="no ping reply from 9"):
                await a.ping(9)
            with pytest.raises(BackendError, match="option ping: Input should be 'mpc' or 'fdp'"):
                b.backend(1, ping="usbl")

    run(main)


@pytest.mark.parametrize("lbl", [
    {"beacons": {"A": 2, "B": 3}, "max_range_m": 500},
    {"beacons": {"A": 2, "B": 3}, "max_range_m": 500, "kind": "narrowband", "tx_hz": 9000,
     "reply_hz": {"A": 10000, "B": 10500}},
], ids=["remus", "narrowband"])
def test_lbl_transponders_range_as_pings(tmp_path: Path, lbl: dict[str, Any]) -> None:
    """Nodes 2 and 3 stand for LBL transponders A and B: a ping to either is one
    interrogation ($CCPDT or $CCPNT → $SNTTA), whose other range goes to on_range too."""
    async def main() -> None:
        async with bench(tmp_path, (1, 2, 3), transponders={2: "A", 3: "B"},
                         nav_late_s=0.3) as b:
            a = await b.modem(1, lbl=lbl)
            heard: list[ModemRange] = []
            a.on_range = heard.append
            rng = await a.ping(2)
            assert (rng.peer, rng.method) == (2, "ping")
            assert rng.travel_time_s == pytest.approx(300.0 / 1500.0, abs=2e-4)
            assert [(r.peer, round(r.travel_time_s, 3)) for r in heard] == [(3, 0.3), (2, 0.2)]
            assert a.stats["ranges"] == 2
            b.water.ocean.set_position(3, (0.0, 600.0, 10.0))  # beyond the 717 ms window
            with pytest.raises(BackendError, match=r"transponder B \(node 3\) did not answer"):
                await a.ping(3)
            assert heard[-1].peer == 2 and a.stats["ranges"] == 3

    run(main)


def test_lbl_option_is_checked(tmp_path: Path) -> None:
    async def main() -> None:
        async with bench(tmp_path, (1,)) as b:
            for bad, why in (({"beacons": {"E": 2}}, "letters of ABCD"),
                             ({"beacons": {"A": 2, "B": 2}}, "two beacons"),
                             ({"beacons": {"A": 2}, "kind": "usbl"}, "remus or narrowband"),
                             ({"beacons": {"A": 2}, "kind": "narrowband"}, "reply_hz"),
                             ({"beacons": {"A": 2}, "range": 9}, "unknown keys")):
                with pytest.raises(BackendError, match=why):
                    b.backend(1, lbl=bad)

    run(main)


def test_fdp_with_ack_waits_for_the_acknowledgement(tmp_path: Path) -> None:
    """An FDP packet with ack returns once the destination's modem acknowledged every data
    frame ($CACDR); to nobody, it fails."""
    async def main() -> None:
        async with bench(tmp_path) as b:
            a = await b.modem(1, rate=1, fdp=True, ack=True, frame_bytes=192, send_retries=0,
                              tx_timeout_s=1.5)
            c = await b.modem(2, rate=1, frame_bytes=192)
            assert await a.send(bytes(range(150)), 2) is True  # three frames acknowledged
            assert (await asyncio.wait_for(c.recv(), 2)).data == bytes(range(150))
            with pytest.raises(BackendError, match="not acknowledged"):
                await a.send(b"nobody", 9)
            assert await a.send(b"to all", None) is None  # a broadcast asks for no ack

    run(main)


def test_unplug_and_replug(tmp_path: Path) -> None:
    async def main() -> None:
        async with bench(tmp_path) as b:
            a, c = await b.modem(1), await b.modem(2)
            await a.send(b"before", 2)
            assert (await asyncio.wait_for(c.recv(), 2)).data == b"before"
            await b.emulators[1].unplug()
            with pytest.raises(BackendError):
                await asyncio.wait_for(a.recv(), 2)  # the port vanished
            with pytest.raises(BackendError):
                await a.send(b"lost?", 2)  # refused, not lost silently
            await a.close()
            with pytest.raises(BackendError, match="absent"):
                await b.backend(1).open()  # port absent at start
            await b.emulators[1].replug()
            fresh = await b.modem(1)  # what the node's factory does after a failure
            await fresh.send(b"after", 2)
            assert (await asyncio.wait_for(c.recv(), 2)).data == b"after"

    run(main)


def test_modem_reboot_mid_transfer(tmp_path: Path) -> None:
    async def main() -> None:
        async with bench(tmp_path) as b:
            a, c = await b.modem(1), await b.modem(2)
            sending = asyncio.create_task(a.send(b"survives a reboot", 2))
            await asyncio.sleep(0.02)  # the cycle-init is on the air
            b.emulators[1].reboot()
            await asyncio.wait_for(sending, 5)
            assert (await asyncio.wait_for(c.recv(), 2)).data == b"survives a reboot"
            assert a.stats["reboots"] == 1 and a.stats["retries"] == 1
            b.emulators[1].reboot()  # between transfers: re-initialised, keeps working
            await asyncio.sleep(0.5)
            await a.send(b"later", 2)
            assert (await asyncio.wait_for(c.recv(), 2)).data == b"later"

    run(main)


async def woken(emulator: MicromodemEmulator, lines: int) -> None:
    """Until the cycles ``emulator`` stalled on have run, and it has had more than ``lines``
    lines from its host."""
    for _ in range(250):
        if not emulator._held and not emulator._busy() and emulator.stats["lines"] > lines:
            return
        await asyncio.sleep(0.02)
    raise AssertionError("the stalled modem never woke")


@pytest.mark.parametrize(("tx_timeout_s", "turn_s", "hold_s", "why"), [
    (3.0, 0.6, 1.2, "called back"),  # the turn ends during the stalled try
    (0.5, 0.9, 1.5, "a retry"),  # the try times out first, a retry would not end in the turn
])
def test_a_stalled_modem_never_transmits_after_the_turn(
        tmp_path: Path, tx_timeout_s: float, turn_s: float, hold_s: float, why: str) -> None:
    """Found from outside: one try's timeout (19.4 s at rate 0) outlasts a 14 s TDMA slot, and
    the retry, or the stalled cycle the modem carried out late, went into the next node's slot.
    Now no cycle begins after ``until``, the stalled one is called back (a blank $CCTXD when its
    $CADRQ comes), and the frame is a counted drop."""
    async def main() -> None:
        async with bench(tmp_path) as b:
            a = await b.modem(1, rate=1, frame_bytes=192, tx_timeout_s=tx_timeout_s,
                              send_retries=2)
            c = await b.modem(2, rate=1, frame_bytes=192)
            sender = b.emulators[1]
            sender.stall(hold_s)  # the $CCCYC is taken hold_s late, then carried out
            lines = sender.stats["lines"] + 1  # (and the $CCTXD it ends with)
            loop = asyncio.get_running_loop()
            t0 = loop.time()
            with pytest.raises(SendTooLate, match=why):
                await a.send(b"in my slot only", 2, until=a.clock() + turn_s)
            assert loop.time() - t0 < turn_s + 0.3  # dropped at the turn's end, not later
            assert a.stats["late"] == 1 and a.stats["retries"] == 0
            assert a.stats["errors"] == 0 and a.stats["sent"] == 0
            await woken(sender, lines)  # it echoes, asks for the data and gets none
            assert sender.stats["stalled"] == 1
            assert sender.stats["tx"] == 0  # it sent nothing, before the turn's end or after
            with pytest.raises(TimeoutError):
                await asyncio.wait_for(c.recv(), 0.3)
            await a.send(b"next slot", 2, until=a.clock() + 5.0)  # the backend is fine
            assert (await asyncio.wait_for(c.recv(), 2)).data == b"next slot"

    run(main)


def test_retries_within_the_turn_and_none_after_it(tmp_path: Path) -> None:
    async def main() -> None:
        async with bench(tmp_path) as b:
            a = await b.modem(1, rate=1, frame_bytes=192, tx_timeout_s=0.5, send_retries=2)
            c = await b.modem(2, rate=1, frame_bytes=192)
            b.emulators[1].stall(1.5)
            lines = b.emulators[1].stats["lines"] + 3  # two $CCCYC, a $CCTXD, and ...
            # a long turn: the retry (0.5 s backoff, 2 s on the air at 250 bit/s) fits in it
            await a.send(b"second try", 2, until=a.clock() + 10.0)
            assert (await asyncio.wait_for(c.recv(), 2)).data == b"second try"
            assert a.stats["retries"] == 1 and "late" not in a.stats
            await woken(b.emulators[1], lines)  # ... the stalled first cycle's: no data
            assert b.emulators[1].stats["tx"] == 1
            lines = b.emulators[1].stats["lines"]
            with pytest.raises(SendTooLate, match="first try would begin"):
                await a.send(b"too late", 2, until=a.clock() - 0.1)
            assert b.emulators[1].stats["lines"] == lines  # not a line to the modem
            assert a.stats["late"] == 1

    run(main)


def test_bad_lines_are_logged_at_warning_once_per_kind(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """A noisy serial line is seen in the log (it was DEBUG only): one WARNING per kind with
    the offending bytes and the count."""
    caplog.set_level(logging.DEBUG, logger="zab.micromodem")

    async def main() -> None:
        async with bench(tmp_path, (1,), rev_period_s=None) as b:
            a = await b.modem(1)
            b.emulators[1].pty.write(b"$CATXF,2*00\r\n$CATXF,3*00\r\nxx$CATXF,2*56\r\n")
            while a.stats["bad_lines"] < 3:
                await asyncio.sleep(0.01)

    run(main)
    warned = [r.getMessage() for r in caplog.records
              if r.levelno == logging.WARNING and "bad modem input" in r.getMessage()]
    assert len(warned) == 2
    assert "checksum mismatch" in warned[0] and "b'$CATXF,2*00'" in warned[0]
    assert "noise before" in warned[1] and "b'xx'" in warned[1]


def test_bad_checksums_both_ways(tmp_path: Path) -> None:
    async def main() -> None:
        async with bench(tmp_path, rev_period_s=0.1) as b:
            a = await b.modem(1)
            b.emulators[1].pty.write(b"$CATXF,2*00\r\n$CAREV,1,AUV*\r\n")
            await a.send(b"x", 2)  # interleaved $CAREV and garbage do not disturb it
            assert a.stats["bad_lines"] == 2
            assert b.emulators[1].stats["bad_checksum"] == 0
            port = serial.serial_for_url(b.devices[2], baudrate=19200, timeout=0.2)
            try:
                port.write(b"$CCCFG,SRC,2*00\r\n$CCXYZ,1\r\n$CCCFQ,SRC\r\n")
                await asyncio.sleep(0.3)
                lines = port.read(4096).decode().split("\r\n")
            finally:
                port.close()
            errors = [ln for ln in lines if ln.startswith("$CAERR")]
            assert any(",NMEA,2,Bad checksum*" in ln for ln in errors)
            assert any(",NMEA,1,Unknown command*" in ln for ln in errors)
            assert "$CACFG,SRC,2*30" in lines
            assert b.emulators[2].stats["bad_checksum"] == 1

    run(main)


def test_start_up_faults(tmp_path: Path) -> None:
    async def main() -> None:
        with pytest.raises(BackendError, match="absent"):
            bad = MicromodemBackend(ModemSetup("x", 1, 32, {"device": str(tmp_path / "none")}))
            await bad.open()
        with pytest.raises(BackendError, match="'device'"):
            MicromodemBackend(ModemSetup("x", 1, 32, {}))
        silent = PtyHost(lambda data: None)  # a port with no modem behind it
        device = await silent.open()
        try:
            mute = MicromodemBackend(ModemSetup("x", 1, 32, {"device": device, "timeout_s": 0.2,
                                                             "retries": 1}))
            with pytest.raises(BackendError, match="no reply"):
                await mute.open()
            await mute.close()
        finally:
            await silent.close()
        async with bench(tmp_path, (1,)) as b:
            other = b.backend(1)
            object.__setattr__(other, "address", 5)  # $CCCFG,SRC,5: the modem renumbers
            await other.open()
            assert b.emulators[1].address == 5 and b.emulators[1].nvram["SRC"] == "5"
            for _ in range(500):  # it rejoins the water under its new address, alone
                if b.water.stats()["clients"] == [5]:
                    break
                await asyncio.sleep(0.02)
            assert b.water.stats()["clients"] == [5]

    run(main)


def test_fdp_and_legacy_side_by_side_at_every_fdp_rate(tmp_path: Path) -> None:
    """An MM2 sends by FDP at rates 1-6 (rate 6: 6 × 32 B) to a legacy sender's modem, and
    each receives the other's packets whole: legacy and FDP side by side."""
    async def main() -> None:
        async with bench(tmp_path) as b:
            legacy = await b.modem(2, rate=1, frame_bytes=192)
            for rate in (1, 2, 3, 4, 5, 6):
                fdp = await b.modem(1, rate=rate, fdp=True, frame_bytes=192)
                data = bytes(range(rate, rate + 150))
                await fdp.send(data, 2)
                rx = await asyncio.wait_for(legacy.recv(), 2)
                size = {1: 64, 2: 64, 3: 256, 4: 256, 5: 256, 6: 32}[rate]
                assert (rx.data, rx.src, rx.meta["rate"]) == (data, 1, rate)
                assert rx.meta["frames"] == -(-150 // size)
                await legacy.send(data[::-1], 1)  # and back, by the legacy cycle
                back = await asyncio.wait_for(fdp.recv(), 2)
                assert (back.data, back.meta["rate"]) == (data[::-1], 1)
                await fdp.close()
            with pytest.raises(BackendError, match="FDP sends at rates 1-6"):
                b.backend(1, rate=0, fdp=True)

    run(main)


def test_a_packet_lost_in_the_water_is_a_bad_crc(tmp_path: Path) -> None:
    """The water loses every packet (its signal still arrives): the receiving modem prints
    $CAMSG,BAD_CRC per frame, the driver counts them and the packet as lost."""
    async def main() -> None:
        async with bench(tmp_path) as b:
            a = await b.modem(1, rate=1, frame_bytes=192)
            c = await b.modem(2, rate=1, frame_bytes=192)
            b.water.ocean.loss = 1.0
            await a.send(bytes(100), 2)  # two frames
            for _ in range(100):  # (the packet is lost at the first BAD_CRC: wait for both)
                if c.stats["bad_crc"] >= 2:
                    break
                await asyncio.sleep(0.02)
            assert (c.stats["bad_crc"], c.stats["rx_lost"]) == (2, 1)
            assert b.emulators[2].stats["bad_crc"] == 2 and c.stats["received"] == 0

    run(main)


def test_a_cycle_init_without_its_data_is_a_packet_timeout(tmp_path: Path) -> None:
    """Node 2 hears node 1's rate-0 cycle-init, then sails out of range before the data:
    after PTO its modem prints $CAMSG,PACKET_TIMEOUT and the driver counts it."""
    async def main() -> None:
        async with bench(tmp_path, pto_s=0.3) as b:
            a, c = await b.modem(1), await b.modem(2)
            sender = b.emulators[1]
            transmit = sender._transmit

            async def then_leave(header: Any, body: bytes, **kw: Any) -> bool:
                sent = await transmit(header, body, **kw)
                if header.kind.name == "CYCLE_INIT":  # the data goes after: out of range
                    b.water.ocean.set_position(2, (1e6, 0.0, 10.0))
                return sent

            sender._transmit = then_leave  # type: ignore[method-assign]
            await a.send(b"never heard", 2)
            for _ in range(100):
                if c.stats["packet_timeout"]:
                    break
                await asyncio.sleep(0.02)
            assert (c.stats["packet_timeout"], c.stats["rx_lost"]) == (1, 1)
            assert b.emulators[2].stats["packet_timeout"] == 1

    run(main)


@pytest.mark.parametrize("how", ["clk", "tms"])
def test_the_driver_sets_and_reads_the_modem_clock(tmp_path: Path, how: str) -> None:
    async def main() -> None:
        async with bench(tmp_path, (1,)) as b:
            b.emulators[1].clock_offset_s = 3600.0  # the modem's clock is an hour off
            a = await b.modem(1, set_clock=how)
            # set at the top of a second, naming it: the modem now keeps the host's time
            assert abs(b.emulators[1].clock_offset_s) < 0.01
            if how == "tms":  # read back with $CCTMQ
                assert abs(a.stats["clock_offset_ms"]) < 100
            with pytest.raises(BackendError, match="set_clock"):
                b.backend(1, set_clock="gps")

    run(main)


def test_log_lines_name_the_modem_as_a_user_would() -> None:
    """Found from outside: lines read '<MicromodemBackend auv1@2 new>: …'."""
    backend = MicromodemBackend(ModemSetup("auv1", 2, 32, {"device": "/dev/null"}))
    assert str(backend) == "micromodem modem 'auv1'"
    assert repr(backend) == "<MicromodemBackend auv1@2 new>"  # (for debugging)
