"""``micromodem``: a WHOI Micro-Modem on a serial port, through its NMEA interface.

Options (``modem.options`` of the mission): the table at the end.

- ``device``: serial path (``/dev/ttyUSB0``, a pty) or pyserial URL; ``ack`` asks the
  destination to acknowledge every frame (only for frames with one destination).
- ``fdp``: send by MM2's flexible data protocol (``$CCTDP``, rates 1–6) instead of the
  legacy cycle; packets of either kind are received all the same (``$CARXD``, ``$CARDP``,
  ``$CARFP``, user mini-frames included). An FDP send returns at its ``$CATXF``, or with
  ``ack`` at the destination's ``$CACDR`` acknowledging every data frame.
- ``timeout_s``, ``retries``: goby's 5 s and 3 tries (reference 2.4 E); ``tx_timeout_s``
  (derived from the rate) is one whole data cycle.
- ``broadcast`` (0, Goby's ``BROADCAST_ID``; the mission's ``modem.broadcast`` sets it): the
  address of frames without one destination, and the one that marks a received frame as
  broadcast. Every Micro-Modem passes every packet to its host anyway (seed 003), so it only
  labels frames, but a fleet must agree on it: ``zab check`` says when a node's address is it.
- ``ping``: how :meth:`ping` ranges to another modem, ``mpc`` (``$CCMPC`` → ``$CAMPR``) or
  ``fdp`` (MM2's FDP ping, ``$CCCMD,PNG`` → ``$CACMR,PNR``).
- ``lbl``: LBL transponders among the mission's nodes, which :meth:`ping` ranges to by an
  interrogation (``$CCPDT`` REMUS digital, or ``$CCPNT`` narrowband) → ``$SNTTA``, e.g.
  ``{beacons: {A: 11, B: 12}, max_range_m: 2000}`` or ``{beacons: {A: 11}, kind: narrowband,
  tx_hz: 9000, reply_hz: {A: 10000}}`` (:class:`~bridge.modems.micromodem.nav.Transponders`).
  One interrogation listens for every beacon; the ranges of those not asked for go to
  ``on_range`` too.
- ``set_clock``: at start-up (and after a reboot) set the modem's clock from the host's,
  ``clk`` with ``$CCCLK`` (MM1 and MM2, 50–100 ms after a second's top, naming the next
  second as goby does) or ``tms`` with MM2's ``$CCTMS``, then read it back with ``$CCTMQ``;
  ``stats["clock_offset_ms"]`` is modem minus host as read. ``sound_speed_mps`` turns a
  ``$CAUSB2`` travel time into a range.
- ``config``: extra ``$CCCFG`` keys set at start-up, e.g. ``{CTO: 10}``.

Start-up sets ``SRC`` to the node's address (and ``config``) and waits for every echo. A bridge
frame is split over the rate's frames (:func:`~bridge.modems.micromodem.rates.frame_bytes_for_rate`
bytes at most) and joined again by the receiving backend. ``send`` returns when the packet
left the modem (``$CATXF``), or when every frame was acknowledged with ``ack``; it retries a
failed cycle ``send_retries`` times, then raises :class:`BackendError`: a frame is sent, or the
caller is told. A reboot (``$CAREV,…,INIT``) fails the running cycle and re-initialises the modem.
The frame's MAC turn (``send(until=...)``, a TDMA slot's end) bounds all of it: no cycle begins
from its end on, and a retry only while the packet's nominal airtime still fits before it (one
try's timeout, ``tx_timeout_s``, is longer than a 14 s slot at rate 0); a cycle whose data the
modem has not asked for when the turn ends is called back: each ``$CADRQ`` of it then gets a
blank ``$CCTXD`` (:meth:`~bridge.modems.micromodem.protocol.HostProtocol.cancel`), so a modem
that stalled and wakes later sends nothing. Each such frame is a drop, counted in
``stats["late"]`` (:class:`~bridge.errors.SendTooLate`). Data the modem already holds, and an
FDP packet, cannot be called back [reference 2.3: no such command is verified]: their cycle
runs on, without a retry.
A line with a bad checksum is counted in ``stats["bad_lines"]``, logged (each kind's first at
WARNING, then one a minute: :class:`~bridge.modems.base.BadInputLog`) and dropped. ``$CAMSG``
``BAD_CRC`` and ``PACKET_TIMEOUT`` are counted in ``stats["bad_crc"]`` and
``stats["packet_timeout"]`` (the packet they spoil also in ``rx_lost``). A ``$CAUSB2`` (MM2
USBL) becomes a :class:`~bridge.modems.base.ModemFix` of the node heard last, handed to
``on_fix`` (the runtime publishes it; the line has no covariance, so none is given).

:meth:`~bridge.modems.base.ModemBackend.ping` runs the two-way ping (or the LBL
interrogation of a transponder) and returns the one-way travel time as a
:class:`~bridge.modems.base.ModemRange` (method ``ping``), also handed to ``on_range``.
"""

from __future__ import annotations

import asyncio
import contextlib
import datetime
import logging
import math
import time
from collections.abc import Mapping
from typing import Any, ClassVar

from bridge.core.reception import RangingMode
from bridge.errors import BackendError, SendTooLate
from bridge.mission.backends import MicromodemOptions, ModemOptions
from bridge.mission.presets import UnknownPresetError, get_preset
from bridge.modems.base import (
    BadInputLog,
    Inbox,
    ModemBackend,
    ModemFix,
    ModemRange,
    ModemSetup,
    Reception,
)
from bridge.modems.micromodem.nav import Transponders, TravelTimes
from bridge.modems.micromodem.nmea import Sentence, from_modem
from bridge.modems.micromodem.protocol import (
    BadSentence,
    Clock,
    ClockReply,
    Config,
    HostProtocol,
    ModemError,
    ModemMessage,
    Packet,
    PacketLost,
    PingReply,
    Revision,
    RxStart,
    TransferDone,
    TransferFailed,
    UsblFix,
)
from bridge.modems.micromodem.rates import get_rate
from bridge.modems.transport import ByteTransport

__all__ = ["MicromodemBackend"]

log = logging.getLogger("zab.micromodem")

DEFAULT_BROADCAST = 0
"""Goby's ``BROADCAST_ID`` (reference 2.x, goby ``mm_driver``): the convention of a mixed
Goby/zab fleet unless the mission says otherwise."""
RX_QUEUE = 256
RETRY_BACKOFF_S = 0.5


class MicromodemBackend(ModemBackend):
    """A WHOI Micro-Modem (MM1/MM2) driven over NMEA."""

    name: ClassVar[str] = "micromodem"
    options_model: ClassVar[type[ModemOptions]] = MicromodemOptions
    options: MicromodemOptions
    ranging: ClassVar[RangingMode | None] = RangingMode.PING
    default_broadcast: ClassVar[int | None] = DEFAULT_BROADCAST
    probe: ClassVar[bytes | None] = Sentence("CC", "CFQ", ("SRC",)).encode()  # its address

    @classmethod
    def speaks(cls, line: bytes) -> bool:
        return from_modem(line)

    @classmethod
    def _options(cls, options: Mapping[str, Any]) -> MicromodemOptions:
        opts = cls.parse_options(options, "(zab check)")
        assert isinstance(opts, MicromodemOptions)
        return opts

    @classmethod
    def max_frame_bytes(cls, options: Mapping[str, Any]) -> int | None:
        """A whole packet at the configured rate (the driver spreads it over the rate's frames)."""
        return get_rate(cls._options(options).rate).max_bytes

    @classmethod
    def setup_problems(cls, options: Mapping[str, Any], address: int) -> tuple[list[str],
                                                                               list[str]]:
        """Besides the broadcast address: a water preset whose packets are smaller than the
        rate's (``zab water`` would refuse the frames), or made for another rate."""
        errors, warnings = super().setup_problems(options, address)
        opts = cls._options(options)
        rate = get_rate(opts.rate)
        try:
            preset = get_preset(str(opts.preset)) if opts.preset is not None else None
        except UnknownPresetError:
            return errors, warnings
        if preset is None or not preset.name.startswith("micromodem-rate"):
            return errors, warnings
        if preset.frame_bytes < rate.max_bytes:
            warnings.append(f"rate {rate.number} sends packets of up to {rate.max_bytes} B, "
                            f"the water's preset {preset.name} carries {preset.frame_bytes} B: "
                            f"larger frames are refused (use micromodem-rate{rate.number})")
        elif preset.name != f"micromodem-rate{rate.number}":
            warnings.append(f"the water's preset {preset.name} times packets at another rate "
                            f"than rate {rate.number} (use micromodem-rate{rate.number})")
        return errors, warnings

    def __init__(self, setup: ModemSetup) -> None:
        super().__init__(setup)
        opts = self.options
        where = f"micromodem backend of {setup.node!r}"
        if not opts.device:
            raise BackendError(f"{where}: option 'device' (serial path or URL) is required")
        self.rate = get_rate(opts.rate)
        self.baud = opts.baud
        self.timeout_s = opts.timeout_s
        self.retries = opts.retries
        self.send_retries = opts.send_retries
        self.ping_timeout_s = opts.ping_timeout_s
        self.broadcast = self.broadcast_address(setup.options)
        self.fdp = opts.fdp
        self.set_clock = opts.set_clock
        self.sound_speed = opts.sound_speed_mps
        self.ping_mode = opts.ping
        try:
            self.lbl = Transponders.from_option(opts.lbl) if opts.lbl else None
            self.protocol = HostProtocol(setup.address)
        except (TypeError, ValueError) as exc:
            raise BackendError(f"{where}: {exc}") from None
        self.device = opts.device
        self.config: dict[str, Any] = dict(opts.config)
        # a packet's airtime, cycle-init and travel, with room: [C] estimates (reference 2.6)
        packet_s = self.rate.max_bytes * 8 / self.rate.bitrate_bps + 4.0
        self.tx_timeout_s = opts.tx_timeout_s or self.timeout_s + 2 * packet_s
        self.frame_bytes = min(self.frame_bytes, self.rate.max_bytes)
        if setup.frame_bytes > self.rate.max_bytes:
            log.warning("%s: frame_bytes %d > %d B of a rate-%d packet; frames are capped",
                        where, setup.frame_bytes, self.rate.max_bytes, self.rate.number)
        self.stats.update(bad_lines=0, modem_errors=0, reboots=0, rx_lost=0, retries=0,
                          dropped=0, bad_crc=0, packet_timeout=0, fixes=0)
        self._transport: ByteTransport | None = None
        self._reader: asyncio.Task[None] | None = None
        self._init_task: asyncio.Task[None] | None = None
        self._inbox = Inbox(self.stats, RX_QUEUE)
        self._bad_input = BadInputLog(log, f"micromodem {setup.node}")
        self._lock = asyncio.Lock()  # one cycle or ping at a time: the modem is half-duplex
        self._ready = asyncio.Event()
        self._failure: BackendError | None = None
        self._configs: dict[str, asyncio.Future[str]] = {}
        self._transfer: asyncio.Future[TransferDone] | None = None
        self._pinging: tuple[int, asyncio.Future[float]] | None = None
        self._interrogating: asyncio.Future[TravelTimes] | None = None
        self._clock_reply: asyncio.Future[ClockReply | Clock] | None = None
        self._rx_start: float | None = None

    # -- hooks ---------------------------------------------------------------------------------

    async def _open(self) -> None:
        self._failure = None  # open may be retried after a failure: start clean
        self._inbox = Inbox(self.stats, RX_QUEUE)
        self._ready.clear()
        self.protocol = HostProtocol(self.address)
        name = f"micromodem {self.setup.node}"
        self._transport = ByteTransport(self.device, self.baud, name=name)
        await self._transport.open()
        self._reader = asyncio.create_task(self._read_loop(), name=f"micromodem-{self.address}")
        await self._initialise()

    async def _send(self, data: bytes, dest: int | None, ack: bool,
                    deadline: float | None) -> bool | None:
        to = self.broadcast if dest is None else dest
        if to is None:
            raise BackendError(f"{self}: a frame to every node, but no broadcast address")
        ack = ack and dest is not None
        last: BackendError | None = None
        for attempt in range(self.send_retries + 1):
            if attempt:
                backoff = RETRY_BACKOFF_S * attempt
                self._check_turn(deadline, f"a retry after a failed try ({last})",
                                 backoff + self.airtime_s(len(data)))
                self.stats["retries"] += 1
                log.warning("%s: %s; retry %d/%d", self, last, attempt, self.send_retries)
                await asyncio.sleep(backoff)
            try:
                await self._cycle(data, to, ack, deadline)
                return True if ack else None  # with ack, a cycle ends with every $CAACK
            except SendTooLate:
                raise
            except BackendError as exc:
                if self._failure is not None:
                    raise self._failure from None
                last = exc
        assert last is not None
        raise BackendError(f"micromodem {self.setup.node!r}: frame not sent after "
                           f"{self.send_retries + 1} tries: {last}")

    async def _recv(self) -> Reception:
        return await self._inbox.get()

    async def _close(self) -> None:
        self._fail(BackendError(f"micromodem {self.setup.node!r} is closed"))
        tasks = [t for t in (self._reader, self._init_task) if t is not None]
        self._reader = self._init_task = None
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        transport, self._transport = self._transport, None
        if transport is not None:
            await transport.close()

    async def _ping(self, dest: int) -> ModemRange:
        """Two-way ping of ``dest`` (``$CCMPC`` → ``$CAMPR``, or ``$CCCMD,PNG`` →
        ``$CACMR``, each giving the one-way travel time [V]), or the LBL interrogation of the
        transponder ``dest`` stands for; :class:`BackendError` when no reply comes."""
        if self.lbl is not None and dest in self.lbl.by_address:
            return await self._interrogate(dest, self.lbl)
        async with self._lock:
            await self._wait_ready()
            fut: asyncio.Future[float] = asyncio.get_running_loop().create_future()
            self._pinging = (dest, fut)
            try:
                try:
                    self.protocol.ping(dest, fdp=self.ping_mode == "fdp")
                except ValueError as exc:
                    raise BackendError(f"micromodem {self.setup.node!r}: {exc}") from None
                await self._flush()
                async with asyncio.timeout(self.ping_timeout_s):
                    owtt = await fut
                return ModemRange(dest, owtt, "ping", self.clock())
            except TimeoutError:
                raise BackendError(f"micromodem {self.setup.node!r}: no ping reply from "
                                   f"{dest} within {self.ping_timeout_s:g} s") from None
            finally:
                self._pinging = None

    async def _interrogate(self, dest: int, lbl: Transponders) -> ModemRange:
        """Interrogate the LBL transponders; the range to ``dest``'s is returned, the others'
        go to ``on_range``."""
        async with self._lock:
            await self._wait_ready()
            fut: asyncio.Future[TravelTimes] = asyncio.get_running_loop().create_future()
            self._interrogating = fut
            wait_s = lbl.window_s + self.timeout_s
            try:
                self.protocol.send(lbl.sentence)
                await self._flush()
                async with asyncio.timeout(wait_s):
                    heard = (await fut).heard()
            except TimeoutError:
                raise BackendError(f"micromodem {self.setup.node!r}: no $SNTTA within "
                                   f"{wait_s:g} s of the LBL interrogation") from None
            finally:
                self._interrogating = None
        now, ranges = self.clock(), {}
        for address, beacon in lbl.by_address.items():
            if beacon in heard:
                ranges[address] = ModemRange(address, heard[beacon], "ping", now)
        for address, rng in ranges.items():
            if address != dest:
                self._report_range(rng)
        if dest not in ranges:
            raise BackendError(f"micromodem {self.setup.node!r}: transponder "
                               f"{lbl.by_address[dest]} (node {dest}) did not answer")
        return ranges[dest]

    # -- internals -----------------------------------------------------------------------------

    async def _wait_ready(self) -> None:
        if self._failure is not None:
            raise self._failure
        if not self._ready.is_set():
            try:
                async with asyncio.timeout(self.timeout_s * (self.retries + 1)):
                    await self._ready.wait()
            except TimeoutError:
                raise BackendError(f"micromodem {self.setup.node!r}: modem not initialised") \
                    from None
        if self._failure is not None:
            raise self._failure

    def airtime_s(self, n_bytes: int) -> float:
        """The least time a packet of ``n_bytes`` keeps the modem transmitting: its frames at
        the rate's nominal bit rate, a partial frame costing a whole one [C, reference 2.2 and
        2.6: the PSK probe and header, and rate 0's cycle-init, add to it]."""
        rate = self.rate
        return rate.frames_for(n_bytes) * rate.frame_bytes * 8 / rate.bitrate_bps

    async def _cycle(self, data: bytes, dest: int, ack: bool, deadline: float | None) -> None:
        async with self._lock:
            await self._wait_ready()
            self._check_turn(deadline, "its cycle")  # (a ping, a re-initialisation took long)
            loop = asyncio.get_running_loop()
            fut: asyncio.Future[TransferDone] = loop.create_future()
            self._transfer = fut
            turn_end = None if deadline is None else loop.call_at(deadline, self._turn_ended, fut)
            try:
                try:
                    start = self.protocol.start_fdp if self.fdp else self.protocol.start_transfer
                    start(dest, data, self.rate.number, ack)
                except ValueError as exc:
                    raise BackendError(f"micromodem {self.setup.node!r}: {exc}") from None
                await self._flush()
                try:
                    async with asyncio.timeout(self.tx_timeout_s):
                        await asyncio.shield(fut)
                except TimeoutError:
                    what = "acknowledged" if ack else "sent"
                    self.protocol.abort(f"not {what} within {self.tx_timeout_s:g} s")
                    self._dispatch()
                    await fut  # raises the BackendError set by TransferFailed
            finally:
                self._transfer = None
                if turn_end is not None:
                    turn_end.cancel()

    def _turn_ended(self, fut: asyncio.Future[TransferDone]) -> None:
        """The MAC turn of the frame in ``fut``'s cycle ended: if the modem holds none of its
        data yet, the cycle is called back and the frame dropped; else its packet is on its way
        (the cycle runs on, and no retry follows)."""
        if fut.done() or not self.protocol.cancel("its MAC turn ended"):
            return
        fut.set_exception(self._too_late("the modem had not asked for its data when its MAC "
                                         "turn ended: the cycle is called back"))
        self._dispatch()  # (the TransferFailed of the cancelled cycle: fut holds the drop)

    async def _initialise(self) -> None:
        """Set SRC and the configured keys, each confirmed by its ``$CACFG`` echo; then the
        clock (``set_clock``)."""
        self._ready.clear()
        for key, value in (("SRC", self.address), *self.config.items()):
            await self._configure(str(key), value)
        if self.set_clock != "none":
            await self._set_modem_clock()
        self.protocol.needs_init = False
        self._ready.set()
        log.info("%s: initialised (rate %d, %s)", self, self.rate.number, self.device)

    async def _configure(self, key: str, value: Any) -> None:
        text = str(int(value)) if isinstance(value, bool) else str(value)
        for attempt in range(self.retries + 1):
            if self._failure is not None:
                raise self._failure
            fut: asyncio.Future[str] = asyncio.get_running_loop().create_future()
            self._configs[key] = fut
            self.protocol.configure(key, text)
            await self._flush()
            try:
                async with asyncio.timeout(self.timeout_s):
                    got = await fut
            except TimeoutError:
                log.warning("%s: no echo of $CCCFG,%s (try %d)", self, key, attempt + 1)
                continue
            except BackendError as exc:
                if self._failure is not None:
                    raise
                log.warning("%s: $CCCFG,%s refused: %s", self, key, exc)
                continue
            finally:
                self._configs.pop(key, None)
            if got.strip() != text:
                raise BackendError(f"micromodem {self.setup.node!r}: {key} is {got!r}, "
                                   f"wanted {text!r}")
            return
        raise BackendError(f"micromodem {self.setup.node!r}: no reply from the modem on "
                           f"{self.device} to $CCCFG,{key} ({self.retries + 1} tries of "
                           f"{self.timeout_s:g} s)")

    async def _clock_command(self, sentence: Sentence, wait_s: float) -> ClockReply | Clock:
        fut: asyncio.Future[ClockReply | Clock] = asyncio.get_running_loop().create_future()
        self._clock_reply = fut
        try:
            self.protocol.send(sentence)
            await self._flush()
            async with asyncio.timeout(wait_s):
                return await fut
        except TimeoutError:
            raise BackendError(f"micromodem {self.setup.node!r}: no reply to ${sentence.name}"
                               f" within {wait_s:g} s") from None
        finally:
            self._clock_reply = None

    async def _set_modem_clock(self) -> None:
        """Set the modem clock from the host's (``$CCCLK`` or ``$CCTMS``), then read it back
        with ``$CCTMQ`` (MM2; the reply comes ~0.5 s late, goby) and keep the offset."""
        now = time.time()
        await asyncio.sleep(1.075 - now % 1.0 if now % 1.0 > 0.075 else 0.075 - now % 1.0)
        second = datetime.datetime.fromtimestamp(math.floor(time.time()) + 1, datetime.UTC)
        if self.set_clock == "clk":  # 50-100 ms into a second, naming the next one (goby)
            fields = tuple(str(v) for v in (second.year, second.month, second.day,
                                            second.hour, second.minute, second.second))
            await self._clock_command(Sentence("CC", "CLK", fields), self.timeout_s)
            return
        stamp = second.strftime("%Y-%m-%dT%H:%M:%SZ")
        reply = await self._clock_command(Sentence("CC", "TMS", (stamp, "0")), self.timeout_s)
        if isinstance(reply, ClockReply) and reply.timed_out:
            raise BackendError(f"micromodem {self.setup.node!r}: $CCTMS timed out")
        reply = await self._clock_command(Sentence("CC", "TMQ", ("0",)), self.timeout_s + 0.5)
        heard = time.time()  # the reply's time is when the modem printed it, ~0.5 s on
        if isinstance(reply, ClockReply):
            with contextlib.suppress(ValueError):
                read = datetime.datetime.fromisoformat(reply.time.replace("Z", "+00:00"))
                if read.tzinfo is None:
                    read = read.replace(tzinfo=datetime.UTC)
                self.stats["clock_offset_ms"] = round((read.timestamp() - heard) * 1000)

    async def _reinitialise(self) -> None:
        try:
            await self._initialise()
        except BackendError as exc:
            self.stats["errors"] += 1
            self._fail(BackendError(f"micromodem {self.setup.node!r}: re-initialisation after "
                                    f"a reboot failed: {exc}"))

    async def _flush(self) -> None:
        data = self.protocol.data_to_send()
        if data and self._transport is not None:
            try:
                await self._transport.write(data)
            except BackendError as exc:
                self._fail(exc)
                raise

    async def _read_loop(self) -> None:
        assert self._transport is not None
        try:
            while True:
                self.protocol.receive_data(await self._transport.read())
                self._dispatch()
                await self._flush()
        except asyncio.CancelledError:
            raise
        except BackendError as exc:
            self.stats["errors"] += 1
            self._fail(exc)

    def _dispatch(self) -> None:
        for event in self.protocol.events():
            if isinstance(event, RxStart):
                self._rx_start = time.time()
            elif isinstance(event, Packet):
                self._received(event)
            elif isinstance(event, TransferDone | TransferFailed):
                fut = self._transfer
                if fut is not None and not fut.done():
                    if isinstance(event, TransferDone):
                        fut.set_result(event)
                    else:
                        fut.set_exception(BackendError(
                            f"micromodem {self.setup.node!r}: {event.reason}"))
            elif isinstance(event, Config):
                fut_cfg = self._configs.get(event.key)
                if fut_cfg is not None and not fut_cfg.done():
                    fut_cfg.set_result(event.value)
            elif isinstance(event, PingReply):
                ping = self._pinging
                if (ping is not None and event.src == ping[0] and event.dest == self.address
                        and not ping[1].done()):
                    ping[1].set_result(event.travel_time_s)
            elif isinstance(event, ModemError):
                self.stats["modem_errors"] += 1
                log.warning("%s: modem error %s %s %s", self, event.module, event.number,
                            event.message)
                if event.module in ("NMEA", "CFG", "NAV"):  # goby stops waiting
                    self._wake(BackendError(f"micromodem {self.setup.node!r}: the modem "
                                            f"refused the command ({event.module} "
                                            f"{event.message})"), transfer=False)
            elif isinstance(event, Revision) and event.init:
                self.stats["reboots"] += 1
                log.warning("%s: the modem rebooted; re-initialising", self)
                if self._ready.is_set() and (self._init_task is None or self._init_task.done()):
                    self._ready.clear()
                    self._init_task = asyncio.create_task(self._reinitialise())
            elif isinstance(event, ClockReply | Clock):
                fut_clk = self._clock_reply
                if fut_clk is not None and not fut_clk.done():
                    fut_clk.set_result(event)
            elif isinstance(event, ModemMessage):
                if event.bad_crc or event.packet_timeout:
                    self.stats["bad_crc" if event.bad_crc else "packet_timeout"] += 1
            elif isinstance(event, UsblFix):
                self._usbl(event)
            elif isinstance(event, TravelTimes):
                fut_tta = self._interrogating
                if fut_tta is not None and not fut_tta.done():
                    fut_tta.set_result(event)
            elif isinstance(event, BadSentence):
                self.stats["bad_lines"] += 1
                self._bad_input.bad(event.line, event.reason)
            elif isinstance(event, PacketLost):
                self.stats["rx_lost"] += 1
                log.info("%s: lost a packet from %s: %s", self, event.src, event.reason)

    def _usbl(self, fix: UsblFix) -> None:
        """A ``$CAUSB2``: the node heard last, located from this modem's USBL head."""
        if fix.src is None:
            log.info("%s: $CAUSB2 before any node was heard; dropped", self)
            return
        r = fix.travel_time_s * self.sound_speed
        az, el = math.radians(fix.azimuth_deg), math.radians(fix.elevation_deg)
        level = r * math.cos(el)
        self._report_fix(ModemFix(fix.src, self.clock(), r, fix.azimuth_deg, fix.elevation_deg,
                                  level * math.sin(az), level * math.cos(az), r * math.sin(el)))

    def _received(self, packet: Packet) -> None:
        now = time.time()
        start, self._rx_start = self._rx_start, None
        meta = {
            "dest": None if packet.dest == self.broadcast else packet.dest,
            "ack": packet.ack,
            "rate": packet.rate,
            "frames": packet.frames,
            "start": start if start is not None else now,
        }
        self._deliver(Reception(data=packet.data, src=packet.src, time=now, meta=meta))

    def _fail(self, error: BackendError) -> None:
        """Enter the failed state once: wake every waiter with ``error``."""
        if self._failure is not None:
            return
        self._failure = error
        self._ready.set()  # waiters wake and see the failure
        self._wake(error, transfer=True)
        with contextlib.suppress(asyncio.QueueFull):
            self._inbox.put(error)

    def _wake(self, error: BackendError, *, transfer: bool) -> None:
        """Fail every command waiting for the modem's answer (and the transfer with
        ``transfer``)."""
        futures: list[asyncio.Future[Any]] = [*self._configs.values()]
        if transfer and self._transfer is not None:
            futures.append(self._transfer)
        if self._pinging is not None:
            futures.append(self._pinging[1])
        if self._interrogating is not None:
            futures.append(self._interrogating)
        for fut in futures:
            if not fut.done():
                fut.set_exception(error)
