"""The emulated Micro-Modem over its pty, as a host speaks to it: the MM2 sentences beyond the
data cycle (pings, LBL, GPIO, sweeps, FDP mini-frames and acknowledgements), sentence by
sentence, against two or three emulators in one simulated water."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from bridge.modems.micromodem.nmea import LineBuffer, Sentence, parse_sentence
from bridge.modems.transport import ByteTransport
from tests.modems.micromodem.test_driver import Bench, bench, run


class Host:
    """A raw NMEA host on one emulator's pty (pyserial, as a lab's own script would be)."""

    def __init__(self, device: str) -> None:
        self.port = ByteTransport(device)
        self._lines = LineBuffer()
        self._heard: list[Sentence] = []

    async def send(self, line: str) -> None:
        await self.port.write(line.encode() + b"\r\n")

    async def expect(self, name: str, timeout: float = 3.0) -> Sentence:
        """The next sentence called ``name`` (``CACMD``, ``SNTTA``); the others before it are
        skipped."""
        async def find() -> Sentence:
            while True:
                while self._heard:
                    s = self._heard.pop(0)
                    if s.name == name:
                        return s
                for line in self._lines.feed(await self.port.read())[0]:
                    self._heard.append(parse_sentence(line))

        return await asyncio.wait_for(find(), timeout)

    async def command(self, line: str, reply: str) -> Sentence:
        await self.send(line)
        return await self.expect(reply)


@contextlib.asynccontextmanager
async def hosts(b: Bench) -> AsyncIterator[dict[int, Host]]:
    opened = {a: Host(d) for a, d in b.devices.items()}
    try:
        for h in opened.values():
            await h.port.open()
            await h.command("$CCCFQ,SRC", "CACFG")  # the modem is there
        yield opened
    finally:
        for h in opened.values():
            await h.port.close()


def fields(s: Sentence) -> list[str]:
    return list(s.fields)


def test_a_command_cut_off_does_not_eat_the_next_one(tmp_path: Path) -> None:
    """A host sentence cut off without its line end is one bad line; the sentence after it
    on the same line is still answered."""
    async def main() -> None:
        async with bench(tmp_path, (1,)) as b, hosts(b) as h:
            await h[1].send("$CCCFQ,SR$CCCFQ,SRC*3A")
            assert fields(await h[1].expect("CAERR"))[1:] == ["NMEA", "1", "Bad sentence"]
            assert fields(await h[1].expect("CACFG")) == ["SRC", "1"]
            assert b.emulators[1].stats["unknown"] == 1

    run(main)


def test_lbl_interrogations(tmp_path: Path) -> None:
    """$CCPDT/$CCPNT are echoed ($SNPDT, $SNPNT with the time first) and answered by $SNTTA:
    the one-way travel time to each transponder listened for that answered in the window."""
    async def main() -> None:
        async with bench(tmp_path, (1, 2, 3), transponders={2: "A", 3: "C"},
                         nav_late_s=0.3) as b, hosts(b) as h:
            echo = await h[1].command("$CCPDT,1,2,0,0,1000,1,1,1,0", "SNPDT")
            assert fields(echo) == ["1", "2", "0", "0", "1000", "1", "1", "1", "0"]
            tta = fields(await h[1].expect("SNTTA"))
            assert (tta[0], tta[1], tta[2], tta[3]) == ("0.2000", "", "0.3000", "")
            assert len(tta[4]) == 9 and tta[4][6] == "."  # hhmmss.ss of the ping
            # narrowband: C not listened for (0 Hz), a window too short for A's 300 m
            echo = await h[1].command("$CCPNT,9000,10,10,300,10000,0,0,0,1", "SNPNT")
            assert len(echo.fields[0]) == 6 and fields(echo)[1:] == [
                "9000", "10", "10", "300", "10000", "0", "0", "0", "1"]
            assert fields(await h[1].expect("SNTTA"))[:4] == ["", "", "", ""]
            # tflag 0: timed by an external pulse, nothing transmitted, nobody answers (once
            # C's late answer to the ping before has come and gone)
            await asyncio.sleep(0.5)
            await h[1].command("$CCPNT,9000,10,10,1000,10000,0,11000,0,0", "SNPNT")
            assert fields(await h[1].expect("SNTTA"))[:4] == ["", "", "", ""]
            for bad in ("$CCPDT,1,5,0,0,1000,1,0,0,0", "$CCPDT,1,1,0,0,1000,1,0,0",
                        "$CCPNT,9000,10,10,0,10000,0,0,0,1"):
                err = await h[1].command(bad, "CAERR")
                assert fields(err)[1:] == ["NMEA", "3", "Bad fields"]

    run(main)


def test_fdp_ping(tmp_path: Path) -> None:
    """$CCCMD,PNG → $CACMD echo (the real MM2's six fields), $CACMA at every modem that hears
    it, $CACMR,PNR at the pinger with the one-way travel time; each with a $CACST."""
    async def main() -> None:
        async with bench(tmp_path, (1, 2, 3)) as b, hosts(b) as h:
            echo = await h[1].command("$CCCMD,PNG,1,2,1,0", "CACMD")
            assert fields(echo) == ["PNG", "1", "2", "1", "0", "0"]
            assert fields(await h[1].expect("CATXF")) == ["2"]
            for a in (2, 3):  # the destination and a modem overhearing
                heard = fields(await h[a].expect("CACMA"))
                assert heard[1:5] == ["PNG", "1", "2", "20.0"] and len(heard) == 9
                assert (await h[a].expect("CACST")).fields[14:16] == ("1", "2")
            reply = fields(await h[1].expect("CACMR"))
            assert reply[0] == "PNR" and reply[2:4] == ["2", "1"] and len(reply) == 10
            assert float(reply[4]) == pytest.approx(0.2, abs=2e-4)
            await h[1].expect("CACST")
            echo = await h[1].command("$CCCMD,PNG,1,3,1,0,C0FFEE", "CACMD")  # with data
            assert fields(echo)[-1] == "3"
            assert float(fields(await h[1].expect("CACMR"))[4]) == pytest.approx(0.3, abs=2e-4)
            for bad in ("$CCCMD,RLS,1,2", "$CCCMD,PNG,2,1,1,0", "$CCCMD,PNG,1,2,0,0"):
                assert fields(await h[1].command(bad, "CAERR"))[1:3] == ["NMEA", "3"]

    run(main)


def test_hardware_control(tmp_path: Path) -> None:
    """$CCMEC to this modem sets and reads its lines (the echo carries the level read); to
    another, $CAMEA there and $CAMER back with the line's level."""
    async def main() -> None:
        async with bench(tmp_path) as b, hosts(b) as h:
            assert fields(await h[1].command("$CCMEC,1,1,5,0,0", "CAMEC"))[-1] == "0"
            assert fields(await h[1].command("$CCMEC,1,1,5,1,1", "CAMEC")) == [
                "1", "1", "5", "1", "1"]
            assert fields(await h[1].command("$CCMEC,1,1,5,0,0", "CAMEC"))[-1] == "1"
            await h[1].command("$CCMEC,1,1,3,3,0", "CAMEC")  # low for 1 ms, then high again
            await asyncio.sleep(0.05)
            assert fields(await h[1].command("$CCMEC,1,1,3,0,0", "CAMEC"))[-1] == "1"
            assert fields(await h[1].command("$CCMEC,1,2,6,1,1", "CAMEC")) == [
                "1", "2", "6", "1", "1"]
            assert fields(await h[2].expect("CAMEA")) == ["1", "2", "6", "1", "1"]
            assert fields(await h[1].expect("CAMER")) == ["2", "1", "6", "1", "1"]
            assert b.emulators[2].lines == {6: 1}
            for bad in ("$CCMEC,1,1,9,0,0", "$CCMEC,1,1,5,1,2", "$CCMEC,1,1,5,0"):
                assert fields(await h[1].command(bad, "CAERR"))[1:3] == ["NMEA", "3"]

    run(main)


def test_fm_sweep_and_firmware_query(tmp_path: Path) -> None:
    """$CCRSP,0,txsig,0 sends an FM sweep and is echoed as $CARSP; $CCCFQ,info answers the
    firmware version under MM2's dotted key."""
    async def main() -> None:
        async with bench(tmp_path) as b, hosts(b) as h:
            assert fields(await h[1].command("$CCCFQ,info", "CACFG")) == [
                "info.firmware_version", "2.0.27087"]
            assert fields(await h[1].command("$CCRSP,0,2,0", "CARSP")) == ["0", "2", "0"]
            assert fields(await h[1].command("$CCRSP,0,3,0", "CAERR"))[1:3] == ["NMEA", "3"]
            for _ in range(50):  # the sweep went into the water
                if b.emulators[1].stats["tx"]:
                    break
                await asyncio.sleep(0.02)
            assert b.emulators[1].stats["tx"] == 1

    run(main)


def test_fdp_mini_frames_and_acknowledgements(tmp_path: Path) -> None:
    """$CCTFP sends user mini-frames with (or without) data frames: $CATFP echo, $CARFP with
    the mini-frame in its user field; with ack the destination's modem acknowledges, and the
    sender prints $CACDR with the frames' masks. $CCTDP with ack likewise."""
    async def main() -> None:
        async with bench(tmp_path, (1, 2, 3)) as b, hosts(b) as h:
            echo = await h[1].command("$CCTFP,2,1,1,1,0,0a0b,0102030405", "CATFP")
            assert fields(echo)[0] == "0" and fields(echo)[2:] == ["2", "1", "1", "1", "0"]
            assert fields(await h[1].expect("CATXF")) == ["7"]
            rfp = fields(await h[2].expect("CARFP"))
            assert rfp[2:8] == ["1", "2", "1", "1", "1", "0"]
            assert rfp[8:] == ["", "1;2;0A0B", "1;5;0102030405"]
            assert fields(await h[3].expect("CARFP"))[9] == "1;2;0A0B"  # overheard, unacked
            cdr = fields(await h[1].expect("CACDR"))
            assert cdr[1] == echo.fields[1] and cdr[2:] == ["2", "1", "1", "01", "0001"]
            await h[1].command(f"$CCTFP,3,5,5,0,0,{'ee' * 90},", "CATFP")  # mini-frame only
            assert fields(await h[3].expect("CARFP"))[4:] == [
                "5", "-1", "0", "0", "", f"1;90;{'EE' * 90}", ""]
            await h[1].command(f"$CCTDP,2,1,1,0,{'11' * 130}", "CATDP")  # three data frames
            assert fields(await h[1].expect("CACDR"))[5:] == ["00", "0007"]
            for bad in (f"$CCTFP,2,1,1,0,0,{'ee' * 91},", "$CCTFP,2,2,1,0,0,ee,",
                        "$CCTFP,2,1,1,0,0,,", "$CCTFP,2,1,1,0,False,ee,"):
                assert fields(await h[1].command(bad, "CAERR"))[1:3] == ["NMEA", "3"]

    run(main)
