"""The water: an asyncio TCP server hosting a pure :class:`~bridge.sim.ocean.Ocean`.

Sim modems (:class:`bridge.modems.sim.SimBackend`) connect, say ``hello`` with their address
and position, send ``tx`` messages and receive ``txdone`` and ``rx`` messages (see
:mod:`bridge.sim.protocol`). The model runs on the event loop's monotonic clock; every time
sent to a modem is converted to wall-clock seconds. Only deliveries reach modems; losses are
counted in :meth:`WaterService.stats`. Nodes given a scripted :class:`~bridge.mission.path.Path`
follow it from the moment the service starts (:attr:`WaterService.started_at`, wall clock).
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import logging
import os
import time
from collections.abc import Callable, Mapping
from typing import Any

from bridge.errors import WaterError
from bridge.mission.path import Path
from bridge.mission.presets import Preset, get_preset
from bridge.sim.ocean import Delivery, Loss, Ocean, Position, TransmitRefused, TxDone
from bridge.sim.protocol import (
    DETECTED_LOSSES,
    PROTOCOL_VERSION,
    ProtocolError,
    pack,
    read_message,
)

__all__ = ["WaterService", "listen_problem", "serve_water"]

log = logging.getLogger(__name__)

HELLO_TIMEOUT_S = 5.0
"""A client that does not say hello within this time is dropped."""


def listen_problem(host: str, port: int, exc: BaseException) -> str:
    """Why a water cannot listen on ``host:port`` (``exc``: what binding raised), and what to
    do, in one line."""
    if isinstance(exc, OSError) and exc.errno == errno.EADDRINUSE:
        return f"{host}:{port} is already in use (is another `zab water` running?)"
    if isinstance(exc, OSError) and exc.errno is not None and exc.errno > 0:
        reason = os.strerror(exc.errno)  # (asyncio's strerror repeats the address)
    else:  # a host name unknown (its own message), a port out of range (OverflowError)
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
    return f"the water cannot listen on {host}:{port}: {reason}"


class WaterService:
    """Hosts one :class:`Ocean` and the TCP connections of the sim modems in it."""

    def __init__(
        self,
        preset: str | Preset,
        seed: int | None = 0,
        positions: Mapping[int, Position] | None = None,
        *,
        loss: float = 0.0,
        loss_curve: Callable[[float, float], float] | None = None,
        paths: Mapping[int, Path] | None = None,
    ) -> None:
        self.preset = get_preset(preset) if isinstance(preset, str) else preset
        self.ocean = Ocean(self.preset, seed, loss=loss, loss_curve=loss_curve)
        self._initial_positions: dict[int, Position] = dict(positions or {})
        self._paths: dict[int, Path] = dict(paths or {})
        self._path_start = 0.0  # loop clock when the service started
        self.started_at: float | None = None
        """Wall-clock time at which the service started, the time 0 of every path."""
        self._clients: dict[int, asyncio.StreamWriter] = {}
        self._told_losses: set[int] = set()  # modems that asked to hear of their losses
        self._pending_tx: dict[int, tuple[int, int | None]] = {}  # frame_id -> (addr, tx id)
        self._server: asyncio.Server | None = None
        self._driver: asyncio.Task[None] | None = None
        self._handlers: set[asyncio.Task[Any]] = set()
        self._wake = asyncio.Event()
        self._last = 0.0
        self._offset = 0.0  # wall clock minus loop clock
        self._counters = {
            "connections": 0,
            "rejected": 0,
            "tx": 0,
            "txerr": 0,
            "rx_sent": 0,
            "rx_no_client": 0,
            "protocol_errors": 0,
        }
        self.port: int | None = None

    # -- lifecycle -----------------------------------------------------------------------------

    async def start(self, host: str = "127.0.0.1", port: int = 0) -> int:
        """Listen on ``host:port`` (0 = any free port); returns the bound port.
        :class:`~bridge.errors.WaterError` (one line) when it cannot."""
        if self._server is not None:
            raise RuntimeError("water service already started")
        loop = asyncio.get_running_loop()
        self._offset = time.time() - loop.time()
        self._last = self._path_start = loop.time()
        self.started_at = self._wall(self._path_start)
        try:
            self._server = await asyncio.start_server(self._handle, host, port)
        except (OSError, OverflowError) as exc:
            self.started_at = None
            raise WaterError(listen_problem(host, port, exc)) from None
        self.port = self._server.sockets[0].getsockname()[1]
        self._driver = asyncio.create_task(self._drive(), name="water-driver")
        self._driver.add_done_callback(_log_crash)
        log.info("water (%s) listening on %s:%s", self.preset.name, host, self.port)
        return self.port

    async def stop(self) -> None:
        """Close every connection and stop; safe to call twice."""
        server, self._server = self._server, None
        if server is not None:
            server.close()
        for writer in list(self._clients.values()):
            writer.close()  # each handler then reads the end of its stream and returns
        if self._handlers:
            await asyncio.wait(list(self._handlers), timeout=1.0)
        tasks = [t for t in (self._driver, *self._handlers) if t is not None]
        self._driver = None
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        if server is not None:
            with contextlib.suppress(Exception):
                await server.wait_closed()

    async def __aenter__(self) -> WaterService:
        if self._server is None:
            await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()

    def stats(self) -> dict[str, Any]:
        """Per-link model statistics plus service counters, as a JSON-able dict."""
        out = self.ocean.stats()
        out["service"] = dict(self._counters)
        out["clients"] = sorted(self._clients)
        return out

    def position(self, addr: int, wall: float | None = None) -> Position:
        """Where node ``addr`` is at wall-clock time ``wall`` (default: now); ``KeyError`` if it
        is not in the water."""
        return self.ocean.position(addr, (time.time() if wall is None else wall) - self._offset)

    # -- clock ---------------------------------------------------------------------------------

    def _now(self) -> float:
        self._last = max(asyncio.get_running_loop().time(), self._last)
        return self._last

    def _wall(self, t: float) -> float:
        return t + self._offset

    async def _drive(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            self._wake.clear()
            t = self.ocean.next_event_time()
            if t is None:
                await self._wake.wait()
                continue
            delay = t - loop.time()
            if delay > 0:
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(delay):
                        await self._wake.wait()
                    continue  # something new was transmitted: recompute the next event
            self._last = max(self._last, t)
            for event in self.ocean.advance(self._now()):
                self._dispatch(event)

    def _dispatch(self, event: TxDone | Delivery | Loss) -> None:
        if isinstance(event, TxDone):
            addr, tx_id = self._pending_tx.pop(event.frame_id, (event.src, None))
            if tx_id is not None:
                self._send(addr, {"t": "txdone", "id": tx_id, "time": self._wall(event.time)})
        elif isinstance(event, Delivery):
            meta = dict(event.meta)
            for key in ("sent_at", "tx_start"):
                meta[key] = self._wall(meta[key])
            meta["start"] = self._wall(event.start)
            msg = {
                "t": "rx",
                "src": event.src,
                "data": event.data,
                "time": self._wall(event.end),
                "meta": meta,
            }
            if self._send(event.dst, msg):
                self._counters["rx_sent"] += 1
            else:
                self._counters["rx_no_client"] += 1
        elif event.dst in self._told_losses and event.reason in DETECTED_LOSSES:
            self._send(event.dst, {"t": "lost", "src": event.src, "reason": event.reason,
                                   "time": self._wall(event.time), "dest": event.dest})

    def _send(self, addr: int, msg: dict[str, Any]) -> bool:
        writer = self._clients.get(addr)
        if writer is None or writer.is_closing():
            return False
        writer.write(pack(msg))
        return True

    # -- connections ---------------------------------------------------------------------------

    async def _handle(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._handlers.add(task)
        addr: int | None = None
        try:
            addr = await self._hello(reader, writer)
            if addr is None:
                return
            while True:
                msg = await read_message(reader)
                if msg is None:
                    return
                self._on_message(addr, msg)
        except (ProtocolError, asyncio.IncompleteReadError, ConnectionError) as exc:
            self._counters["protocol_errors"] += isinstance(exc, ProtocolError)
            log.warning("water: dropping modem %s: %s", addr, exc)
        finally:
            if addr is not None and self._clients.get(addr) is writer:
                del self._clients[addr]
                self._told_losses.discard(addr)
                self.ocean.remove_node(addr)
            writer.close()
            self._handlers.discard(task)

    async def _hello(
        self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter
    ) -> int | None:
        def reject(reason: str) -> None:
            self._counters["rejected"] += 1
            writer.write(pack({"t": "error", "error": reason}))

        try:
            async with asyncio.timeout(HELLO_TIMEOUT_S):
                msg = await read_message(reader)
        except TimeoutError:
            reject("no hello received")
            return None
        if msg is None:
            return None
        addr = msg.get("addr")
        if msg.get("t") != "hello" or not isinstance(addr, int) or not 0 <= addr <= 0xFFFF:
            reject("expected hello with an integer addr in 0..65535")
            return None
        if msg.get("v", PROTOCOL_VERSION) != PROTOCOL_VERSION:
            reject(f"protocol version {msg.get('v')} unsupported (water speaks {PROTOCOL_VERSION})")
            return None
        if addr in self._clients:
            reject(f"modem address {addr} is already in the water")
            return None
        pos = msg.get("pos")
        try:
            position = _as_position(pos) if pos is not None else None
        except (TypeError, ValueError):
            reject(f"bad position {pos!r}")
            return None
        if position is None:
            position = self._initial_positions.get(addr, (0.0, 0.0, 0.0))
        self._clients[addr] = writer
        if msg.get("losses"):
            self._told_losses.add(addr)
        self.ocean.add_node(addr, position)
        if addr in self._paths:
            self.ocean.set_path(addr, self._paths[addr], self._path_start)
            position = self.ocean.position(addr, self._now())  # (where its path has it)
        self._counters["connections"] += 1
        writer.write(
            pack(
                {"t": "welcome", "preset": self.preset.name, "frame_bytes": self.preset.frame_bytes}
            )
        )
        log.info("water: modem %s (%s) at %s", addr, msg.get("name", "?"), position)
        return addr

    def _on_message(self, addr: int, msg: dict[str, Any]) -> None:
        kind = msg["t"]
        if kind == "tx":
            tx_id = msg.get("id")
            data = msg.get("data")
            dest = msg.get("dest")
            if not isinstance(data, bytes) or not (dest is None or isinstance(dest, int)):
                raise ProtocolError("tx needs bytes 'data' and an int or nil 'dest'")
            at = msg.get("at")
            if isinstance(at, int | float):  # a timed emission
                late = time.time() - at
                if late > 0:  # as a timed modem does (EvoLogics' EXPIREDIMS): never sent
                    self._counters["txerr"] += 1
                    self._send(addr, {"t": "txerr", "id": tx_id, "reason": "expired",
                                      "error": f"expired: asked to start {late * 1000:.1f} ms ago"})
                    return
                loop = asyncio.get_running_loop()
                loop.call_later(-late, self._on_message, addr,
                                {**msg, "at": None, "start": at - self._offset})
                return
            start = msg.get("start")
            now = self._now() if start is None else max(float(start), self.ocean.now)
            try:
                self.ocean.transmit(now, addr, data, dest)
            except TransmitRefused as exc:
                self._counters["txerr"] += 1
                self._send(
                    addr, {"t": "txerr", "id": tx_id, "reason": exc.reason, "error": str(exc)}
                )
                return
            self._counters["tx"] += 1
            self._pending_tx[self.ocean.last_frame_id] = (addr, tx_id)
            self._wake.set()
        elif kind == "pos":
            try:
                self.ocean.set_position(addr, _as_position(msg.get("pos")),
                                        max(self._now(), self.ocean.now))
            except (TypeError, ValueError) as exc:
                raise ProtocolError(f"bad position {msg.get('pos')!r}") from exc
        else:
            raise ProtocolError(f"unknown message type {kind!r}")


def _log_crash(task: asyncio.Task[None]) -> None:
    if not task.cancelled() and task.exception() is not None:
        log.error("water driver crashed", exc_info=task.exception())


def _as_position(pos: Any) -> Position:
    x, y, z = (float(v) for v in pos)
    return (x, y, z)


async def serve_water(
    preset: str | Preset,
    seed: int | None,
    positions: Mapping[int, Position] | None,
    host: str = "127.0.0.1",
    port: int = 0,
    ready: Callable[[int], None] | None = None,
    *,
    loss: float = 0.0,
    paths: Mapping[int, Path] | None = None,
) -> None:
    """Run a water service until cancelled (for a standalone ``zab water``).

    ``ready`` is called with the bound port once it listens.
    """
    service = WaterService(preset, seed, positions, loss=loss, paths=paths)
    port = await service.start(host, port)
    try:
        if ready is not None:
            ready(port)
        await asyncio.Future()
    finally:
        await service.stop()
