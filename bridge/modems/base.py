"""The modem backend interface every modem driver implements (like python-can's ``BusABC``).

Public methods do the shared checks and counting and call one hook each, which backends
implement: :meth:`ModemBackend._open`, :meth:`~ModemBackend._send`, :meth:`~ModemBackend._recv`
and :meth:`~ModemBackend._close`. Every failure surfaces as :class:`~bridge.errors.BackendError`.

A frame's MAC turn ends at the ``until`` given to :meth:`ModemBackend.send` (a TDMA slot's end):
no transmission of it begins from then on, neither its first try nor a retry. The base refuses
a frame already too late; the send hooks get the end as ``deadline``, on the event loop's clock,
and a backend that waits (for its lock, for the modem) or retries checks it before each try
(:meth:`ModemBackend._check_turn`). A frame so dropped is counted in ``stats["late"]``,
logged, and :class:`~bridge.errors.SendTooLate` raised; the backend stays up.
"""

from __future__ import annotations

import asyncio
import logging
import math
import re
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, ClassVar

from bridge.core.reception import ModemFix, ModemRange, RangingMode, Reception
from bridge.errors import BackendError, SendTooLate
from bridge.mission.backends import AnyOptions, ModemOptions, option_errors

__all__ = ["BadInputLog", "Inbox", "ModemBackend", "ModemFix", "ModemRange", "ModemSetup",
           "Reception"]

_EMPTY: Mapping[str, Any] = MappingProxyType({})

log = logging.getLogger("zab.modem")


@dataclass(frozen=True)
class ModemSetup:
    """Everything a backend needs to know about its node, built from the mission file."""

    node: str
    address: int
    frame_bytes: int
    options: Mapping[str, Any] = field(default_factory=lambda: _EMPTY)
    peers: Mapping[int, Mapping[str, Any]] = field(default_factory=lambda: MappingProxyType({}))
    position: tuple[float, float, float] | None = None


class BadInputLog:
    """Bad input from a modem (a noisy line), logged so an operator sees it without a flood:
    each kind's first at WARNING, then at most one WARNING per ``period_s`` per kind, with the
    running count; the others at DEBUG. A kind is the reason without its numbers and quoted
    parts (``checksum mismatch``, ``+++AT packet declares N B, its body holds N``)."""

    SHOWN = 80
    """Bytes of the offending input shown."""

    def __init__(self, logger: logging.Logger, who: str, period_s: float = 60.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.logger = logger
        self.who = who
        self.period_s = period_s
        self.clock = clock
        self.counts: dict[str, int] = {}
        self._warned: dict[str, float] = {}

    @staticmethod
    def kind(reason: str) -> str:
        head = re.split(r"[:;(]| in | got |'|\$", reason, maxsplit=1)[0]
        return re.sub(r"\d+", "N", head).strip()[:60] or "bad input"

    def bad(self, data: bytes, reason: str) -> None:
        """Count (and maybe log) one piece of bad input."""
        kind = self.kind(reason)
        count = self.counts[kind] = self.counts.get(kind, 0) + 1
        now = self.clock()
        last = self._warned.get(kind)
        level = logging.DEBUG
        if last is None or now - last >= self.period_s:
            self._warned[kind] = now
            level = logging.WARNING
        self.logger.log(level, "%s: bad modem input (%s; %d of this kind so far): %r", self.who,
                        reason, count, data[: self.SHOWN])


class Inbox:
    """Receptions waiting for :meth:`ModemBackend.recv`.

    Bounded (``maxsize`` 0 = unbounded): when full, the oldest reception is dropped and counted
    in ``stats["dropped"]``. A :class:`BackendError` put in it is sticky: every later
    :meth:`get` raises it, so a failed backend never hangs a reader.
    """

    def __init__(self, stats: dict[str, int], maxsize: int = 0) -> None:
        self._stats = stats
        self._stats.setdefault("dropped", 0)
        self._queue: asyncio.Queue[Reception | BackendError] = asyncio.Queue(maxsize)

    def put(self, item: Reception | BackendError) -> None:
        if self._queue.full():
            self._queue.get_nowait()
            self._stats["dropped"] += 1
        self._queue.put_nowait(item)

    async def get(self) -> Reception:
        item = await self._queue.get()
        if isinstance(item, BackendError):
            self.put(item)
            raise item
        return item


class ModemBackend(ABC):
    """An async modem: ``open``, ``send`` frames, ``recv`` receptions, ``close``.

    Use as ``async with Backend(setup) as modem: ...``. ``stats`` counts ``sent``, ``received``
    and ``errors`` (backends may add more keys).
    """

    name: ClassVar[str] = "abstract"
    _inbox: Inbox
    """Where a backend keeps what :meth:`_recv` returns; it hands each reception to
    :meth:`_deliver`, which puts it there unless :attr:`on_reception` takes it."""
    timed_send: ClassVar[bool] = False
    """Whether :meth:`send` honours ``at`` (a scheduled emission start)."""
    direct: ClassVar[bool] = False
    """Whether the backend's I/O bypasses the event loop: :meth:`send_now` works from any
    thread, and :attr:`on_reception` is called on the backend's own reader thread (so what
    it calls must be thread-safe). A runtime then carries a frame from a Zenoh callback to
    the wire, and from the wire to Zenoh, with no hop through its loop."""
    ranging: ClassVar[RangingMode | None] = None
    """How the modem measures ranges itself (:class:`RangingMode`), or None. Measurements go
    to :attr:`on_range`."""
    options_model: ClassVar[type[ModemOptions]] = AnyOptions
    """The backend's options (:mod:`bridge.mission.backends`), which the mission loader checks
    and :attr:`options` holds."""

    def __init__(self, setup: ModemSetup) -> None:
        self.setup = setup
        self.address = setup.address
        self.frame_bytes = setup.frame_bytes
        self.stats: dict[str, int] = {"sent": 0, "received": 0, "errors": 0}
        self.options: ModemOptions = self.parse_options(setup.options, setup.node)
        self.ack = self.options.ack
        self.tx_lead_s = self.options.tx_lead_s
        """How far ahead of :meth:`clock` a timed emission is scheduled (``timed_send``)."""
        self.on_range: Callable[[ModemRange], None] | None = None
        """Called with every range the modem measures (the runtime sets it)."""
        self.on_fix: Callable[[ModemFix], None] | None = None
        """Called with every position the modem's USBL head measures (the runtime sets it)."""
        self.on_reception: Callable[[Reception], None] | None = None
        """Called with every reception as it arrives, instead of queueing it for :meth:`recv`
        (the runtime sets it: a frame heard is decoded at once, with no task to wake in
        between); on the event loop, or on the reader thread of a :attr:`direct` backend.
        Errors still reach :meth:`recv`."""
        self._opened = False
        self._closed = False

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open" if self._opened else "new"
        return f"<{type(self).__name__} {self.setup.node}@{self.address} {state}>"

    def __str__(self) -> str:
        """How log lines and errors name it: ``micromodem modem 'auv1'``."""
        return f"{self.name} modem {self.setup.node!r}"

    @property
    def is_open(self) -> bool:
        """Opened and not yet closed."""
        return self._opened and not self._closed

    # -- public API ----------------------------------------------------------------------------

    async def open(self) -> None:
        """Connect to the modem (or water); raises :class:`BackendError` if unavailable.

        After such an error the backend has released what it held and ``open`` may be retried.
        """
        if self._closed:
            raise BackendError(f"{self!r}: cannot reopen a closed backend")
        if self._opened:
            return
        try:
            await self._open()
        except BackendError:
            self.stats["errors"] += 1
            await self._close()
            raise
        self._opened = True

    async def send(
        self, data: bytes, dest: int | None = None, *, at: float | None = None,
        ack: bool | None = None, until: float | None = None,
    ) -> bool | None:
        """Transmit one frame (``dest`` ``None`` = broadcast).

        ``ack`` asks the modem for a delivery confirmation of a unicast frame (default: the
        backend's ``ack`` option); backends without one ignore it. Returns the modem's
        confirmation: True delivered, False reported not delivered, None unknown.

        ``at`` asks for the emission to start at that time of :meth:`clock` (DLBL needs the
        exact start); backends whose ``timed_send`` is False send at once and ignore it.
        ``until``, a time of :meth:`clock` too (None: none), ends the MAC turn the frame was
        granted: no transmission of it begins from then on, neither the first try nor a retry;
        a frame too late (or due ``at`` a start not before it) is dropped, counted in
        ``stats["late"]``, and :class:`~bridge.errors.SendTooLate` raised.
        When it returns is backend-specific and documented by each backend. Raises
        :class:`BackendError` if the frame is too long or empty, or the backend is not open.
        """
        self._check_frame(data)
        try:
            ack = self.ack if ack is None else ack
            deadline = self._deadline(until)
            if at is not None and self.timed_send and until is not None and at >= until:
                raise self._too_late(f"its start is due {at - until:.3f} s after the end of "
                                     "its MAC turn")
            self._check_turn(deadline, "its first try")
            if at is not None and self.timed_send:
                confirmed = await self._send_timed(bytes(data), dest, ack, at, deadline)
            else:
                confirmed = await self._send(bytes(data), dest, ack, deadline)
        except SendTooLate:
            raise
        except BackendError:
            self.stats["errors"] += 1
            raise
        self.stats["sent"] += 1
        return confirmed

    def send_now(self, data: bytes, dest: int | None = None, *,
                 ack: bool | None = None, until: float | None = None) -> bool | None:
        """:meth:`send` without waiting, from any thread: only :attr:`direct` backends (which
        begin the transmission at once and never retry, so ``until`` is checked here only)."""
        if not self.direct:
            raise BackendError(f"{self!r}: this backend sends only from its event loop")
        self._check_frame(data)
        if until is not None and (past := self.clock() - until) >= 0:
            raise self._too_late(f"its first try would begin {past:.3f} s after the end of "
                                 "its MAC turn")
        try:
            confirmed = self._send_now(bytes(data), dest, self.ack if ack is None else ack)
        except BackendError:
            self.stats["errors"] += 1
            raise
        self.stats["sent"] += 1
        return confirmed

    def _deadline(self, until: float | None) -> float | None:
        """``until`` (a time of :meth:`clock`) as a time of the running event loop's clock,
        which the backend's timers follow (None: no end)."""
        if until is None or math.isinf(until):
            return None
        return asyncio.get_running_loop().time() + (until - self.clock())

    def _check_turn(self, deadline: float | None, what: str, need_s: float = 0.0) -> None:
        """Raise the drop (counted and logged: :meth:`_too_late`) if ``what`` (a try of the
        frame, which keeps the modem transmitting ``need_s``) would not end by ``deadline`` (the
        loop's clock; a try that needs nothing: would not begin before it)."""
        if deadline is None:
            return
        left = deadline - asyncio.get_running_loop().time()
        if left > need_s:
            return
        if left <= 0:
            raise self._too_late(f"{what} would begin {-left:.3f} s after the end of its MAC "
                                 "turn")
        raise self._too_late(f"{what} needs {need_s:.3f} s on the air, {left:.3f} s of its MAC "
                             "turn are left")

    def _too_late(self, why: str) -> SendTooLate:
        """Count and log a frame dropped because its MAC turn ended; the error to raise."""
        self.stats["late"] = self.stats.get("late", 0) + 1
        log.warning("%s: frame dropped, %s (counted in late)", self, why)
        return SendTooLate(f"{self!r}: frame dropped, {why}")

    def _check_frame(self, data: bytes) -> None:
        if not self.is_open:
            raise BackendError(f"{self!r}: send on a backend that is not open")
        if not data:
            raise BackendError(f"{self!r}: cannot send an empty frame")
        if len(data) > self.frame_bytes:
            raise BackendError(
                f"{self!r}: frame of {len(data)} B exceeds frame_bytes={self.frame_bytes}"
            )

    async def recv(self) -> Reception:
        """Wait for the next reception; raises :class:`BackendError` once the backend is down."""
        if not self.is_open:
            raise BackendError(f"{self!r}: recv on a backend that is not open")
        rx = await self._recv()
        self.stats["received"] += 1
        return rx

    async def close(self) -> None:
        """Release the modem and cancel the backend's tasks; safe to call twice."""
        if self._closed:
            return
        self._closed = True
        await self._close()

    async def ping(self, dest: int) -> ModemRange:
        """Range to ``dest`` with the modem's own ping (backends whose ``ranging`` is ``ping``).

        The range also goes to :attr:`on_range`. Raises :class:`BackendError` when the modem
        has no ping, is not open or no reply came; a missing reply leaves the backend usable.
        """
        if not self.is_open:
            raise BackendError(f"{self!r}: ping on a backend that is not open")
        rng = await self._ping(dest)
        self._report_range(rng)
        return rng

    def _deliver(self, rx: Reception) -> None:
        """A reception arrived: to :attr:`on_reception` at once, else queued for :meth:`recv`."""
        if self.on_reception is None:
            self._inbox.put(rx)
            return
        self.stats["received"] += 1
        self.on_reception(rx)

    def _report_range(self, rng: ModemRange) -> None:
        """Hand a range the modem measured to :attr:`on_range`."""
        self.stats["ranges"] = self.stats.get("ranges", 0) + 1
        if self.on_range is not None:
            self.on_range(rng)

    def _report_fix(self, fix: ModemFix) -> None:
        """Hand a USBL fix the modem measured to :attr:`on_fix`."""
        self.stats["fixes"] = self.stats.get("fixes", 0) + 1
        if self.on_fix is not None:
            self.on_fix(fix)

    async def _ping(self, dest: int) -> ModemRange:
        """Hook for backends with a ping."""
        raise BackendError(f"{self!r}: this modem has no ping")

    @classmethod
    def parse_options(cls, options: Mapping[str, Any], node: str) -> ModemOptions:
        """``options`` as :attr:`options_model`; :class:`BackendError` says what is wrong (a
        mission's are checked when it is loaded)."""
        problems = option_errors(cls.options_model, options)
        if problems:
            raise BackendError(f"{cls.name} backend of {node!r}: " + "; ".join(
                f"option {key}: {message}" if key else message for key, message in problems))
        return cls.options_model.model_validate(dict(options))

    @classmethod
    def max_frame_bytes(cls, options: Mapping[str, Any]) -> int | None:
        """The largest frame this backend can send with ``options`` (None: no fixed limit)."""
        return None

    default_broadcast: ClassVar[int | None] = None
    """The backend's own convention for the address that means every node (None: none)."""

    probe: ClassVar[bytes | None] = None
    """A harmless query a modem of this kind answers in its own protocol, as written to its
    port (``zab doctor`` asks it of a device that did not start, to tell which modem it is);
    None: none."""

    @classmethod
    def speaks(cls, line: bytes) -> bool:
        """Whether ``line``, one line a device wrote, is in this kind of modem's protocol."""
        return False

    @classmethod
    def broadcast_address(cls, options: Mapping[str, Any]) -> int | None:
        """The address that means every node: the ``broadcast`` option (the mission's
        ``modem.broadcast``), else :attr:`default_broadcast`."""
        value = options.get("broadcast")
        return cls.default_broadcast if value is None else int(value)

    @classmethod
    def setup_problems(cls, options: Mapping[str, Any], address: int) -> tuple[list[str],
                                                                               list[str]]:
        """What ``zab check`` should say of a node with ``options`` at ``address``: (errors,
        warnings). The default: a node whose address is the broadcast address is an error."""
        broadcast = cls.broadcast_address(options)
        if broadcast is not None and address == broadcast:
            return [f"address {address} is the {cls.name} broadcast address (modem.broadcast):"
                    " frames to it would go to every node"], []
        return [], []

    def _send_now(self, data: bytes, dest: int | None, ack: bool) -> bool | None:
        """Hook for :attr:`direct` backends: transmit a checked frame without waiting."""
        raise BackendError(f"{self!r}: this backend sends only from its event loop")

    async def _send_timed(self, data: bytes, dest: int | None, ack: bool, at: float,
                          deadline: float | None) -> bool | None:
        """Hook for backends with ``timed_send``: emit at ``at`` (modem clock); ``deadline`` as
        for :meth:`_send`."""
        return await self._send(data, dest, ack, deadline)

    def clock(self) -> float:
        """The modem's clock, in which it stamps receptions (default: the host's wall clock)."""
        return time.time()

    def set_position(self, x: float, y: float, depth: float) -> None:  # noqa: B027
        """Tell the backend where the vehicle is (only the simulator uses it; default no-op)."""

    async def __aenter__(self) -> ModemBackend:
        await self.open()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    # -- hooks ---------------------------------------------------------------------------------

    @abstractmethod
    async def _open(self) -> None:
        """Connect; raise :class:`BackendError` on failure."""

    @abstractmethod
    async def _send(self, data: bytes, dest: int | None, ack: bool,
                    deadline: float | None) -> bool | None:
        """Transmit a checked frame; begin no try of it from ``deadline`` on (the event
        loop's clock; None: no end): :meth:`_check_turn` raises when a try is too late."""

    @abstractmethod
    async def _recv(self) -> Reception:
        """Wait for the next reception."""

    @abstractmethod
    async def _close(self) -> None:
        """Release resources; called once, also after a failed open."""
