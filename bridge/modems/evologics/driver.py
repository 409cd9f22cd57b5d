"""``evologics``: an EvoLogics S2C modem over serial or TCP, frames as instant messages.

Options (``modem.options`` in the mission): the table at the end. ``device`` is a serial path, or
``socket://host:9200`` for the modem's TCP port; ``ack`` asks unicast frames to be acknowledged
(``AT*SENDIM ... ack``; else ``noack``); ``mode`` is ``data`` (as evins does) or ``command``;
``eol`` defaults to ``\\r`` on serial, ``\\n`` over TCP [V]; ``busy_backoff_s`` doubles after
each ``BUSY``; ``keepalive_s`` queries ``AT?AL`` when idle to notice a dead or rebooted modem;
``timed_send`` schedules frames on the modem clock with ``AT*SENDIMS`` when the modem answers
``AT?CLOCK`` and ``AT@ZX1``, ``tx_lead_s`` ahead of it (the command must reach the modem first:
64 B at 19200 baud take 44 ms), and ``AT?CLOCK`` is read again every ``clock_sync_s`` to follow
host–modem drift.

At start-up the backend asks ``ATI0`` for the firmware version (``stats`` keeps it as
``firmware``): firmware before 1.7 prints ``RECVIM``/``RECVPBM`` with bitrate and propagation
time in place of the duration [V DUNE], and is parsed so. A modem that does not answer ``ATI0``
with a version is taken as 1.7 or later (logged).

Timed sends (``timed_send`` is then True for the runtime): :meth:`clock` is the modem's µs clock
(:class:`~bridge.modems.evologics.clock.ModemClock`), ``send(at=...)`` becomes
``AT*SENDIMS,<len>,<dst>,<usec>,<data>`` so the emission starts exactly at ``at``, and each
reception's ``start`` is the modem's own timestamp (``RECVIMS``, or the ``RECVEND`` just
before a ``RECVIM``): DLBL delays and ranges are then exact to the modem's timestamping.
``SENDIMS`` has no ack flag [V syntax], so a frame that asks for an ack goes as an
``AT*SENDIM ... ack`` at about ``at`` (its timing is then only as good as the host's). An IMS
that the modem reports too late (``EXPIREDIMS``) raises :class:`BackendError` without failing
the backend, and is counted in ``stats["expired"]``.

Ranges: after every delivered acknowledged IM the backend reads ``AT?T`` (one-way propagation
of the exchange, µs [V DUNE/evins]) and reports it to ``on_range`` (method ``propagation``).

``send`` returns when the modem reports the end of the transmission (``SENDEND``); with ``ack``
and a unicast destination, after the delivery report. The frame's MAC turn
(``send(until=...)``, a TDMA slot's end) bounds the sending: a frame still waiting for the modem
(behind another send, a keep-alive) when it ends, or a ``BUSY`` answer whose retry would not
end before it (the IM's airtime by the §1.9 model), is dropped: counted in ``stats["late"]``,
:class:`~bridge.errors.SendTooLate` raised, the backend up. A ``FAILEDIM`` is counted in
``stats["failed"]`` and logged (the frame was transmitted; the runtime treats a BackendError as a
dead modem). Any modem failure (no reply, port lost, ``ERROR`` reply, ``BUSY`` after the
retries) raises :class:`BackendError` from ``send`` *and* ends ``recv``, so the runtime reopens a
fresh backend, which re-initialises the modem.

Each :class:`Reception` carries in ``meta``: ``dest`` (``None`` for broadcast), ``start`` (wall
clock), ``duration_s``, ``rssi_db``, ``integrity``, ``velocity_mps``, ``flag``, and when known
``rx_timestamp_us`` (modem clock at the start of reception, from ``RECVEND``/``RECVIMS``),
``propagation_s`` (one-way, from ``AT?T`` after our last delivered IM to that node) and ``usbl``
(the latest ``USBLLONG`` fix of the sender). Each ``USBLLONG`` also goes to ``on_fix`` as a
:class:`~bridge.modems.base.ModemFix` with a covariance from its accuracy (the runtime
publishes it on ``@zab/<mission>/<node>/usbl/<peer>``).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from collections.abc import Mapping
from dataclasses import asdict
from typing import Any, ClassVar

from bridge.core.reception import RangingMode
from bridge.errors import BackendError, SendTooLate
from bridge.mission.backends import EvologicsOptions, ModemOptions
from bridge.modems.base import (
    BadInputLog,
    Inbox,
    ModemBackend,
    ModemFix,
    ModemRange,
    ModemSetup,
    Reception,
)
from bridge.modems.evologics.clock import ModemClock
from bridge.modems.evologics.commands import send_im, send_ims
from bridge.modems.evologics.protocol import (
    BROADCAST,
    IM_MAX_BYTES,
    BurstData,
    Busy,
    CanceledIm,
    DeliveredIm,
    Error,
    Event,
    ExpiredIms,
    FailedIm,
    HostProtocol,
    Malformed,
    Mode,
    Ok,
    RecvEnd,
    RecvIm,
    RecvImLegacy,
    RecvIms,
    RecvPbm,
    RecvPbmLegacy,
    SendEnd,
    UsblLong,
    Value,
    firmware_is_legacy,
    from_modem,
)
from bridge.modems.transport import ByteTransport

__all__ = ["EvologicsBackend"]

log = logging.getLogger("zab.evologics")

RECVEND_MATCH_S = 1.0
"""A ``RECVEND`` older than this when its ``RECVIM`` arrives belongs to another signal."""


def im_airtime_s(n_bytes: int) -> float:
    """How long an IM of ``n_bytes`` is on the air: the §1.9 model fitted to real durations
    (182 ms for 4 B, 221 ms for 7 B) [C]."""
    return 0.13 + 0.012 * n_bytes


class EvologicsBackend(ModemBackend):
    """An EvoLogics S2C modem through pyserial (serial port or TCP)."""

    name: ClassVar[str] = "evologics"
    options_model: ClassVar[type[ModemOptions]] = EvologicsOptions
    options: EvologicsOptions
    ranging: ClassVar[RangingMode | None] = RangingMode.ACK
    default_broadcast: ClassVar[int | None] = BROADCAST  # driver practice [V BIR]
    probe: ClassVar[bytes | None] = b"+++AT?MODE\r"  # (the start-up's first query)

    @classmethod
    def max_frame_bytes(cls, options: Mapping[str, Any]) -> int | None:
        """Instant messages carry at most 64 bytes."""
        return IM_MAX_BYTES

    @classmethod
    def speaks(cls, line: bytes) -> bool:
        return from_modem(line)

    def __init__(self, setup: ModemSetup) -> None:
        super().__init__(setup)
        opts = self.options
        if not opts.device:
            raise BackendError(
                f"evologics backend of {setup.node!r}: option 'device' (serial path or "
                "socket://host:9200) is required"
            )
        if not 1 <= setup.address <= 254:
            raise BackendError(f"evologics backend: address {setup.address} outside 1..254")
        self.device = opts.device
        self.broadcast = self.broadcast_address(setup.options)
        self.frame_bytes = min(self.frame_bytes, IM_MAX_BYTES)
        tcp = self.device.startswith("socket://")
        self.mode = Mode(opts.mode)
        eol = (opts.eol if opts.eol is not None else "\n" if tcp else "\r").encode()
        self.timeout_s = opts.timeout_s
        self.probe_retries = opts.probe_retries
        self.busy_retries = opts.busy_retries
        self.busy_backoff_s = opts.busy_backoff_s
        self.send_timeout_s = opts.send_timeout_s
        self.ack_timeout_s = opts.ack_timeout_s
        self.keepalive_s = opts.keepalive_s
        self.promiscuous = opts.promiscuous
        self.usbl = opts.usbl
        self.want_timed = opts.timed_send
        self.clock_sync_s = opts.clock_sync_s
        self.modem_clock = ModemClock()
        self._timed = False
        self._last_sync = -float("inf")
        self.transport = ByteTransport(self.device, opts.baud,
                                       name=f"evologics {setup.node}")
        self.protocol = HostProtocol(Mode.DATA, eol=eol)
        self.stats.update(delivered=0, failed=0, busy=0, malformed=0, modem_errors=0,
                          burst_bytes=0, expired=0)
        self.fixes: dict[int, dict[str, Any]] = {}
        self.propagation: dict[int, tuple[float, float]] = {}  # dst -> (time, seconds)
        self._inbox = Inbox(self.stats)
        self._bad_input = BadInputLog(log, f"evologics {setup.node}")
        self._reply: asyncio.Future[Event] | None = None
        self._expect: str | None = None
        self._raw: bytearray = bytearray()
        self._tx_events: asyncio.Queue[Event] = asyncio.Queue()
        self._last_end: tuple[float, RecvEnd] | None = None
        self._lock = asyncio.Lock()
        self._reader: asyncio.Task[None] | None = None
        self._keepalive: asyncio.Task[None] | None = None
        self._failure: BackendError | None = None
        self._extended = True
        self._last_io = 0.0
        self.firmware: str | None = None
        """What ``ATI0`` answered at start-up (None before, or when it named no version)."""

    @property
    def timed_send(self) -> bool:  # type: ignore[override]
        """Whether ``send(at=...)`` is exact: the modem answered ``AT?CLOCK`` at start-up."""
        return self._timed

    def clock(self) -> float:
        """The modem's clock when sends are timed (seconds near host time), else the host's."""
        if self._timed:
            return self.modem_clock.now(time.time())
        return time.time()

    # -- hooks ---------------------------------------------------------------------------------

    async def _open(self) -> None:
        self._failure = None
        await self.transport.open()
        self._reader = asyncio.create_task(self._read_loop(), name=f"evologics-{self.address}")
        async with self._lock:
            await self._initialise()
        if self.keepalive_s > 0 or (self._timed and self.clock_sync_s > 0):
            self._keepalive = asyncio.create_task(self._keepalive_loop())
        log.info("%s: modem ready on %s (address %d, %s mode)", self.setup.node, self.device,
                 self.address, self.mode.value)

    async def _send(self, data: bytes, dest: int | None, ack: bool,
                    deadline: float | None) -> bool | None:
        dst = self.broadcast if dest is None else dest
        if dst is None:
            raise BackendError(f"{self}: a frame to every node, but no broadcast address")
        ack = ack and dst != self.broadcast  # broadcast requires noack [V driver practice]
        async with self._lock:
            self._check()
            self._check_turn(deadline, "its AT*SENDIM")  # (it waited for the modem)
            while not self._tx_events.empty():
                self._tx_events.get_nowait()  # reports of earlier, finished sends
            try:
                return await self._send_locked(data, dst, ack, deadline)
            except SendTooLate:
                raise
            except BackendError as exc:
                self._fail(exc)
                raise

    async def _recv(self) -> Reception:
        return await self._inbox.get()

    async def _close(self) -> None:
        self._fail(BackendError(f"evologics modem {self.setup.node!r} is closed"))
        for task in (self._keepalive, self._reader):
            if task is not None:
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError, Exception):
                    await task
        self._keepalive = self._reader = None
        await self.transport.close()

    # -- start-up ------------------------------------------------------------------------------

    async def _initialise(self) -> None:
        """Find the mode, settle in the configured one, set and check the address (§1.2)."""
        current = await self._probe_mode()
        if current is Mode.COMMAND and self.mode is Mode.DATA:
            self.protocol.send("O", reply=False)  # ATO: no reply [V]
            await self._write(self.protocol.data_to_send())
            self.protocol.mode = Mode.DATA
            if await self._probe_mode() is not Mode.DATA:
                raise BackendError(f"{self}: ATO did not switch the modem to data mode")
        elif current is Mode.DATA and self.mode is Mode.COMMAND:
            reply = await self._command("C")  # +++ATC -> OK [V BIR]
            self.protocol.mode = Mode.COMMAND
            self._expect_ok(reply, "+++ATC")
        await self._firmware()
        await self._command_ok(f"!AL{self.address}")
        reply = await self._command("?AL")
        if not isinstance(reply, Value) or reply.text.strip() != str(self.address):
            raise BackendError(f"{self}: address is {_text(reply)} after AT!AL{self.address}"
                               " (a pending [*]OK value needs a modem reset)")
        reply = await self._command("@ZX1")  # SENDSTART/SENDEND/RECVSTART/RECVEND [V]
        self._extended = isinstance(reply, Ok)
        if not self._extended:
            log.warning("%s: AT@ZX1 refused (%s): send timing is estimated", self,
                        _text(reply))
        await self._command_ok(f"!RP{int(self.promiscuous)}")
        if self.usbl:
            await self._command("@ZU1")  # only USBL heads have it; a refusal is harmless
        self._timed = False
        if self.want_timed and self._extended:
            self._timed = await self._sync_clock()
            if not self._timed:
                log.warning("%s: AT?CLOCK unanswered: frames are sent untimed (AT*SENDIM)",
                            self)

    async def _firmware(self) -> None:
        """``ATI0``: the firmware version, and with it the ``RECVIM``/``RECVPBM`` layout."""
        reply = await self._command("I0")
        text = reply.text.strip() if isinstance(reply, Value) else ""
        try:
            legacy = firmware_is_legacy(text)
        except ValueError:
            log.warning("%s: ATI0 answered %s, not a firmware version: taking 1.7+ layouts",
                        self, _text(reply))
            legacy = False
        self.firmware = text or None
        self.protocol.legacy_recvim = legacy
        log.info("%s: firmware %s (%s RECVIM layout)", self, text or "?",
                 "1.6" if legacy else "1.7+")

    async def _sync_clock(self, readings: int = 3) -> bool:
        """Read ``AT?CLOCK`` a few times and keep the reading with the shortest round trip."""
        best: tuple[float, float, int] | None = None  # (round trip, host midpoint, counter)
        for _ in range(readings):
            sent = time.time()
            reply = await self._command("?CLOCK")
            got = time.time()
            text = reply.text.strip() if isinstance(reply, Value) else ""
            if not text.isdigit() or int(text) >= 1 << 32:
                return False
            if best is None or got - sent < best[0]:
                best = (got - sent, (sent + got) / 2, int(text))
        assert best is not None
        self.modem_clock.sync(best[1], best[2], uncertainty_s=best[0] / 2)
        self._last_sync = time.monotonic()
        return True

    async def _probe_mode(self) -> Mode:
        """Send ``+++AT?MODE``: a wrapped reply means data mode, ``ERROR WRONG FORMAT`` command
        mode (evins/dmac2 start-up [V])."""
        for attempt in range(1, self.probe_retries + 1):
            self.protocol.mode = Mode.DATA
            self.protocol.clear_pending()
            self._raw.clear()
            try:
                reply = await self._command("?MODE", timeout=self.timeout_s)
            except _NoReply:
                reply = None
            if isinstance(reply, BurstData):  # an unwrapped ERROR WRONG FORMAT: command mode
                self.protocol.mode = Mode.COMMAND
                self.protocol.clear_pending()
                reply = await self._command("?MODE")
                if isinstance(reply, Value):
                    return Mode.COMMAND
                raise BackendError(f"{self}: AT?MODE answered {_text(reply)}")
            if reply is None:
                log.info("%s: no answer to +++AT?MODE (attempt %d of %d)", self, attempt,
                         self.probe_retries)
                continue
            if isinstance(reply, Value):
                return Mode.DATA
            if isinstance(reply, Error) and reply.reason.startswith("NOT INITIALIZED"):
                await asyncio.sleep(self.timeout_s / 2)  # dmac2 ignores it and asks again
                continue
            raise BackendError(f"{self}: unexpected answer to AT?MODE: {_text(reply)}")
        wrote = bytes(self._raw).strip().split(b"\n", 1)[0].strip()  # (the last probe's)
        raise BackendError(f"{self}: no answer from the modem on {self.device} within "
                           f"{self.timeout_s:g} s ({self.probe_retries} probes)" + (
                               f"; the device wrote {wrote.decode('latin-1')[:80]!r} instead "
                               "(another kind of modem? zab doctor tells)" if wrote else ""))

    # -- sending -------------------------------------------------------------------------------

    async def _send_timed(self, data: bytes, dest: int | None, ack: bool, at: float,
                          deadline: float | None) -> bool | None:
        dst = self.broadcast if dest is None else dest
        if dst is None:
            raise BackendError(f"{self}: a frame to every node, but no broadcast address")
        if ack and dst != self.broadcast:  # SENDIMS has no ack flag: an acked IM at about ``at``
            await asyncio.sleep(max(0.0, at - self.clock()))
            return await self._send(data, dest, ack, deadline)
        async with self._lock:
            self._check()
            self._check_turn(deadline, "its AT*SENDIMS")
            while not self._tx_events.empty():
                self._tx_events.get_nowait()
            try:
                await self._send_ims_locked(data, dst, at, deadline)
            except (_NotSent, SendTooLate):
                raise
            except BackendError as exc:
                self._fail(exc)
                raise
        return None

    async def _send_ims_locked(self, data: bytes, dst: int, at: float,
                               deadline: float | None) -> None:
        """``AT*SENDIMS`` at modem time ``at``; wait for its ``SENDEND`` (or ``EXPIREDIMS``)."""
        usec = self.modem_clock.counter(at)
        await self._command_busy(send_ims(data, dst, usec), f"AT*SENDIMS to {dst}", deadline,
                                 im_airtime_s(len(data)))
        wait = max(0.0, at - self.clock()) + self.send_timeout_s
        end = await self._wait_tx(
            lambda e: (isinstance(e, SendEnd) and e.addr == dst) or (
                isinstance(e, ExpiredIms | CanceledIm) and e.dst == dst), wait, "SENDEND")
        if isinstance(end, ExpiredIms | CanceledIm):
            self.stats["expired"] += 1
            raise _NotSent(f"{self}: the modem dropped the IMS to {dst} due at {at:.6f} "
                           f"({end.body().decode('latin-1')}): scheduled too late?")

    async def _command_busy(self, text: bytes, what: str, deadline: float | None = None,
                            airtime_s: float = 0.0) -> None:
        """A send command, retried while the modem answers ``BUSY``, as long as a retry
        (``airtime_s`` on the air) still ends before ``deadline`` (the loop's clock)."""
        delay = self.busy_backoff_s
        for attempt in range(self.busy_retries + 1):
            reply = await self._command(text)
            if isinstance(reply, Ok):
                return
            if isinstance(reply, Busy) and attempt < self.busy_retries:
                self.stats["busy"] += 1
                self._check_turn(deadline, f"a retry of {what} after BUSY {reply.reason}",
                                 delay + airtime_s)
                log.info("%s: modem busy (%s), retry in %.2f s", self, reply.reason, delay)
                await asyncio.sleep(delay)
                delay *= 2
                continue
            raise BackendError(f"{self}: {what} refused: {_text(reply)}")

    async def _send_locked(self, data: bytes, dst: int, ack: bool,
                           deadline: float | None) -> bool | None:
        """Send one IM; with ``ack``, whether the modem reported it delivered."""
        await self._command_busy(send_im(data, dst, ack=ack), f"AT*SENDIM to {dst}", deadline,
                                 im_airtime_s(len(data)))
        if not self._extended:
            await asyncio.sleep(im_airtime_s(len(data)))
            return None
        await self._wait_tx(lambda e: isinstance(e, SendEnd) and e.addr == dst,
                            self.send_timeout_s, "SENDEND")
        if not ack:
            return None
        try:
            report = await self._wait_tx(
                lambda e: isinstance(e, DeliveredIm | FailedIm) and e.dst == dst,
                self.ack_timeout_s, "DELIVEREDIM/FAILEDIM")
        except BackendError:
            self.stats["failed"] += 1
            log.warning("%s: no delivery report for the IM to %d", self, dst)
            return None
        if isinstance(report, FailedIm):
            self.stats["failed"] += 1
            log.warning("%s: IM to %d not delivered (FAILEDIM)", self, dst)
            return False
        self.stats["delivered"] += 1
        reply = await self._command("?T")  # one-way propagation, µs [V DUNE/evins]
        if isinstance(reply, Value) and reply.text.strip().isdigit():
            travel = int(reply.text) * 1e-6
            self.propagation[dst] = (time.time(), travel)
            self._report_range(ModemRange(dst, travel, "propagation", self.clock()))
        return True

    async def _wait_tx(self, match: Any, timeout: float, what: str) -> Event:
        deadline = asyncio.get_running_loop().time() + timeout
        while True:
            left = deadline - asyncio.get_running_loop().time()
            try:
                async with asyncio.timeout(max(left, 0.0)):
                    event = await self._tx_events.get()
            except TimeoutError:
                raise BackendError(f"{self}: no {what} within {timeout:g} s") from None
            self._check()
            if match(event):
                return event

    # -- commands ------------------------------------------------------------------------------

    async def _command(self, text: str | bytes, *, timeout: float | None = None) -> Event:
        """Send ``AT<text>`` and wait for its reply (``_NoReply`` on timeout during start-up,
        :class:`BackendError` otherwise)."""
        self._check()
        loop = asyncio.get_running_loop()
        self._reply = loop.create_future()
        self.protocol.send(text)
        self._expect = self.protocol.pending[-1]
        await self._write(self.protocol.data_to_send())
        try:
            async with asyncio.timeout(timeout or self.timeout_s):
                return await asyncio.shield(self._reply)
        except TimeoutError:
            self._check()
            if timeout is not None:
                raise _NoReply() from None
            raise BackendError(f"{self}: no reply to AT{_show(text)} within "
                               f"{self.timeout_s:g} s") from None
        finally:
            self._reply = None
            self._expect = None

    async def _command_ok(self, text: str) -> None:
        self._expect_ok(await self._command(text), f"AT{text}")

    def _expect_ok(self, reply: Event, what: str) -> None:
        if not isinstance(reply, Ok):
            raise BackendError(f"{self}: {what} answered {_text(reply)}")

    async def _write(self, data: bytes) -> None:
        self._last_io = time.monotonic()
        await self.transport.write(data)

    # -- reading -------------------------------------------------------------------------------

    async def _read_loop(self) -> None:
        try:
            while True:
                data = await self.transport.read()
                self._last_io = time.monotonic()
                self.protocol.receive_data(data)
                for event in self.protocol.events():
                    self._dispatch(event)
        except BackendError as exc:
            self.stats["errors"] += 1
            self._fail(exc)

    def _dispatch(self, event: Event) -> None:
        now = time.time()
        if isinstance(event, Ok | Value | Error | Busy) and event.command is not None:
            fut = self._reply
            if fut is not None and not fut.done() and event.command == self._expect:
                fut.set_result(event)
            else:
                log.debug("%s: late reply ignored: %s", self, event)
            return
        if isinstance(event, Error | Busy):  # asynchronous: ERROR EFAULT, ERROR OVERLOAD
            self.stats["modem_errors"] += 1
            log.warning("%s: modem reports %s", self, _text(event))
        elif isinstance(event, RecvIm | RecvImLegacy | RecvIms | RecvPbm | RecvPbmLegacy):
            self._deliver(self._reception(event, now))
        elif isinstance(event, RecvEnd):
            self._last_end = (now, event)
        elif isinstance(event, UsblLong):
            self.fixes[event.remote_addr] = {"time": now, **asdict(event)}
            self._report_fix(_fix(event, self.clock()))
        elif isinstance(event, SendEnd | DeliveredIm | FailedIm | ExpiredIms | CanceledIm):
            self._tx_events.put_nowait(event)
        elif isinstance(event, BurstData):
            self._raw += event.data  # the start-up probe looks here for ERROR WRONG FORMAT
            del self._raw[:-256]
            self.stats["burst_bytes"] += len(event.data)
            fut = self._reply
            if self._expect == "?MODE" and b"ERROR WRONG FORMAT\r\n" in self._raw and (
                fut is not None and not fut.done()
            ):
                fut.set_result(event)
        elif isinstance(event, Malformed):
            self.stats["malformed"] += 1
            self._bad_input.bad(event.data, event.reason)

    def _reception(self, ev: RecvIm | RecvImLegacy | RecvIms | RecvPbm | RecvPbmLegacy,
                   now: float) -> Reception:
        duration = getattr(ev, "duration_us", 0) * 1e-6
        if isinstance(ev, RecvImLegacy | RecvPbmLegacy) and ev.bitrate > 0:
            duration = len(ev.data) * 8 / ev.bitrate  # 1.6 gives the bit rate, not the time
        meta: dict[str, Any] = {
            "dest": None if ev.dst == self.broadcast else ev.dst,
            "start": now - duration,
            "duration_s": duration,
            "rssi_db": ev.rssi,
            "integrity": ev.integrity,
            "velocity_mps": ev.velocity,
            "flag": getattr(ev, "flag", None),
        }
        if isinstance(ev, RecvIms):
            meta["rx_timestamp_us"] = ev.timestamp_us
        elif self._last_end is not None and now - self._last_end[0] < RECVEND_MATCH_S:
            meta["rx_timestamp_us"] = self._last_end[1].timestamp_us
        if self._timed:  # the modem clock: its own reception stamp when there is one
            modem_now = self.modem_clock.now(now)
            meta["start"] = modem_now - duration
            if "rx_timestamp_us" in meta:
                meta["start"] = self.modem_clock.seconds(meta["rx_timestamp_us"],
                                                         modem_now - duration)
            now = meta["start"] + duration
        if isinstance(ev, RecvImLegacy | RecvPbmLegacy):
            meta["propagation_s"] = ev.ptime_us * 1e-6
        elif ev.src in self.propagation:
            meta["propagation_s"] = self.propagation[ev.src][1]
        if ev.src in self.fixes:
            meta["usbl"] = self.fixes[ev.src]
        return Reception(data=ev.data, src=ev.src, time=now, meta=meta)

    async def _keepalive_loop(self) -> None:
        """Re-read the modem clock every ``clock_sync_s``; ask ``AT?AL`` when idle."""
        period = min(t / 2 for t in (self.keepalive_s, self.clock_sync_s) if t > 0)
        while True:
            await asyncio.sleep(period)
            if self._timed and 0 < self.clock_sync_s <= time.monotonic() - self._last_sync \
                    and not self._lock.locked():
                async with self._lock:
                    try:
                        if not await self._sync_clock(readings=1):
                            raise BackendError(f"{self}: AT?CLOCK no longer answered")
                    except BackendError as exc:
                        self._fail(exc)
                        return
            if self.keepalive_s <= 0 or self._lock.locked() or \
                    time.monotonic() - self._last_io < self.keepalive_s:
                continue
            async with self._lock:
                try:
                    reply = await self._command("?AL")
                    if not isinstance(reply, Value) or reply.text.strip() != str(self.address):
                        raise BackendError(f"{self}: keep-alive AT?AL answered "
                                           f"{_text(reply)} (modem reset?)")
                except BackendError as exc:
                    self._fail(exc)
                    return

    # -- failure -------------------------------------------------------------------------------

    def _check(self) -> None:
        if self._failure is not None:
            raise self._failure

    def _fail(self, error: BackendError) -> None:
        """Enter the failed state once: pending and later calls raise ``error``."""
        if self._failure is not None:
            return
        self._failure = error
        if self._reply is not None and not self._reply.done():
            self._reply.set_exception(error)
        self._tx_events.put_nowait(Malformed(b"", "failed"))  # wakes _wait_tx, which checks
        self._inbox.put(error)


def _fix(ev: UsblLong, now: float) -> ModemFix:
    """A ``USBLLONG`` as a :class:`ModemFix`: its ENU offset; its ``accuracy`` taken as the
    standard deviation (m) of each axis [U: the unit is not in a stored source]."""
    level = math.hypot(ev.e, ev.n)
    variance = ev.accuracy ** 2
    return ModemFix(ev.remote_addr, now, math.hypot(level, ev.u),
                    math.degrees(math.atan2(ev.e, ev.n)) % 360.0,
                    math.degrees(math.atan2(-ev.u, level)), ev.e, ev.n, -ev.u,
                    (variance, 0.0, 0.0, 0.0, variance, 0.0, 0.0, 0.0, variance))


class _NoReply(Exception):
    """A start-up probe got no reply (not yet an error)."""


class _NotSent(BackendError):
    """The modem dropped a frame (a late IMS) but is fine: the caller is told, the backend
    stays up."""


def _text(event: Event) -> str:
    if isinstance(event, Error):
        return f"ERROR {event.reason}"
    if isinstance(event, Busy):
        return f"BUSY {event.reason}"
    if isinstance(event, Value):
        return repr(event.text)
    if isinstance(event, Ok):
        return "[*]OK" if event.pending else "OK"
    return repr(event)


def _show(text: str | bytes) -> str:
    raw = text.decode("latin-1") if isinstance(text, bytes) else text
    return raw.split(",", 4)[0] if raw.startswith("*SEND") else raw
