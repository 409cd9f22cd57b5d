"""An emulated WHOI Micro-Modem 2: NMEA on a pseudo-terminal, packets in the simulated water.

The emulator answers the host like the modem in the reference (section 2, checklist 2.7) and
like the MM2 its ``$CAREV`` announces: it echoes ``$CCCYC``/``$CCMPC``/``$CCMUC``/``$CCCFG``/
``$CCCLK``/``$CCMSC``, answers ``$CCCFQ`` (one ``$CACFG`` per key; ``ALL``/``TOP`` all of them),
runs the legacy data cycle (rate 0: the cycle-init mini-packet goes out first, then ``$CATXF,2``
and ``$CAXST``, then the ``$CADRQ``; rates 1–6: a second ``$CACYC``), MM2's FDP (``$CCTDP`` →
``$CATDP`` → ``$CATXP``/``$CATXF``; received as ``$CARFP``), the clock (``$CCCLK``, ``$CCTMS``
→ ``$CATMS``, ``$CCTMQ`` → ``$CATMQ`` half a second later), ``$CCALQ`` → ``$CAALQ``, prints
``$CAERR`` for unknown commands, bad checksums and data timeouts, ``$CAREV,…,INIT`` when it
(re)boots and ``$CAREV,…,AUV`` periodically while ``REV`` is 1, all interleaved with
asynchronous receptions.

It honours the configuration it holds: ``SRC`` renumbers it (it rejoins the water under the new
address), ``REV`` 0 stops the periodic ``$CAREV``, ``RXP``/``CST``/``XST`` 0 silence
``$CARXP``/``$CACST``/``$CAXST``, ``DTO`` is the data-request timeout, ``PTO`` the packet
timeout. With ``crc32`` every line it prints carries the MM2's 8-digit CRC-32; what the host
sends may carry either checksum, and a wrong or lower-case one is refused.

Every acoustic packet is one transmission of a :class:`~bridge.modems.sim.SimBackend` in the
water, which adds airtime, propagation, collisions and loss: a data packet goes as one
transmission of all its frames (joined; a byte per frame giving its length first when a frame
other than the last is short), as the modem sends one PSK packet behind one probe; the
``micromodem-rate<N>`` presets carry a whole packet of their rate. What the real modem's
waveform conveys implicitly (packet type, cycle-init fields) travels in the water's ``dest``
metadata, packed by :func:`pack_header`.
Mini-packets (cycle-init, ack, ping, ``$CCMUC``) are 2-byte transmissions. A packet whose
signal reached the modem but that the water lost (a collision, bit errors, loss at range)
prints ``$CAMSG,BAD_CRC,<frame>`` for each of its frames; a rate-0 cycle-init whose data never
comes prints ``$CAMSG,PACKET_TIMEOUT,1`` after ``PTO`` seconds, each with its ``$CACST``.

Not modelled: NVRAM semantics of other keys (stored and echoed only), navigation pings
(``$CCPDT``/``$CCPNT``), the newer ping API (``$CCCMD``), GPIO (``$CCMEC``), ``$CCRSP``,
FDP mini-frames (``$CCTFP``) and acknowledgements of FDP packets, sleep (``$CCMSC`` with
minutes > 0 is echoed only), USBL (``$CAUSB2``).
"""

from __future__ import annotations

import asyncio
import dataclasses
import datetime
import enum
import logging
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bridge.core.loaded import LoadedMission
from bridge.errors import BackendError
from bridge.modems.base import ModemSetup, Reception
from bridge.modems.micromodem.nmea import LineBuffer, NmeaError, Sentence, parse_sentence
from bridge.modems.micromodem.rates import FDP_RATES, get_rate
from bridge.modems.pty_host import PtyHost
from bridge.modems.setup import modem_setup
from bridge.modems.sim import SimBackend

__all__ = ["AirKind", "MicromodemEmulator", "pack_header", "run_emulator", "unpack_header"]

log = logging.getLogger("zab.emulate.micromodem")

REVISION = "2.0.27087"
"""Firmware revision printed in ``$CAREV`` (the MM2 revision seen in the reference)."""

TURNAROUND_S = 0.05
"""Ping turn-around at the pinged modem (REMUS LBL TAT, reference 2.6 [V])."""

MINI = b"\x00\x00"
"""Body of a mini-packet in the water (the real one carries 13 bits)."""

WATER_RETRY_S = 1.0

TMQ_DELAY_S = 0.5
"""``$CATMQ`` comes about half a second after ``$CCTMQ`` (goby waits 500 ms more) [V]."""

API_LEVEL = 11
"""What ``$CAALQ`` reports (pyacomms' default level) [U: a real MM2's name and level]."""

MAX_ADDRESS = 127
"""Highest address the emulator takes (the driver's range; its water header has 7 bits)."""


class AirKind(enum.IntEnum):
    """What an acoustic packet is (the real modem tells them apart by waveform)."""

    CYCLE_INIT = 1
    DATA = 2
    ACK = 3
    PING = 4
    PING_REPLY = 5
    MINI = 6
    FDP = 7


@dataclasses.dataclass(frozen=True)
class Header:
    """The out-of-band header of one acoustic packet."""

    kind: AirKind
    src: int = 0  # the cycle's source (differs from the transmitter for a poll)
    dest: int = 0
    rate: int = 0
    ack: bool = False
    frame: int = 0
    frames: int = 0
    seq: int = 0


def pack_header(h: Header) -> int:
    """The header as one integer for the water's ``dest`` field."""
    return (int(h.kind) | h.src << 4 | h.dest << 11 | h.rate << 18 | int(h.ack) << 21
            | h.frame << 22 | h.frames << 26 | h.seq << 30)


def unpack_header(value: Any) -> Header | None:
    """The header from a reception's ``dest`` metadata; ``None`` if it is not one of ours."""
    if not isinstance(value, int) or value < 0:
        return None
    try:
        kind = AirKind(value & 0xF)
    except ValueError:
        return None
    return Header(kind, value >> 4 & 0x7F, value >> 11 & 0x7F, value >> 18 & 0x7, bool(
        value >> 21 & 1), value >> 22 & 0xF, value >> 26 & 0xF, value >> 30 & 0xFF)


def _hhmmss() -> str:
    return time.strftime("%H%M%S", time.gmtime())


def pack_frames(frames: list[bytes], frame_bytes: int) -> tuple[bytes, bool]:
    """A packet's frames as one water transmission, and whether it is length-prefixed: the
    frames joined when all but the last are full (``frame_bytes``), as the host fills them;
    else one byte per frame (its length - 1) first."""
    if all(len(f) == frame_bytes for f in frames[:-1]):
        return b"".join(frames), False
    return bytes(len(f) - 1 for f in frames) + b"".join(frames), True


def unpack_frames(body: bytes, count: int, frame_bytes: int, prefixed: bool) -> list[bytes]:
    """The frames of :func:`pack_frames`; ``ValueError`` if ``body`` does not hold them."""
    if not prefixed:
        frames = [body[i : i + frame_bytes] for i in range(0, len(body), frame_bytes)]
        if len(frames) != count:
            raise ValueError("not a packet of frames")
        return frames
    frames, pos = [], count
    for size in body[:count]:
        frames.append(body[pos : pos + size + 1])
        pos += size + 1
    if count < 1 or len(body) < count or pos != len(body):
        raise ValueError("not a packet of frames")
    return frames


def _iso(t: float) -> str:
    """``t`` (seconds) as MM2 prints times: ISO 8601 UTC with microseconds."""
    return datetime.datetime.fromtimestamp(t, datetime.UTC).strftime("%Y-%m-%dT%H:%M:%S.%f")


class MicromodemEmulator:
    """One emulated Micro-Modem: a :class:`PtyHost` on the host side, a sim modem in the water.

    ``setup`` is the node's :class:`ModemSetup` with a ``water`` option. ``dto_s`` is the
    data-request timeout, ``rev_period_s`` the period of ``$CAREV,…,AUV`` (``None``: never),
    ``boot_s`` how long a reboot takes, ``ping_timeout_s`` how long a ping waits for its reply.
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
    ) -> None:
        # the water sets the size limit; its dest carries packed headers, never a broadcast
        self.setup = dataclasses.replace(setup, frame_bytes=4096, options={
            k: v for k, v in setup.options.items() if k != "broadcast"})
        self.address = setup.address
        self.rev_period_s = rev_period_s
        self.boot_s = boot_s
        self.ping_timeout_s = ping_timeout_s
        self.crc32 = crc32
        self.defaults: dict[str, str] = {"CST": "1", "XST": "1", "REV": "1", "RXP": "1",
                                         "DTO": f"{dto_s:g}", "PTO": f"{pto_s:g}"}
        self.nvram: dict[str, str] = {"SRC": str(setup.address), **self.defaults}
        self.stats: dict[str, int] = {"lines": 0, "bad_checksum": 0, "unknown": 0, "tx": 0,
                                      "rx": 0, "tx_errors": 0, "reboots": 0, "rx_no_cycle_init": 0,
                                      "bad_crc": 0, "packet_timeout": 0}
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
        self._heard: dict[int, Header] = {}  # last cycle-init heard from each transmitter
        self._waiting: dict[int, asyncio.TimerHandle] = {}  # rate-0 data awaited, by sender
        self._seq = 0
        self._booted = time.monotonic()

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

    def reboot(self) -> None:
        """Reboot now (power glitch or ``$CCMSC,…,0``): abandon the cycle, print ``INIT``."""
        self.stats["reboots"] += 1
        self._cancel_cycle()
        self._lines.clear()
        self._heard.clear()
        for timer in self._waiting.values():
            timer.cancel()
        self._waiting.clear()
        self._spawn(self._boot())

    # -- host side -----------------------------------------------------------------------------

    def _print(self, kind: str, *fields: object) -> None:
        sentence = Sentence("CA", kind, tuple(_text(f) for f in fields))
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
            start = line.find(b"$")
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
        keys = sorted(self.nvram) if f[0] in ("ALL", "TOP") else [f[0]]
        for key in keys:
            self._print("CFG", key, self.nvram.get(key, ""))

    def _cc_cyc(self, f: tuple[str, ...]) -> None:
        src, dest, rate, ack, frames = (int(x) for x in f[1:6])
        spec = get_rate(rate)
        if not (0 <= dest <= MAX_ADDRESS and 1 <= frames <= spec.frames and ack in (0, 1)):
            raise ValueError("bad cycle-init")
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
        dest, rate, ack, _reserved = (int(x) for x in f[:4])
        data = bytes.fromhex(f[4])
        if not (0 <= dest <= MAX_ADDRESS and rate in FDP_RATES and ack in (0, 1) and data
                and len(data) <= get_rate(rate).max_bytes):
            raise ValueError("bad FDP packet")
        seq = self._next_seq()
        busy = self._busy()
        self._print("TDP", int(busy), seq, dest, rate, ack, 0)  # [U] echo of errflag and id
        if not busy:
            self._cycle = asyncio.create_task(self._run_fdp(dest, rate, bool(ack), data, seq))

    def _cc_mpc(self, f: tuple[str, ...]) -> None:
        src, dest = int(f[0]), int(f[1])
        self._print("MPC", src, dest)
        self._spawn(self._run_ping(dest))

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
                txd = await asyncio.wait_for(self._txd, self.dto_s)
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

    async def _run_fdp(self, dest: int, rate: int, ack: bool, data: bytes, seq: int) -> None:
        size = get_rate(rate).frame_bytes
        frames = [data[i : i + size] for i in range(0, len(data), size)]
        self._print("TXP", len(data))
        body, prefixed = pack_frames(frames, size)
        header = Header(AirKind.FDP, self.address, dest, rate, ack, int(prefixed), len(frames),
                        seq)
        if not await self._transmit(header, body, report=False):
            return
        self._print("TXF", len(data))
        self._xst(rate, dest, ack, len(frames), len(frames), len(data))

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

    # -- ping ----------------------------------------------------------------------------------

    async def _run_ping(self, dest: int) -> None:
        fut: asyncio.Future[float] = asyncio.get_running_loop().create_future()
        self._ping = (dest, fut)
        try:
            if not await self._transmit(Header(AirKind.PING, self.address, dest), MINI):
                return
            owtt = await asyncio.wait_for(fut, self.ping_timeout_s)
            self._print("MPR", dest, self.address, f"{owtt:.4f}")
        except TimeoutError:
            pass  # [U] the modem prints nothing when no reply comes
        finally:
            if self._ping is not None and self._ping[1] is fut:
                self._ping = None

    async def _reply_ping(self, src: int, outbound_s: float) -> None:
        await asyncio.sleep(TURNAROUND_S)
        body = min(int(outbound_s * 1e4), 0xFFFF).to_bytes(2, "big")  # 0.1 ms units
        await self._transmit(Header(AirKind.PING_REPLY, self.address, src), body)

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
            self._heard[src] = h
            self._rxp(0)
            self._print("CYC", 0, h.src, h.dest, h.rate, int(h.ack), h.frames)
            self._cst(h, rx.time, mini=True)
            polled = h.src == me and h.src != src  # we are asked to send to h.dest
            if polled and not self._busy():
                self._cycle = asyncio.create_task(
                    self._run_cycle(h.dest, h.rate, h.ack, h.frames))
            elif h.src == src and h.rate == 0:  # its FSK data should follow within PTO
                self._await_data(src)
        elif h.kind in (AirKind.DATA, AirKind.FDP):
            try:
                frames = unpack_frames(rx.data, h.frames, get_rate(h.rate).frame_bytes,
                                       bool(h.frame))
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
                self._print("RFP", _iso(self.modem_time()), h.seq, h.src, h.dest, -1, h.rate,
                            int(h.ack), 0, "", "", ";".join(
                                f"1;{len(f)};{f.hex().upper()}" for f in frames))
            else:
                if h.rate != 0:
                    self._print("CYC", 0, h.src, h.dest, h.rate, int(h.ack), len(frames))
                for frame, chunk in enumerate(frames, 1):
                    self._print("RXD", h.src, h.dest, int(h.ack), frame, chunk.hex().upper())
            self._cst(h, rx.time, mini=False)
            if h.kind is AirKind.DATA and h.ack and h.dest == me:
                mask = (1 << len(frames)) - 1  # [C] one ack mini-packet for every good frame
                self._spawn(self._transmit(
                    Header(AirKind.ACK, me, src, h.rate, True, 0, len(frames), h.seq),
                    mask.to_bytes(2, "big")))
        elif h.kind is AirKind.ACK and h.dest == me:
            mask = int.from_bytes(rx.data[:2], "big")
            for frame in range(1, h.frames + 1):
                if mask >> (frame - 1) & 1:
                    self._print("ACK", src, me, frame, 1)
        elif h.kind is AirKind.PING and h.dest == me:
            self._print("MPA", src, me)
            self._spawn(self._reply_ping(src, float(rx.meta.get("travel_time_s", 0.0))))
        elif h.kind is AirKind.PING_REPLY and h.dest == me:
            ping = self._ping
            if ping is not None and ping[0] == src and not ping[1].done():
                outbound = int.from_bytes(rx.data[:2], "big") / 1e4
                back = float(rx.meta.get("travel_time_s", outbound))
                ping[1].set_result((outbound + back) / 2)
        elif h.kind is AirKind.MINI and h.dest == me:
            self._print("MUA", src, me, f"{int.from_bytes(rx.data[:2], 'big'):04X}")

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
        self._cst(h, time.time(), mini=False, mode=1)

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
            self._cst(ci, time.time(), mini=False, mode=2)

    def _rxp(self, packet_type: int) -> None:
        if self._on("RXP"):
            self._print("RXP", packet_type)

    def _cst(self, h: Header, at: float, *, mini: bool, mode: int = 0) -> None:
        """``$CACST`` v6+ layout (reference 2.5), mode 0 good, 1 bad CRC, 2 packet timeout;
        TOA on the modem clock; figures besides rate/src/dest are invented."""
        if not self._on("CST"):
            return
        t = at + self.clock_offset_s
        toa = time.strftime("%Y%m%d%H%M%S", time.gmtime(t)) + f".{int(t % 1 * 1e6):06d}"
        self._print("CST", 6, mode, toa, 0, 200, 50, 100, 130, 0, 0, 0, 0, 0, h.rate, h.src,
                    h.dest, 0, 2 if mini else (1 if h.rate == 0 else 3), h.frames,
                    h.frames if mode == 1 else 0, 150, "20.0", "15.0", "12.0", "-10.0", 0,
                    "0.00", 50, 25000, 5000)

    def _spawn(self, coro: Any) -> None:
        task = asyncio.create_task(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)


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
