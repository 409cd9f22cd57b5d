"""One link of a bridge node at run time: its modem backend, the loop that reads it and the
loop that sends at the core's opportunities on it (asyncio).

A :class:`~bridge.runtime.zenoh_node.BridgeNode` has one port per link of its node: one in a
mission without ``links``, one per modem otherwise (seed 002's generic link layer: an acoustic
modem and an RF modem, each under its MAC). Every port drives the one core through its link's
name, holding the node's lock: the transmit loop sleeps until the core's MAC on that link has
an opportunity (new data or a frame heard on any link wakes it to ask again) and carries out
what the core says; the modem loop opens the modem (again, with backoff, when it fails) and
hands each frame heard to the core as heard on that link.

With a :attr:`~bridge.modems.base.ModemBackend.direct` backend (``udp``) and one link, the
data path skips the loop: the Zenoh callback ingests a sample and, when an opportunity is
open, the frame leaves from that thread (:meth:`LinkPort.ingest_now`).
"""

from __future__ import annotations

import asyncio
import logging
import math
import threading
from collections.abc import Callable
from typing import Any, Protocol

from bridge.core.events import Event
from bridge.core.modem_outage import ModemOutage
from bridge.core.node import NodeCore, Ping, SendFrame
from bridge.core.reception import RangingMode
from bridge.errors import BackendError, SendTooLate
from bridge.modems.base import ModemBackend, ModemFix, ModemRange, Reception
from bridge.runtime.eager import start_eagerly
from bridge.runtime.intake import Intake

__all__ = ["InputSample", "LinkPort", "ingest_sample", "modem_start", "modem_until"]

log = logging.getLogger("zab.node")

RETRY_MIN_S, RETRY_MAX_S = 0.5, 10.0

InputSample = tuple[str, bytes, str, "str | None", "str | None", "bytes | None", "float | None"]
"""A sample for the core's ingest: key, payload, encoding, ref, the sample's own key, its
attachment and its own timestamp (seconds since the epoch), if any."""


def ingest_sample(core: NodeCore, sample: InputSample, now: float) -> None:
    """The core takes ``sample`` at ``now``."""
    key, data, encoding, ref, sample_key, attachment, taken = sample
    core.ingest(key, data, encoding, now, ref, sample_key, attachment, taken)


def modem_start(backend: ModemBackend) -> float:
    """The modem time a frame handed to ``backend`` now starts at: with a timed modem the
    emission starts exactly then, so DLBL delays are exact."""
    return backend.clock() + (backend.tx_lead_s if backend.timed_send else 0.0)


def modem_until(backend: ModemBackend, until: float, now: float) -> float | None:
    """A :class:`~bridge.core.node.SendFrame`'s ``until``, on the node's clock whose time is
    ``now``, as a time of ``backend``'s clock, which its ``send`` takes (None: no end). The
    node's clock runs at the loop's pace (the transmit loop sleeps ``wake - now`` seconds of
    it), whatever its origin: a time is carried across as the same distance from now."""
    if math.isinf(until):
        return None
    return backend.clock() + (until - now)


class Host(Protocol):
    """What a port needs of its node (:class:`~bridge.runtime.zenoh_node.BridgeNode`)."""

    core: NodeCore
    node: str
    lock: threading.RLock
    clock: Callable[[], float]
    intake: Intake | None

    def _flush(self) -> None: ...

    def _persist(self) -> None: ...

    def settle_soon(self) -> None: ...

    def _event(self, event: Event) -> None: ...

    def _soon(self, callback: Callable[..., object], *args: Any) -> None: ...

    def wake_if_sooner(self, now: float) -> None: ...


class LinkPort:
    """One modem of a node, and the loops that drive it."""

    def __init__(self, host: Host, link: str | None, make_backend: Callable[[], ModemBackend],
                 primary: bool = True) -> None:
        """``link``: the core's name of the link (None: the node's only one); ``primary``: its
        modem ranges (the node's first link)."""
        self.host = host
        self.link = link
        self.primary = primary
        self.make_backend = make_backend
        self.backend: ModemBackend | None = None
        self.data = asyncio.Event()
        """Set when the core may have something new to send on this link."""
        self.modem_up = asyncio.Event()
        self.outage = ModemOutage()
        self.sending = False
        self.planned: float | None = None  # when the transmit loop wakes by itself
        self.name = host.node if link is None else f"{host.node}/{link}"

    def wake(self) -> None:
        """The transmit loop asks the core again (from any thread)."""
        self.host._soon(self.data.set)

    def direct(self) -> ModemBackend | None:
        """The open backend, if it is direct and sends what the core gives it at once (a
        modem that pings must be awaited)."""
        backend = self.backend
        if backend is None or not backend.direct or backend.ranging is RangingMode.PING:
            return None
        return backend

    def ingest(self, backend: ModemBackend | None, sample: InputSample) -> None:
        """A sample for the core, on any thread: with a ``backend`` (:meth:`direct`) an open
        opportunity's frame leaves from here, else from the loop."""
        host = self.host
        with host.lock:
            ready = not self.sending and self.modem_up.is_set()
            if ready and backend is not None:  # (its outputs and the frame's, flushed together)
                self._send_now(backend, sample)
                return
            now = host.clock()
            ingest_sample(host.core, sample, now)
            wake = host.core.wake_at(now, self.link) if ready else None
            if wake is None or wake > now + 1e-9:  # the transmit loop decides when, after the
                host.settle_soon()  # outputs of every sample taken until the loop's turn
                return
            host._flush()
        host._soon(self._transmit_eagerly)

    def _transmit_eagerly(self) -> None:
        """On the loop: an opportunity open now, the frame leaves from here."""
        start_eagerly(self.transmit())

    # -- core -> modem -------------------------------------------------------------------------

    async def transmit_loop(self) -> None:
        """Sleep until the core's MAC on this link has an opportunity (new data or a frame
        heard wakes it to ask again), then carry out what the core says to do there."""
        host = self.host
        while True:
            await self.modem_up.wait()
            self.data.clear()
            with host.lock:
                sending = self.sending
                now = host.clock()
                wake = self.planned = None if sending else host.core.wake_at(now, self.link)
            if sending:  # one in flight (from the ingest path): it wakes us after
                await self._wait_for_data(None)
                continue
            if wake is None or wake > now:
                await self._wait_for_data(None if wake is None else wake - now)
                continue
            if not await self.transmit():
                # nothing went out (the core then waits for news or IDLE_S before the next
                # opportunity): whatever it says next, never a loop that does not yield
                await asyncio.sleep(0)

    async def _wait_for_data(self, timeout: float | None) -> None:
        """Until new data or a frame sets :attr:`data`, or ``timeout`` seconds pass (a timer
        on the loop: no task per wait, as ``asyncio.wait_for`` would make)."""
        timer = None if timeout is None else \
            asyncio.get_running_loop().call_later(timeout, self.data.set)
        try:
            await self.data.wait()
        finally:
            if timer is not None:
                timer.cancel()

    async def transmit(self) -> bool:
        """Carry out the core's action at an open opportunity: send its frame, or ping.
        Returns whether something went out. One at a time: the transmit loop and the ingest
        path both come here."""
        backend = self.backend
        with self.host.lock:
            if backend is None or self.sending:
                return False
            self.sending = True
        try:
            return await self._transmit(backend)
        finally:
            self.sending = False
            # the transmit loop looks again (what is due changed), behind the I/O already
            # waiting: a frame this send put on a local link is heard first
            asyncio.get_running_loop().call_soon(self.data.set)

    async def _transmit(self, backend: ModemBackend) -> bool:
        host = self.host
        with host.lock:
            action, now = self._act(backend)
            if action is None:
                return False
        confirmed = None
        try:
            if isinstance(action, Ping):
                await backend.ping(action.peer)
            else:
                out = action.frame
                until = modem_until(backend, action.until, host.clock())
                confirmed = await backend.send(out.data, out.dest, at=out.at, ack=out.ack,
                                               until=until)
        except BackendError as exc:
            with host.lock:
                self._failed(backend, action, now, exc)
            return False
        with host.lock:
            host.core.done(action, now, host.clock(), confirmed=confirmed)
            host._flush()
        return True

    def _act(self, backend: ModemBackend, sample: InputSample | None = None
             ) -> tuple[Ping | SendFrame | None, float]:
        """Ask the core what to do at this opportunity (holding the lock), once it has taken
        ``sample`` if one just came; a frame's counter is saved before it leaves."""
        host = self.host
        core = host.core
        if self.primary:
            core.modem_ranging = backend.ranging
        now, at = host.clock(), modem_start(backend)
        if sample is not None:
            ingest_sample(core, sample, now)
        action = core.act(now, at, self.link)
        if action is None:
            if sample is None:
                host._flush()
            else:  # (a burst of samples: one flush, on the loop)
                host.settle_soon()
        else:
            host._persist()
        return action, now

    def _send_now(self, backend: ModemBackend, sample: InputSample) -> None:
        """Holding the lock, on any thread: the core takes ``sample`` and its action is
        carried out through a direct backend, which does not wait."""
        host = self.host
        action, now = self._act(backend, sample)
        if action is not None:
            assert isinstance(action, SendFrame)  # a direct backend has no ping
            out = action.frame
            try:
                confirmed = backend.send_now(out.data, out.dest, ack=out.ack,
                                             until=modem_until(backend, action.until, now))
            except BackendError as exc:
                self._failed(backend, action, now, exc)
                return
            end = host.clock()
            host.core.done(action, now, end, confirmed=confirmed)
            host._flush()
            now = end
        self.wake_if_sooner(now)

    def _failed(self, backend: ModemBackend, action: Ping | SendFrame, start: float,
                error: BackendError) -> None:
        """Holding the lock: the modem refused ``action``; if the modem is gone, wait until
        the modem loop reopens it."""
        host = self.host
        what = "ping" if isinstance(action, Ping) else "send"
        # (a frame whose MAC turn ended: a drop the backend counted and logged already)
        level = logging.INFO if isinstance(error, SendTooLate) else logging.WARNING
        log.log(level, "%s: %s failed: %s", self.name, what, error)
        host.core.done(action, start, host.clock(), error=str(error))
        host._flush()
        if not backend.is_open:
            host._soon(self.modem_up.clear)

    def wake_if_sooner(self, now: float) -> None:
        """Holding the lock: wake the transmit loop if the core's next opportunity on this
        link comes before the loop would wake by itself."""
        wake = self.host.core.wake_at(now, self.link)
        if wake is not None and (self.planned is None or wake < self.planned):
            self.wake()

    # -- modem -> core -------------------------------------------------------------------------

    def _modem_range(self, rng: ModemRange) -> None:
        """The modem measured a range (called by the backend, on the loop)."""
        host = self.host
        with host.lock:
            host.core.modem_range(rng, host.clock())
            host._flush()

    def _modem_fix(self, fix: ModemFix) -> None:
        """The modem's USBL head located a peer (called by the backend, on the loop)."""
        host = self.host
        with host.lock:
            host.core.modem_fix(fix, host.clock())
            host._flush()

    async def modem_loop(self) -> None:
        """Open the modem, read receptions; on failure, open a fresh one with backoff (an
        outage is one ``modem_down`` event, and one ``modem_up`` when it ends)."""
        host = self.host
        backoff = RETRY_MIN_S
        while True:
            backend = self.backend = self.make_backend()
            backend.on_range = self._modem_range
            backend.on_fix = self._modem_fix
            backend.on_reception = self._on_reception  # at once, as the frame arrives
            try:
                await backend.open()
                self.modem_up.set()
                backoff = RETRY_MIN_S
                up = self.outage.opened(host.clock())
                if up is not None:
                    log.info("%s: modem back after %.1f s (%d retries)", self.name,
                             up.down_s, up.retries)
                    host._event(up)
                while True:  # what came before on_reception took over, then its errors
                    self.receive(await backend.recv())
            except BackendError as exc:
                self.modem_up.clear()
                log.warning("%s: modem unavailable: %s (retry in %.1f s)", self.name, exc,
                            backoff)
                down = self.outage.failed(str(exc), host.clock())
                if down is not None:
                    host._event(down)
                await backend.close()
                await asyncio.sleep(backoff)
                backoff = min(backoff * 2, RETRY_MAX_S)

    def _on_reception(self, rx: Reception) -> None:
        """:meth:`receive` for the modem's reader: a frame whose handling raises (it never
        should) is counted and logged, and the reader goes on."""
        try:
            self.receive(rx)
        except Exception:
            if self.host.intake is None:
                raise
            self.host.intake.failed("(modem)")

    def receive(self, rx: Reception) -> None:
        """Hand one received frame to the core and publish what it produced (any thread:
        a direct backend calls it from its reader)."""
        host = self.host
        modem_now = self.backend.clock() if self.backend is not None else None
        with host.lock:
            valid = host.core.stats.frames_received
            host.core.receive(rx, host.clock(), modem_now, self.link)
            host._flush()
            if host.core.stats.frames_received > valid:
                # a poll, a ranging turn or a frame to carry on may open an opportunity
                host.wake_if_sooner(host.clock())

    async def close(self) -> None:
        if self.backend is not None:
            await self.backend.close()
