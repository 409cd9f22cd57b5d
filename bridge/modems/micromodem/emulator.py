"""An emulated WHOI Micro-Modem 2: NMEA on a pseudo-terminal, packets in the simulated water.

The emulator answers the host like the modem in the reference (section 2, checklist 2.7) and
like the MM2 its ``$CAREV`` announces: it echoes ``$CCCYC``/``$CCMPC``/``$CCMUC``/``$CCCFG``/
``$CCCLK``/``$CCMSC``, answers ``$CCCFQ`` (one ``$CACFG`` per key; ``ALL``/``TOP`` all of them),
runs the legacy data cycle (rate 0: the cycle-init mini-packet goes out first, then ``$CATXF,2``
and ``$CAXST``, then the ``$CADRQ``; rates 1–6: a second ``$CACYC``), MM2's FDP (``$CCTDP`` →
``$CATDP``, ``$CCTFP`` with mini-frames → ``$CATFP``, then ``$CATXP``/``$CATXF``; received as
``$CARFP``; with ack the receiving modem acknowledges and the sender prints ``$CACDR``), the
clock (``$CCCLK``, ``$CCTMS`` → ``$CATMS``, ``$CCTMQ`` → ``$CATMQ`` half a second later),
``$CCALQ`` → ``$CAALQ``, and the rest of what a lab drives an MM2 with:

* pings: ``$CCMPC`` (``$CAMPA`` at the pinged modem, ``$CAMPR`` with the one-way travel time),
  the FDP ping ``$CCCMD,PNG`` (``$CACMD`` echo, ``$CACMA`` at every modem that hears it,
  ``$CACMR,PNR`` with the travel time, each followed by a ``$CACST``), and LBL interrogations
  ``$CCPDT``/``$CCPNT`` (echoed as ``$SNPDT``/``$SNPNT``, answered by ``$SNTTA``; see
  :mod:`~bridge.modems.micromodem.nav`): an emulated node whose modem options name a
  ``transponder`` letter (A-D) stands for that LBL transponder at its position, and answers
  every interrogation it hears after the REMUS turn-around;
* ``$CCMEC`` (GPIO lines: ``$CAMEC`` echo, for a read with the line's level; to another modem
  ``$CAMEA`` there and ``$CAMER`` back) and ``$CCRSP`` (an FM sweep: ``$CARSP`` echo);

prints ``$CAERR`` for unknown commands, bad checksums and data timeouts, ``$CAREV,…,INIT`` when
it (re)boots and ``$CAREV,…,AUV`` periodically while ``REV`` is 1, all interleaved with
asynchronous receptions. ``docs/backends.md`` says, per sentence, what each layout rests on.

It honours the configuration it holds: ``SRC`` renumbers it (it rejoins the water under the new
address), ``REV`` 0 stops the periodic ``$CAREV``, ``RXP``/``CST``/``XST`` 0 silence
``$CARXP``/``$CACST``/``$CAXST``, ``DTO`` is the data-request timeout, ``PTO`` the packet
timeout, ``TAT`` the LBL turn-around it allows for. With ``crc32`` every line it prints carries
the MM2's 8-digit CRC-32; what the host sends may carry either checksum, and a wrong or
lower-case one is refused.

Every acoustic packet is one transmission of a :class:`~bridge.modems.sim.SimBackend` in the
water, which adds airtime, propagation, collisions and loss: a data packet goes as one
transmission of all its frames (:mod:`~bridge.modems.micromodem.air`), as the modem sends one
PSK packet behind one probe; the ``micromodem-rate<N>`` presets carry a whole packet of their
rate (an FDP packet's mini-frames come on top). What the real modem's waveform conveys
implicitly (packet type, cycle-init fields) travels in the water's ``dest`` metadata.
Mini-packets (cycle-init, ack, pings, ``$CCMUC``, GPIO commands, sweeps) are 2-byte
transmissions. A packet whose signal reached the modem but that the water lost (a collision,
bit errors, loss at range) prints ``$CAMSG,BAD_CRC,<frame>`` for each of its frames; a rate-0
cycle-init whose data never comes prints ``$CAMSG,PACKET_TIMEOUT,1`` after ``PTO`` seconds,
each with its ``$CACST``. Travel times come from the water (its propagation, not the modems'
clocks).

A test makes it stall (:meth:`MicromodemEmulator.stall`): the next ``$CCCYC`` is taken seconds
late, as a modem busy or hung would, then carried out (echo, cycle-init, ``$CADRQ``).

Not modelled: NVRAM semantics of other keys (stored and echoed only), ``$CCCMD`` modes other
than ``PNG`` (refused as bad fields), the data of an FDP ping, sleep (``$CCMSC`` with minutes >
0 is echoed only), USBL (``$CAUSB2``), PPS synchronisation of LBL pings.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import datetime
import logging
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bridge.core.loaded import LoadedMission
from bridge.errors import BackendError
from bridge.mission.presets import UnknownPresetError, get_preset
from bridge.modems.base import ModemSetup, Reception
from bridge.modems.micromodem import nav
from bridge.modems.micromodem.air import (
    AirKind,
    Header,
    pack_frames,
    pack_header,
    unpack_frames,
    unpack_header,
)
from bridge.modems.micromodem.nmea import LineBuffer, NmeaError, Sentence, parse_sentence
from bridge.modems.micromodem.rates import FDP_MINI_BYTES, FDP_RATES, get_rate
from bridge.modems.pty_host import PtyHost
from bridge.modems.setup import modem_setup
from bridge.modems.sim import SimBackend, water_options

__all__ = ["MicromodemEmulator", "run_emulator"]

log = logging.getLogger("zab.emulate.micromodem")

REVISION = "2.0.27087"
"""Firmware revision printed in ``$CAREV`` (the MM2 revision seen in the reference)."""

TURNAROUND_S = 0.05
"""Turn-around of a pinged modem or transponder (REMUS LBL TAT, reference 2.6 [V])."""

MINI = b"\x00\x00"
"""Body of a mini-packet in the water (the real one carries 13 bits)."""

WATER_RETRY_S = 1.0

TMQ_DELAY_S = 0.5
"""``$CATMQ`` comes about half a second after ``$CCTMQ`` (goby waits 500 ms more) [V]."""

API_LEVEL = 11
"""What ``$CAALQ`` reports (pyacomms' default level) [U: a real MM2's name and level]."""

MAX_ADDRESS = 127
"""Highest address the emulator takes (the driver's range; its water header has 7 bits)."""

NAV_GUARD_S = 0.05
"""Between two transponders' answers in the water (see :meth:`MicromodemEmulator._on_air`)."""

PING_DATA_BYTES = 32
"""Most hex data an FDP ping (``$CCCMD,PNG``) takes (pyacomms' limit) [V]."""

MEC_TOGGLE_S = (0.001, 0.5, 1.0, 2.0, 6.0, 10.0, 20.0, 30.0)
"""How long a ``$CCMEC`` toggle holds the line, by its argument (libumutil ``MEC_TIMEO_*``)."""

TX_LEVEL = 1
"""The transmit level an FDP ping reports (the real ``$CACMR``'s) [U: its meaning]."""


def _hhmmss() -> str:
    return time.strftime("%H%M%S", time.gmtime())


def _iso(t: float) -> str:
    """``t`` (seconds) as MM2 prints times: ISO 8601 UTC with microseconds."""
    return datetime.datetime.fromtimestamp(t, datetime.UTC).strftime("%Y-%m-%dT%H:%M:%S.%f")


class MicromodemEmulator:
    """One emulated Micro-Modem: a :class:`PtyHost` on the host side, a sim modem in the water.

    ``setup`` is the node's :class:`ModemSetup` with a ``water`` option (and a
    ``transponder`` letter when the node stands for an LBL transponder). ``dto_s`` is the
    data-request timeout, ``rev_period_s`` the period of ``$CAREV,…,AUV`` (``None``: never),
    ``boot_s`` how long a reboot takes, ``ping_timeout_s`` how long a ping waits for its reply,
    ``nav_late_s`` how long an LBL ping waits past its window for answers that were in time
    (default: what the water's preset takes for four transponders' answers, and 3 s more: the
    processes of a loaded machine answer late in real time, though in time in the water's; a
    real modem waits only the window, so only a missing transponder's $SNTTA comes later).
    """

    def __init__(
        self,
        setup: ModemSetup,
        *,
        link: Path | None = None,
        dto_s: float = 2.0,
        rev_period_s: float | None = 10.0,
        boot_s: float = 0.2,
        ping_timeout_s: float = 10.0,
        pto_s: float = 10.0,
        crc32: bool = False,
        nav_late_s: float | None = None,
    ) -> None:
        # the water sets the size limit; its dest carries packed headers, never a broadcast
        self.setup = dataclasses.replace(setup, frame_bytes=4096,
                                         options=water_options(setup.options))
        self.address = setup.address
        self.rev_period_s = rev_period_s
        self.boot_s = boot_s
        self.ping_timeout_s = ping_timeout_s
        self.crc32 = crc32
        try:  # the airtime of a nav tone in this water: the preset's, for a mini-packet
            tone_s = get_preset(str(setup.options["preset"])).airtime(len(MINI))
        except (KeyError, UnknownPresetError):
            tone_s = 0.05
        self.nav_slot_s = tone_s + NAV_GUARD_S
        self.nav_late_s = 4 * self.nav_slot_s + 3.0 if nav_late_s is None else nav_late_s
        letter = str(setup.options.get("transponder", "")).upper()
        if letter and (len(letter) != 1 or letter not in nav.BEACONS):
            raise BackendError(f"micromodem emulator of {setup.node!r}: transponder must be one "
                               f"of {', '.join(nav.BEACONS)}, got {letter!r}")
        self.transponder = letter or None
        self.lines: dict[int, int] = {}  # GPIO line levels ($CCMEC)
        self.defaults: dict[str, str] = {"CST": "1", "XST": "1", "REV": "1", "RXP": "1",
                                         "DTO": f"{dto_s:g}", "PTO": f"{pto_s:g}"}
        self.nvram: dict[str, str] = {"SRC": str(setup.address), **self.defaults}
        self.stats: dict[str, int] = {"lines": 0, "bad_checksum": 0, "unknown": 0, "tx": 0,
                                      "rx": 0, "tx_errors": 0, "reboots": 0, "rx_no_cycle_init": 0,
                                      "bad_crc": 0, "packet_timeout": 0, "stalled": 0}
        self.clock_offset_s = 0.0  # modem clock minus host clock, set by $CCCLK / $CCTMS
        self.pty = PtyHost(self._on_host_bytes, link=link)
        self._lines = LineBuffer()
        self._sim: SimBackend | None = None
        self._tasks: set[asyncio.Task[Any]] = set()
        self._water_task: asyncio.Task[None] | None = None
        self._rev_task: asyncio.Task[None] | None = None
        self._cycle: asyncio.Task[None] | None = None
        self._txd: asyncio.Future[Sentence] | None = None
        self._ping: tuple[int, asyncio.Future[float]] | None = None
        self._nav: _NavPing | None = None
        self._heard: dict[int, Header] = {}  # last cycle-init heard from each transmitter
        self._waiting: dict[int, asyncio.TimerHandle] = {}  # rate-0 data awaited, by sender
        self._seq = 0
        self._booted = time.monotonic()
        self._stalls: list[float] = []  # holds of the next $CCCYCs (:meth:`stall`)
        self._held: set[asyncio.TimerHandle] = set()

    # -- lifecycle -----------------------------------------------------------------------------

    @property
    def dto_s(self) -> float:
        return float(self.nvram.get("DTO") or self.defaults["DTO"])

    @property
    def pto_s(self) -> float:
        return float(self.nvram.get("PTO") or self.defaults["PTO"])

    def _on(self, key: str) -> bool:
        return self.nvram.get(key, "1") != "0"

    def modem_time(self) -> float:
        """The modem's clock (seconds since the epoch), as ``$CCCLK``/``$CCTMS`` set it."""
        return time.time() + self.clock_offset_s

    def _join(self) -> SimBackend:
        sim = SimBackend(self.setup)
        sim.on_loss = self._on_loss
        return sim

    async def open(self) -> str:
        """Join the water, open the pty, print the boot banner; returns the device path."""
        self._sim = self._join()
        await self._sim.open()
        device = await self.pty.open()
        self._water_task = asyncio.create_task(self._water_loop(), name=f"mm-water-{self.address}")
        if self.rev_period_s:
            self._rev_task = asyncio.create_task(self._rev_loop(), name="mm-rev")
        self._banner()
        return device

    async def close(self) -> None:
        """Close the pty and leave the water; cancel every task. Idempotent."""
        self._drop_held()
        for timer in self._waiting.values():
            timer.cancel()
        self._waiting.clear()
        tasks = [t for t in (self._water_task, self._rev_task, self._cycle, *self._tasks) if t]
        self._water_task = self._rev_task = self._cycle = None
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        self._tasks.clear()
        await self.pty.close()
        sim, self._sim = self._sim, None
        if sim is not None:
            await sim.close()

    async def __aenter__(self) -> MicromodemEmulator:
        await self.open()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    async def unplug(self) -> None:
        """Pull the serial cable (the modem keeps running)."""
        self._lines.clear()
        await self.pty.unplug()

    async def replug(self) -> str:
        """Plug the cable back in; returns the (new) device path."""
        self._lines.clear()
        return await self.pty.replug()

    def stall(self, hold_s: float, count: int = 1) -> None:
        """Stall on the next ``count`` ``$CCCYC``: each is taken ``hold_s`` seconds late (no
        echo before), as by a modem busy or hung that then carries the cycle out."""
        self._stalls += [hold_s] * count

    def reboot(self) -> None:
        """Reboot now (power glitch or ``$CCMSC,…,0``): abandon the cycle, print ``INIT``."""
        self.stats["reboots"] += 1
        self._drop_held()
        self._cancel_cycle()
        self._lines.clear()
        self._heard.clear()
        for timer in self._waiting.values():
            timer.cancel()
        self._waiting.clear()
        self._spawn(self._boot())

    # -- host side -----------------------------------------------------------------------------

    def _print(self, kind: str, *fields: object, talker: str = "CA") -> None:
        self._write(Sentence(talker, kind, tuple(_text(f) for f in fields)))

    def _write(self, sentence: Sentence) -> None:
        self.pty.write(sentence.encode(crc32=self.crc32))

    def _error(self, module: str, number: int | str, message: str = "") -> None:
        self._print("ERR", _hhmmss(), module, number, *([message] if message else []))

    def _banner(self) -> None:
        uptime = time.strftime("%H%M%S", time.gmtime(time.monotonic() - self._booted))
        self._print("REV", uptime, "INIT", REVISION)
        self._print("REV", uptime, "AUV", REVISION)

    async def _boot(self) -> None:
        await asyncio.sleep(self.boot_s)
        self._booted = time.monotonic()
        self._banner()

    async def _rev_loop(self) -> None:
        assert self.rev_period_s
        while True:
            await asyncio.sleep(self.rev_period_s)
            if self._on("REV"):  # $CCCFG,REV,0 stops it
                uptime = time.strftime("%H%M%S", time.gmtime(time.monotonic() - self._booted))
                self._print("REV", uptime, "AUV", REVISION)

    def _on_host_bytes(self, data: bytes) -> None:
        lines, overflow = self._lines.feed(data)
        if overflow is not None:
            self._error("NMEA", 1, "Line too long")
        for line in lines:
            self.stats["lines"] += 1
            start = line.rfind(b"$")  # resynchronise on the last '$' (a command cut off before)
            if b"$" in line[:max(start, 0)]:
                self.stats["unknown"] += 1
                self._error("NMEA", 1, "Bad sentence")  # [U] number and text
            try:
                if start < 0:
                    raise NmeaError("no '$'")
                sentence = parse_sentence(line[start:])
            except NmeaError as exc:
                bad_sum = "checksum" in str(exc)
                self.stats["bad_checksum" if bad_sum else "unknown"] += 1
                # [U] the error number and text are not in the reference
                self._error("NMEA", 2 if bad_sum else 1,
                            "Bad checksum" if bad_sum else "Bad sentence")
                continue
            try:
                self._command(sentence)
            except (ValueError, IndexError):
                self.stats["unknown"] += 1
                self._error("NMEA", 3, "Bad fields")  # [U] number and text

    def _command(self, s: Sentence) -> None:
        f = s.fields
        if s.talker != "CC":
            raise ValueError("not a host sentence")
        handler = getattr(self, f"_cc_{s.kind.lower()}", None)
        if handler is None:
            self.stats["unknown"] += 1
            self._error("NMEA", 1, "Unknown command")
            return
        handler(f)

    def _cc_cfg(self, f: tuple[str, ...]) -> None:
        key, value = f[0], f[1]
        if key == "ALL" and value == "0":  # NVRAM reset: the factory values
            self.nvram = {"SRC": str(self.address), **self.defaults}
        elif key == "SRC":
            address = int(value)
            if not 0 <= address <= MAX_ADDRESS:
                raise ValueError("SRC out of range")
            self.nvram["SRC"] = value
            if address != self.address:
                self._renumber(address)
        else:
            if key in ("DTO", "PTO"):
                float(value)
            self.nvram[key] = value
        self._print("CFG", key, value)

    def _cc_cfq(self, f: tuple[str, ...]) -> None:
        """One ``$CACFG`` per key; ``info`` the firmware version, as MM2's dotted key that
        pyacomms reads it from [V]."""
        if f[0] == "info":
            self._print("CFG", "info.firmware_version", REVISION)
            return
        keys = sorted(self.nvram) if f[0] in ("ALL", "TOP") else [f[0]]
        for key in keys:
            self._print("CFG", key, self.nvram.get(key, ""))

    def _cc_cyc(self, f: tuple[str, ...]) -> None:
        _src, dest, rate, ack, frames = (int(x) for x in f[1:6])
        spec = get_rate(rate)
        if not (0 <= dest <= MAX_ADDRESS and 1 <= frames <= spec.frames and ack in (0, 1)):
            raise ValueError("bad cycle-init")
        if not self._stalls:
            self._cycle_init(f)
            return
        self.stats["stalled"] += 1  # (stall): taken later, as it is

        def take() -> None:
            self._held.discard(handle)
            self._cycle_init(f)

        handle: asyncio.TimerHandle = asyncio.get_running_loop().call_later(
            self._stalls.pop(0), take)
        self._held.add(handle)

    def _drop_held(self) -> None:
        for handle in self._held:
            handle.cancel()
        self._held.clear()

    def _cycle_init(self, f: tuple[str, ...]) -> None:
        """A checked ``$CCCYC``: echo it, then run the cycle (or transmit the poll)."""
        src, dest, rate, ack, frames = (int(x) for x in f[1:6])
        self._print("CYC", *f[:6])
        if self._busy():
            self._error("CYC", 1, "Busy")  # [U]
            return
        if src == self.address:
            self._cycle = asyncio.create_task(self._run_cycle(dest, rate, bool(ack), frames))
        else:  # a poll: ask node src to send to dest
            self._spawn(self._transmit(Header(AirKind.CYCLE_INIT, src, dest, rate, bool(ack),
                                              0, frames, self._next_seq()), MINI))

    def _cc_txd(self, f: tuple[str, ...]) -> None:
        if self._txd is None or self._txd.done():
            self._error("NMEA", 4, "Unexpected TXD")  # [U]
            return
        bytes.fromhex(f[3])
        self._txd.set_result(Sentence("CC", "TXD", f))

    def _cc_tdp(self, f: tuple[str, ...]) -> None:
        """``$CCTDP,dest,rate,ack,reserved,hex``: one FDP packet [V layout]."""
        if len(f) != 5:
            raise ValueError("$CCTDP takes 5 fields")
        self._fdp("TDP", f[0], f[1], f[1], f[2], f[3], mini=b"", data=bytes.fromhex(f[4]))

    def _cc_tfp(self, f: tuple[str, ...]) -> None:
        """``$CCTFP,dest,minirate,datarate,ack,reserved,minihex,datahex``: one FDP packet with
        user mini-frames, in the layout pyacomms writes for firmware before 2.1.9 [V layout]."""
        if len(f) != 7:
            raise ValueError("$CCTFP takes 7 fields")
        self._fdp("TFP", f[0], f[1], f[2], f[3], f[4], mini=bytes.fromhex(f[5]),
                  data=bytes.fromhex(f[6]))

    def _fdp(self, kind: str, *numbers: str, mini: bytes, data: bytes) -> None:
        """``dest,minirate,rate,ack,reserved`` (all numbers): echo ``$CATDP``/``$CATFP,errflag,
        id,dest,[minirate,]rate,ack,reserved`` and send the packet [U: the echo after the id]."""
        dest, minirate, rate, ack, _reserved = (int(x) for x in numbers)
        if not (0 <= dest <= MAX_ADDRESS and rate in FDP_RATES and ack in (0, 1)
                and (mini or data) and len(data) <= get_rate(rate).max_bytes
                and (not mini or len(mini) <= FDP_MINI_BYTES.get(minirate, -1))):
            raise ValueError("bad FDP packet")
        seq = self._next_seq()
        busy = self._busy()
        rates = (minirate, rate) if kind == "TFP" else (rate,)
        self._print(kind, int(busy), seq, dest, *rates, ack, 0)
        if not busy:
            self._cycle = asyncio.create_task(self._run_fdp(
                dest, rate, bool(ack), data, seq, (minirate, mini) if mini else None))

    def _cc_mpc(self, f: tuple[str, ...]) -> None:
        src, dest = int(f[0]), int(f[1])
        self._print("MPC", src, dest)
        self._spawn(self._run_ping(dest, AirKind.PING))

    def _cc_cmd(self, f: tuple[str, ...]) -> None:
        """``$CCCMD,PNG,src,dest,rate,cdr[,hex]``: an FDP ping (pyacomms writes five fields for
        firmware before 3.0, six after) → ``$CACMD,PNG,src,dest,rate,cdr,nbytes``, as a real
        MM2 echoes it [V recorded]. Other modes are refused."""
        if f[0] != "PNG" or len(f) not in (5, 6):
            raise ValueError("$CCCMD mode")
        src, dest, rate, cdr = (int(x) for x in f[1:5])
        data = bytes.fromhex(f[5]) if len(f) == 6 else b""
        if not (src == self.address and 0 <= dest <= MAX_ADDRESS and rate in FDP_RATES
                and cdr >= 0 and len(data) <= PING_DATA_BYTES):
            raise ValueError("bad FDP ping")
        self._print("CMD", "PNG", src, dest, rate, cdr, len(data))
        self._spawn(self._run_ping(dest, AirKind.FDP_PING, rate))

    def _cc_pdt(self, f: tuple[str, ...]) -> None:
        """``$CCPDT``: interrogate REMUS digital transponders; echoed as ``$SNPDT``."""
        self._interrogate(nav.interrogation(Sentence("CC", "PDT", f)), ())

    def _cc_pnt(self, f: tuple[str, ...]) -> None:
        """``$CCPNT``: interrogate narrowband transponders; echoed as ``$SNPNT,hhmmss,…``."""
        self._interrogate(nav.interrogation(Sentence("CC", "PNT", f)), (_hhmmss(),))

    def _interrogate(self, ping: nav.Interrogation, before: tuple[str, ...]) -> None:
        if self._nav is not None:
            self._error("NAV", 1, "Busy")  # [U]
            return
        self._print(ping.kind, *before, *ping.fields, talker="SN")
        self._nav = _NavPing(ping, self.modem_time())
        self._spawn(self._run_nav(self._nav))

    def _cc_mec(self, f: tuple[str, ...]) -> None:
        """``$CCMEC,src,dest,line,mode,arg``: a GPIO line of this modem (dest = us; the echo
        carries the level read) or of another, told acoustically (libumutil ``MEC_*``)."""
        if len(f) != 5:
            raise ValueError("$CCMEC takes 5 fields")
        src, dest, line, mode, arg = (int(x) for x in f)
        if not (1 <= line <= 8 and 0 <= mode <= 3 and 0 <= arg <= 7 and 0 <= dest <= MAX_ADDRESS
                and (mode != 1 or arg in (0, 1))):
            raise ValueError("bad hardware control")
        if dest == self.address:
            level = self._gpio(line, mode, arg)
            self._print("MEC", src, dest, line, mode, level if mode == 0 else arg)
            return
        self._print("MEC", src, dest, line, mode, arg)
        self._spawn(self._transmit(Header(AirKind.MEC, self.address, dest),
                                   bytes((line, mode, arg)), report=False))

    def _gpio(self, line: int, mode: int, arg: int) -> int:
        """Read (0), set (1) or toggle high (2) / low (3) for ``MEC_TOGGLE_S[arg]``; the level."""
        if mode == 1:
            self.lines[line] = arg
        elif mode in (2, 3):
            level = 1 if mode == 2 else 0
            self.lines[line] = level
            asyncio.get_running_loop().call_later(MEC_TOGGLE_S[arg], self.lines.__setitem__,
                                                  line, 1 - level)
        return self.lines.get(line, 0)

    def _cc_rsp(self, f: tuple[str, ...]) -> None:
        """``$CCRSP,rxsig,txsig,timeout``: an FM sweep (txsig 1 FSK band, 2 PSK band), echoed
        as ``$CARSP`` (libumutil: the first and last fields obsolete)."""
        if len(f) != 3:
            raise ValueError("$CCRSP takes 3 fields")
        rxsig, txsig, timeout = (int(x) for x in f)
        if txsig not in (1, 2):
            raise ValueError("txsig 1 or 2")
        self._print("RSP", rxsig, txsig, timeout)
        self._spawn(self._transmit(Header(AirKind.SWEEP, self.address, rate=txsig), MINI,
                                   report=False))

    def _cc_muc(self, f: tuple[str, ...]) -> None:
        dest, value = int(f[1]), int(f[2], 16)
        if not 0 <= value <= 0x1FFF:
            raise ValueError("13 bits")
        self._print("MUC", *f[:3])
        self._spawn(self._transmit(Header(AirKind.MINI, self.address, dest),
                                   value.to_bytes(2, "big")))

    def _set_clock(self, when: float) -> None:
        """The clock reads ``when`` at the top of the next second, as goby times ``$CCCLK``
        (sent 50-100 ms into a second, naming the next one) [C: when MM2 applies it]."""
        self.clock_offset_s = when - math.ceil(time.time())

    def _cc_clk(self, f: tuple[str, ...]) -> None:
        """``$CCCLK,YYYY,MM,DD,hh,mm,ss``."""
        year, month, day, hour, minute, second = (int(x) for x in f[:6])
        self._set_clock(datetime.datetime(year, month, day, hour, minute, second,
                                          tzinfo=datetime.UTC).timestamp())
        self._print("CLK", *f[:6])

    def _cc_tms(self, f: tuple[str, ...]) -> None:
        """``$CCTMS,<ISO 8601>Z,mode`` → ``$CATMS,timed_out,time`` [V layout]."""
        when = datetime.datetime.fromisoformat(f[0].replace("Z", "+00:00"))
        int(f[1])
        self._set_clock(when.timestamp())
        self._print("TMS", 0, _iso(when.timestamp()))

    def _cc_tmq(self, f: tuple[str, ...]) -> None:
        """``$CCTMQ,0`` → ``$CATMQ,time,clksrc,pps_src`` half a second later [V layout; the
        source names are U]."""
        if f and f[0] not in ("", "0"):
            raise ValueError("$CCTMQ takes 0")

        async def later() -> None:
            await asyncio.sleep(TMQ_DELAY_S)
            self._print("TMQ", _iso(self.modem_time()), "RTC", "NONE")

        self._spawn(later())

    def _cc_alq(self, f: tuple[str, ...]) -> None:
        self._print("ALQ", "zab-emulator", API_LEVEL)

    def _cc_msc(self, f: tuple[str, ...]) -> None:
        self._print("MSC", *f[:3])
        if int(f[2]) == 0:
            self.reboot()

    def _busy(self) -> bool:
        return self._cycle is not None and not self._cycle.done()

    def _renumber(self, address: int) -> None:
        """``$CCCFG,SRC,n``: the modem answers to ``n`` from now on (it rejoins the water)."""
        self.address = address
        self.setup = dataclasses.replace(self.setup, address=address)
        self._spawn(self._rejoin())

    # -- data cycle ----------------------------------------------------------------------------

    def _next_seq(self) -> int:
        self._seq = (self._seq + 1) & 0xFF
        return self._seq

    def _cancel_cycle(self) -> None:
        if self._cycle is not None:
            self._cycle.cancel()
            self._cycle = None
        if self._txd is not None and not self._txd.done():
            self._txd.cancel()
        self._txd = None

    async def _run_cycle(self, dest: int, rate: int, ack: bool, frames: int) -> None:
        spec = get_rate(rate)
        seq = self._next_seq()
        me = self.address
        if spec.fsk:  # rate 0: the cycle-init mini-packet goes first, then the DRQ
            ci = Header(AirKind.CYCLE_INIT, me, dest, rate, ack, 0, frames, seq)
            if not await self._transmit(ci, MINI):
                return
        else:  # PSK: the cycle-init rides with the packet; the host sees a second CACYC
            self._print("CYC", 0, me, dest, rate, int(ack), frames)
        data: list[bytes] = []
        for frame in range(1, frames + 1):
            self._txd = asyncio.get_running_loop().create_future()
            self._print("DRQ", _hhmmss(), me, dest, int(ack), spec.frame_bytes, frame)
            try:
                async with asyncio.timeout(self.dto_s):
                    txd = await self._txd
            except TimeoutError:
                self._error("DATA_TIMEOUT", frame)
                return
            finally:
                self._txd = None
            chunk = bytes.fromhex(txd.fields[3])[: spec.frame_bytes]
            self._print("TXD", txd.fields[0], txd.fields[1], txd.fields[2], len(chunk))
            if not chunk:
                break  # a blank TXD: nothing (more) to send
            data.append(chunk)
            ack = ack or txd.fields[2] == "1"  # each frame carries its own ack bit [V]
        if not data:
            return
        total = sum(map(len, data))
        self._print("TXP", total)
        body, prefixed = pack_frames(data, spec.frame_bytes)
        header = Header(AirKind.DATA, me, dest, rate, ack, int(prefixed), len(data), seq)
        if not await self._transmit(header, body, report=False):
            return
        self._print("TXF", total)
        self._xst(rate, dest, ack, frames, len(data), total)

    async def _run_fdp(self, dest: int, rate: int, ack: bool, data: bytes, seq: int,
                       mini: tuple[int, bytes] | None) -> None:
        """One FDP packet; ``mini`` is its user mini-frame and the mini-frame's rate, which go
        first in the water (a byte of length - 1 ahead of them)."""
        size = get_rate(rate).frame_bytes
        frames = [data[i : i + size] for i in range(0, len(data), size)]
        n = len(data) + (len(mini[1]) if mini else 0)
        self._print("TXP", n)
        body, prefixed = pack_frames(frames, size) if frames else (b"", False)
        if mini:
            body = bytes((len(mini[1]) - 1,)) + mini[1] + body
        header = Header(AirKind.FDP, self.address, dest, rate, ack, int(prefixed), len(frames),
                        seq, mini[0] if mini else 0)
        if not await self._transmit(header, body, report=False):
            return
        self._print("TXF", n)
        self._xst(rate, dest, ack, len(frames), len(frames), n)

    def _xst(self, rate: int, dest: int, ack: bool, expected: int, sent: int, n: int) -> None:
        """``$CAXST`` in the v6+ layout of reference 2.5 (values partly invented)."""
        if not self._on("XST"):
            return
        now = self.modem_time()
        self._print("XST", 6, time.strftime("%Y%m%d", time.gmtime(now)),
                    time.strftime("%H%M%S", time.gmtime(now)) + f".{int(now % 1 * 1e6):06d}",
                    3, 0, 200, 5000, 25000, rate, self.address, dest, int(ack), expected, sent,
                    1 if rate == 0 else 3, n)

    async def _transmit(self, header: Header, body: bytes, *, report: bool = True) -> bool:
        """Put one packet in the water; ``report`` prints ``$CATXF,2`` for a mini-packet."""
        sim = self._sim
        try:
            if sim is None or not sim.is_open:
                raise BackendError("not in the water")
            await sim.send(body, pack_header(header))
        except BackendError as exc:
            self.stats["tx_errors"] += 1
            log.warning("micromodem emulator %s: transmission failed: %s", self.address, exc)
            self._error("XMIT", 1, "Transmit failed")  # [U]
            return False
        self.stats["tx"] += 1
        if report:
            self._print("TXF", len(body))
            if header.kind is AirKind.CYCLE_INIT:
                self._xst(header.rate, header.dest, header.ack, header.frames, 0, 0)
        return True

    # -- pings -----------------------------------------------------------------------------------

    async def _run_ping(self, dest: int, kind: AirKind, rate: int = 0) -> None:
        """A two-way ping (``PING``: ``$CCMPC``; ``FDP_PING``: ``$CCCMD,PNG``) and its report."""
        fut: asyncio.Future[float] = asyncio.get_running_loop().create_future()
        self._ping = (dest, fut)
        try:
            if not await self._transmit(Header(kind, self.address, dest, rate), MINI):
                return
            async with asyncio.timeout(self.ping_timeout_s):
                owtt = await fut
            if kind is AirKind.PING:
                self._print("MPR", dest, self.address, f"{owtt:.4f}")
            else:  # the real line's layout; its last field (timing) left empty as it was
                self._print("CMR", "PNR", _iso(self.modem_time()), dest, self.address,
                            f"{owtt:.6f}", "20.0", "15.0", TX_LEVEL, 0, "")
                self._cst(Header(kind, dest, self.address, rate), time.time(), packet_type=4)
        except TimeoutError:
            pass  # [U] the modem prints nothing when no reply comes
        finally:
            if self._ping is not None and self._ping[1] is fut:
                self._ping = None

    async def _answer(self, to: Header, outbound_s: float, later_s: float = 0.0) -> None:
        """Answer a ping or an LBL interrogation after the turn-around (and ``later_s``); the
        reply carries the outbound travel time (0.1 ms units), so the pinger measures in the
        water's time."""
        await asyncio.sleep(TURNAROUND_S + later_s)
        body = min(int(outbound_s * 1e4), 0xFFFF).to_bytes(2, "big")
        await self._transmit(to, body, report=to.kind is not AirKind.NAV_REPLY)

    async def _run_nav(self, ping: _NavPing) -> None:
        """An LBL interrogation: transmit (unless timed by an external pulse), gather the
        transponders' replies within the window, print ``$SNTTA``."""
        try:
            if ping.asked.transmit:
                await self._transmit(Header(AirKind.NAV, self.address), MINI, report=False)
            if any(ping.asked.listen):
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(ping.asked.window_s + self.nav_late_s):
                        await ping.all_heard.wait()
            self._write(nav.tta(ping.heard, ping.started))
        finally:
            self._nav = None

    def _nav_reply(self, h: Header, rx: Reception) -> None:
        """A transponder answered: heard if we listen for it and its reply came within the
        window (the round trip and our ``TAT``)."""
        ping, beacon = self._nav, h.frame
        if ping is None or not 0 <= beacon < 4 or not ping.asked.listen[beacon]:
            return
        owtt = _one_way(rx)
        tat_s = float(self.nvram.get("TAT", "50")) / 1000
        if 2 * owtt + tat_s <= ping.asked.window_s:
            ping.heard[nav.BEACONS[beacon]] = owtt
        if all(b in ping.heard for b, on in zip(nav.BEACONS, ping.asked.listen, strict=True)
               if on):
            ping.all_heard.set()

    # -- water side ----------------------------------------------------------------------------

    async def _water_loop(self) -> None:
        while True:
            sim = self._sim
            try:
                if sim is None or not sim.is_open:
                    raise BackendError("not in the water")
                rx = await sim.recv()
            except BackendError as exc:
                if self._sim is not None and self._sim is not sim:
                    continue  # renumbered ($CCCFG,SRC): the new modem is in the water
                log.warning("micromodem emulator %s: %s; rejoining", self.address, exc)
                await asyncio.sleep(WATER_RETRY_S)
                await self._rejoin()
                continue
            self._on_air(rx)

    async def _rejoin(self) -> None:
        """Join the water (again) under the current address; the old modem leaves."""
        old = self._sim
        if old is not None and old.address == self.address:
            self._sim = None
            await old.close()
        sim = self._join()
        try:
            await sim.open()
        except BackendError as exc:
            log.warning("micromodem emulator %s: %s", self.address, exc)
            return
        self._sim = sim
        if old is not None and old.is_open:
            await old.close()

    def _on_air(self, rx: Reception) -> None:
        h = unpack_header(rx.meta.get("dest"))
        if h is None:
            return
        self.stats["rx"] += 1
        me, src = self.address, rx.src
        if h.kind is AirKind.CYCLE_INIT:
            self._heard_cycle_init(h, rx)
        elif h.kind in (AirKind.DATA, AirKind.FDP):
            self._heard_packet(h, rx)
        elif h.kind is AirKind.NAV and self.transponder is not None:
            # real transponders answer at once, each on its own frequency; the water has one
            # channel, so they take turns in it (the travel times it reports are unchanged)
            beacon = nav.BEACONS.index(self.transponder)
            self._spawn(self._answer(Header(AirKind.NAV_REPLY, me, src, frame=beacon),
                                     float(rx.meta.get("travel_time_s", 0.0)),
                                     beacon * self.nav_slot_s))
        elif h.kind is AirKind.FDP_PING:  # heard by every modem, answered by its destination
            self._print("CMA", _iso(self.modem_time()), "PNG", src, h.dest, "20.0", "15.0",
                        TX_LEVEL, 0, 0)
            self._cst(h, rx.time, packet_type=4)
        if h.dest != me:
            return
        if h.kind is AirKind.ACK:
            mask = int.from_bytes(rx.data[:2], "big")
            for frame in range(1, h.frames + 1):
                if mask >> (frame - 1) & 1:
                    self._print("ACK", src, me, frame, 1)
        elif h.kind is AirKind.FDP_ACK:  # [C] the layout pyacomms reads; masks in hex
            self._print("CDR", _iso(self.modem_time()), h.seq, src, me, h.mini or -1,
                        f"{rx.data[0]:02X}", f"{int.from_bytes(rx.data[1:3], 'big'):04X}")
        elif h.kind in (AirKind.PING, AirKind.FDP_PING):
            if h.kind is AirKind.PING:
                self._print("MPA", src, me)
            reply = AirKind.PING_REPLY if h.kind is AirKind.PING else AirKind.FDP_PING_REPLY
            self._spawn(self._answer(Header(reply, me, src, h.rate),
                                     float(rx.meta.get("travel_time_s", 0.0))))
        elif h.kind in (AirKind.PING_REPLY, AirKind.FDP_PING_REPLY):
            ping = self._ping
            if ping is not None and ping[0] == src and not ping[1].done():
                ping[1].set_result(_one_way(rx))
        elif h.kind is AirKind.NAV_REPLY:
            self._nav_reply(h, rx)
        elif h.kind is AirKind.MINI:
            self._print("MUA", src, me, f"{int.from_bytes(rx.data[:2], 'big'):04X}")
        elif h.kind is AirKind.MEC and len(rx.data) == 3:
            line, mode, arg = rx.data
            self._print("MEA", src, me, line, mode, arg)
            level = self._gpio(line, mode, arg)
            self._spawn(self._transmit(Header(AirKind.MEC_REPLY, me, src),
                                       bytes((line, mode, level)), report=False))
        elif h.kind is AirKind.MEC_REPLY and len(rx.data) == 3:
            self._print("MER", src, me, *rx.data)  # goby: the replier first (MM2 >= 2.0.18307)

    def _heard_cycle_init(self, h: Header, rx: Reception) -> None:
        me, src = self.address, rx.src
        self._heard[src] = h
        self._rxp(0)
        self._print("CYC", 0, h.src, h.dest, h.rate, int(h.ack), h.frames)
        self._cst(h, rx.time, packet_type=2)
        polled = h.src == me and h.src != src  # we are asked to send to h.dest
        if polled and not self._busy():
            self._cycle = asyncio.create_task(self._run_cycle(h.dest, h.rate, h.ack, h.frames))
        elif h.src == src and h.rate == 0:  # its FSK data should follow within PTO
            self._await_data(src)

    def _heard_packet(self, h: Header, rx: Reception) -> None:
        """A data packet (legacy or FDP): its frames to the host, an acknowledgement if asked."""
        me, src, body, mini = self.address, rx.src, rx.data, b""
        if h.mini:  # an FDP packet's user mini-frame goes first
            mini, body = body[1 : body[0] + 2], body[body[0] + 2 :]
        try:
            frames = unpack_frames(body, h.frames, get_rate(h.rate).frame_bytes, bool(h.frame))
        except ValueError:
            return
        if h.kind is AirKind.DATA and h.rate == 0:
            ci = self._heard.get(src)
            if ci is None or ci.seq != h.seq:  # the FSK data needs its cycle-init
                self.stats["rx_no_cycle_init"] += 1
                return
            self._data_came(src)
        self._rxp(0 if h.rate == 0 else 1)
        if h.kind is AirKind.FDP:
            self._print("RFP", _iso(self.modem_time()), h.seq, h.src, h.dest, h.mini or -1,
                        h.rate if frames else -1, int(h.ack), 0, "", _fdp_frames([mini]),
                        _fdp_frames(frames))
        else:
            if h.rate != 0:
                self._print("CYC", 0, h.src, h.dest, h.rate, int(h.ack), len(frames))
            for frame, chunk in enumerate(frames, 1):
                self._print("RXD", h.src, h.dest, int(h.ack), frame, chunk.hex().upper())
        self._cst(h, rx.time, packet_type=1 if h.rate == 0 else 3)
        if not (h.ack and h.dest == me):
            return
        mask = (1 << len(frames)) - 1  # [C] every good frame acknowledged in one mini-packet
        if h.kind is AirKind.DATA:
            ack = Header(AirKind.ACK, me, src, h.rate, True, 0, len(frames), h.seq)
            self._spawn(self._transmit(ack, mask.to_bytes(2, "big")))
        else:
            ack = Header(AirKind.FDP_ACK, me, src, h.rate, True, 0, len(frames), h.seq, h.mini)
            self._spawn(self._transmit(ack, bytes((1 if mini else 0,)) + mask.to_bytes(2, "big")))

    def _on_loss(self, src: int, reason: str, dest: Any) -> None:
        """The water lost a packet whose signal reached us: each of its frames fails its CRC
        (the packet header is taken as decoded, so the host knows whose packet it was)."""
        h = unpack_header(dest)
        if h is None or h.kind not in (AirKind.DATA, AirKind.FDP):
            return
        if h.kind is AirKind.DATA and h.rate == 0:
            ci = self._heard.get(src)
            if ci is None or ci.seq != h.seq:
                return  # no cycle-init was heard: the modem was not listening for it
            self._data_came(src)
        log.info("micromodem emulator %s: packet from %s lost (%s)", self.address, src, reason)
        self._rxp(0 if h.rate == 0 else 1)
        if h.rate != 0:
            self._print("CYC", 0, h.src, h.dest, h.rate, int(h.ack), h.frames)
        for frame in range(1, h.frames + 1):
            self.stats["bad_crc"] += 1
            self._print("MSG", "BAD_CRC", frame)
        self._cst(h, time.time(), packet_type=1 if h.rate == 0 else 3, mode=1)

    def _await_data(self, src: int) -> None:
        """A rate-0 cycle-init from ``src``: ``$CAMSG,PACKET_TIMEOUT`` unless its data (or
        its loss) comes within ``PTO``."""
        self._data_came(src)
        loop = asyncio.get_running_loop()
        self._waiting[src] = loop.call_later(self.pto_s, self._packet_timeout, src)

    def _data_came(self, src: int) -> None:
        timer = self._waiting.pop(src, None)
        if timer is not None:
            timer.cancel()

    def _packet_timeout(self, src: int) -> None:
        self._waiting.pop(src, None)
        ci = self._heard.get(src)
        self.stats["packet_timeout"] += 1
        self._print("MSG", "PACKET_TIMEOUT", 1)
        if ci is not None:
            self._cst(ci, time.time(), packet_type=1, mode=2)

    def _rxp(self, packet_type: int) -> None:
        if self._on("RXP"):
            self._print("RXP", packet_type)

    def _cst(self, h: Header, at: float, *, packet_type: int, mode: int = 0) -> None:
        """``$CACST`` v6+ layout (reference 2.5), mode 0 good, 1 bad CRC, 2 packet timeout,
        packet type 1 FSK, 2 FSK mini, 3 PSK, 4 PSK mini (libumutil); TOA on the modem clock;
        figures besides rate/src/dest are invented."""
        if not self._on("CST"):
            return
        t = at + self.clock_offset_s
        toa = time.strftime("%Y%m%d%H%M%S", time.gmtime(t)) + f".{int(t % 1 * 1e6):06d}"
        self._print("CST", 6, mode, toa, 0, 200, 50, 100, 130, 0, 0, 0, 0, 0, h.rate, h.src,
                    h.dest, 0, packet_type, h.frames,
                    h.frames if mode == 1 else 0, 150, "20.0", "15.0", "12.0", "-10.0", 0,
                    "0.00", 50, 25000, 5000)

    def _spawn(self, coro: Any) -> None:
        task = asyncio.create_task(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)


@dataclasses.dataclass
class _NavPing:
    """An LBL interrogation under way: what was asked, when (modem clock), who answered."""

    asked: nav.Interrogation
    started: float
    heard: dict[str, float] = dataclasses.field(default_factory=dict)
    all_heard: asyncio.Event = dataclasses.field(default_factory=asyncio.Event)


def _one_way(rx: Reception) -> float:
    """The one-way travel time of a reply: its outbound time (0.1 ms units) and its own, halved."""
    outbound = int.from_bytes(rx.data[:2], "big") / 1e4
    return (outbound + float(rx.meta.get("travel_time_s", outbound))) / 2


def _fdp_frames(frames: list[bytes]) -> str:
    """FDP frames as the modem prints them: ``crc_ok;nbytes;HEX`` each, joined by ``;``."""
    return ";".join(f"1;{len(f)};{f.hex().upper()}" for f in frames if f)


def _text(value: object) -> str:
    if isinstance(value, bool):
        return "1" if value else "0"
    return str(value)


async def run_emulator(
    loaded: LoadedMission,
    node: str,
    *,
    water: str,
    link: Path | None = None,
    ready: Callable[[dict[str, Any]], None] | None = None,
    **options: Any,
) -> None:
    """Emulate ``node``'s Micro-Modem in the water at ``water`` (host:port) until cancelled.

    ``ready`` receives ``{"device": path}`` once the pty is open. ``options`` go to
    :class:`MicromodemEmulator` (``dto_s``, ``rev_period_s``, ``crc32`` ...).
    """
    setup = modem_setup(loaded.mission, node, extra={"water": water})
    emulator = MicromodemEmulator(setup, link=link, **options)
    try:
        device = await emulator.open()
        log.info("micromodem emulator for %s (address %s) on %s", node, setup.address, device)
        if ready is not None:
            ready({"device": device, "node": node, "address": setup.address})
        await asyncio.Future()
    finally:
        await emulator.close()
