"""An emulated WHOI Micro-Modem: NMEA on a pseudo-terminal, packets in the simulated water.

The emulator answers the host like the modem in the reference (section 2, checklist 2.7): it
echoes ``$CCCYC``/``$CCMPC``/``$CCMUC``/``$CCCFG``/``$CCCLK``/``$CCMSC``, answers ``$CCCFQ``,
runs the data cycle (rate 0: the cycle-init mini-packet goes out first, then ``$CATXF,2`` and
``$CAXST``, then the ``$CADRQ``; rates 1–5: a second ``$CACYC``), prints ``$CAERR`` for unknown
commands, bad checksums and data timeouts, ``$CAREV,…,INIT`` when it (re)boots and
``$CAREV,…,AUV`` periodically, all interleaved with asynchronous receptions.

Every acoustic packet is one transmission of a :class:`~bridge.modems.sim.SimBackend` in the
water, which adds airtime, propagation, collisions and loss. The payload is exactly the frame's
bytes (so airtime matches the ``sim`` backend); what the real modem's waveform conveys
implicitly (packet type, cycle-init fields, frame number) travels in the water's ``dest``
metadata, packed by :func:`pack_header`. A multi-frame PSK packet is one transmission per
frame. Mini-packets (cycle-init, ack, ping, ``$CCMUC``) are 2-byte transmissions, so with the
``micromodem-rate0`` preset each costs its 3 s overhead: pessimistic, not measured.

Not modelled: clock setting, NVRAM semantics beyond storing keys, MM2 FDP (``$CCTDP``),
navigation pings, sleep (``$CCMSC`` with minutes > 0 is echoed only).
"""

from __future__ import annotations

import asyncio
import dataclasses
import enum
import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bridge.core.loaded import LoadedMission
from bridge.errors import BackendError
from bridge.modems.base import ModemSetup, Reception
from bridge.modems.micromodem.nmea import LineBuffer, NmeaError, Sentence, parse_sentence
from bridge.modems.micromodem.rates import get_rate
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


class AirKind(enum.IntEnum):
    """What an acoustic packet is (the real modem tells them apart by waveform)."""

    CYCLE_INIT = 1
    DATA = 2
    ACK = 3
    PING = 4
    PING_REPLY = 5
    MINI = 6


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
    ) -> None:
        self.setup = dataclasses.replace(setup, frame_bytes=4096)  # the water sets the limit
        self.address = setup.address
        self.dto_s = dto_s
        self.rev_period_s = rev_period_s
        self.boot_s = boot_s
        self.ping_timeout_s = ping_timeout_s
        self.nvram: dict[str, str] = {"SRC": str(setup.address), "CST": "1", "XST": "1",
                                      "REV": "1", "RXP": "1", "DTO": f"{dto_s:g}"}
        self.stats: dict[str, int] = {"lines": 0, "bad_checksum": 0, "unknown": 0, "tx": 0,
                                      "rx": 0, "tx_errors": 0, "reboots": 0, "rx_no_cycle_init": 0}
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
        self._seq = 0
        self._booted = time.monotonic()

    # -- lifecycle -----------------------------------------------------------------------------

    async def open(self) -> str:
        """Join the water, open the pty, print the boot banner; returns the device path."""
        self._sim = SimBackend(self.setup)
        await self._sim.open()
        device = await self.pty.open()
        self._water_task = asyncio.create_task(self._water_loop(), name=f"mm-water-{self.address}")
        if self.rev_period_s:
            self._rev_task = asyncio.create_task(self._rev_loop(), name="mm-rev")
        self._banner()
        return device

    async def close(self) -> None:
        """Close the pty and leave the water; cancel every task. Idempotent."""
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
        self._spawn(self._boot())

    # -- host side -----------------------------------------------------------------------------

    def _print(self, kind: str, *fields: object) -> None:
        self.pty.write(Sentence("CA", kind, tuple(_text(f) for f in fields)).encode())

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
        if s.kind == "CFG":
            key, value = f[0], f[1]
            if key == "ALL" and value == "0":
                self.nvram.update(SRC=str(self.address))
            elif key == "SRC" and int(value) != self.address:
                # [U] renumbering means rejoining the water under a new address; not emulated
                self._error("CFG", 1, "SRC is fixed by the emulator")
                return
            else:
                self.nvram[key] = value
                if key == "DTO":
                    self.dto_s = float(value)
            self._print("CFG", key, value)
        elif s.kind == "CFQ":
            keys = sorted(self.nvram) if f[0] in ("ALL", "TOP") else [f[0]]
            for key in keys:
                self._print("CFG", key, self.nvram.get(key, ""))
        elif s.kind == "CYC":
            src, dest, rate, ack, frames = (int(x) for x in f[1:6])
            spec = get_rate(rate)
            if not (0 <= dest <= 127 and 1 <= frames <= spec.frames and ack in (0, 1)):
                raise ValueError("bad cycle-init")
            self._print("CYC", *f[:6])
            if self._cycle is not None and not self._cycle.done():
                self._error("CYC", 1, "Busy")  # [U]
                return
            if src == self.address:
                self._cycle = asyncio.create_task(self._run_cycle(dest, rate, bool(ack), frames))
            else:  # a poll: ask node src to send to dest
                self._spawn(self._transmit(Header(AirKind.CYCLE_INIT, src, dest, rate, bool(ack),
                                                  0, frames, self._next_seq()), MINI))
        elif s.kind == "TXD":
            if self._txd is None or self._txd.done():
                self._error("NMEA", 4, "Unexpected TXD")  # [U]
                return
            bytes.fromhex(f[3])
            self._txd.set_result(s)
        elif s.kind == "MPC":
            src, dest = int(f[0]), int(f[1])
            self._print("MPC", src, dest)
            self._spawn(self._run_ping(dest))
        elif s.kind == "MUC":
            src, dest, value = int(f[0]), int(f[1]), int(f[2], 16)
            if not 0 <= value <= 0x1FFF:
                raise ValueError("13 bits")
            self._print("MUC", *f[:3])
            self._spawn(self._transmit(Header(AirKind.MINI, self.address, dest),
                                       value.to_bytes(2, "big")))
        elif s.kind == "CLK":
            self._print("CLK", *f)
        elif s.kind == "MSC":
            self._print("MSC", *f[:3])
            if int(f[2]) == 0:
                self.reboot()
        else:
            self.stats["unknown"] += 1
            self._error("NMEA", 1, "Unknown command")

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
        if not data:
            return
        total = sum(map(len, data))
        self._print("TXP", total)
        for frame, chunk in enumerate(data, 1):
            header = Header(AirKind.DATA, me, dest, rate, ack, frame, len(data), seq)
            if not await self._transmit(header, chunk, report=False):
                return
        self._print("TXF", total)
        self._xst(rate, dest, ack, frames, len(data), total)

    def _xst(self, rate: int, dest: int, ack: bool, expected: int, sent: int, n: int) -> None:
        """``$CAXST`` in the v6+ layout of reference 2.5 (values partly invented)."""
        if self.nvram.get("XST") != "1":
            return
        now = time.time()
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
                log.warning("micromodem emulator %s: %s; rejoining", self.address, exc)
                await asyncio.sleep(WATER_RETRY_S)
                await self._rejoin()
                continue
            self._on_air(rx)

    async def _rejoin(self) -> None:
        old, self._sim = self._sim, None
        if old is not None:
            await old.close()
        sim = SimBackend(self.setup)
        try:
            await sim.open()
        except BackendError as exc:
            log.warning("micromodem emulator %s: %s", self.address, exc)
            return
        self._sim = sim

    def _on_air(self, rx: Reception) -> None:
        h = unpack_header(rx.meta.get("dest"))
        if h is None:
            return
        self.stats["rx"] += 1
        me, src = self.address, rx.src
        cst = self.nvram.get("CST") == "1"
        if h.kind is AirKind.CYCLE_INIT:
            self._heard[src] = h
            self._print("RXP", 0)
            self._print("CYC", 0, h.src, h.dest, h.rate, int(h.ack), h.frames)
            if cst:
                self._cst(h, rx, mini=True)
            polled = h.src == me and h.src != src  # we are asked to send to h.dest
            if polled and (self._cycle is None or self._cycle.done()):
                self._cycle = asyncio.create_task(
                    self._run_cycle(h.dest, h.rate, h.ack, h.frames))
        elif h.kind is AirKind.DATA:
            if h.rate == 0:
                ci = self._heard.get(src)
                if ci is None or ci.seq != h.seq:  # the FSK data needs its cycle-init
                    self.stats["rx_no_cycle_init"] += 1
                    return
            if h.frame == 1:
                self._print("RXP", 0 if h.rate == 0 else 1)
                if h.rate != 0:
                    self._print("CYC", 0, h.src, h.dest, h.rate, int(h.ack), h.frames)
            self._print("RXD", h.src, h.dest, int(h.ack), h.frame, rx.data.hex().upper())
            if h.frame == h.frames:
                if cst:
                    self._cst(h, rx, mini=False)
                if h.ack and h.dest == me:
                    mask = (1 << h.frames) - 1  # [C] one ack mini-packet for every good frame
                    self._spawn(self._transmit(
                        Header(AirKind.ACK, me, src, h.rate, True, 0, h.frames, h.seq),
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

    def _cst(self, h: Header, rx: Reception, *, mini: bool) -> None:
        """``$CACST`` v6+ layout (reference 2.5); figures besides rate/src/dest are invented."""
        toa = time.strftime("%Y%m%d%H%M%S", time.gmtime(rx.time)) + f".{int(rx.time % 1 * 1e6):06d}"
        self._print("CST", 6, 0, toa, 0, 200, 50, 100, 130, 0, 0, 0, 0, 0, h.rate, h.src,
                    h.dest, 0, 2 if mini else (1 if h.rate == 0 else 3), h.frames, 0, 150,
                    "20.0", "15.0", "12.0", "-10.0", 0, "0.00", 50, 25000, 5000)

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
    :class:`MicromodemEmulator` (``dto_s``, ``rev_period_s`` ...).
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
