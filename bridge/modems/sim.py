"""``sim``: a simulated modem connected to the water service (:mod:`bridge.sim.service`).

Options: the table at the end. ``water``, the ``"host:port"`` of the water, is required (``zab sim``
gives its own); ``broadcast`` (the mission's ``modem.broadcast``) is the address a frame for
every node carries in the water, and that marks a frame heard as one (without it the water
carries no address for them); ``seed`` and ``loss`` are the water's random seed and the share
of frames it loses at random (``zab sim``, ``zab water``; ``zab check`` refuses other values);
``rx_queue`` receptions are kept while nobody calls ``recv`` (the oldest are dropped and
counted in ``stats["dropped"]``); each frame's start is scheduled ``tx_lead_s`` ahead. Like a
timed modem, the water refuses a frame whose start has passed when it arrives ("expired"), so
DLBL delays are never stamped for a start that did not happen; a loaded host is easily 10 ms
late.

A caller that sets :attr:`SimBackend.on_loss` before ``open`` also hears of the frames the
water lost at this modem after their signal reached it (``on_loss(src, reason, dest)``): an
emulated modem prints them as its CRC failures.

``send`` returns when the water reports the transmission DONE (the modem is free again), so it
takes the frame's airtime plus the preset's intrinsic delay. A frame that waited behind another
until its MAC turn ended (``until``) is dropped, never handed to the water (counted in
``stats["late"]``); the water does not retry.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import random
import time
from collections.abc import Callable, Mapping
from typing import Any, ClassVar

from bridge.errors import BackendError
from bridge.mission.backends import ModemOptions, SimOptions
from bridge.mission.network import water_address
from bridge.modems.base import Inbox, ModemBackend, ModemSetup, Reception
from bridge.sim.protocol import PROTOCOL_VERSION, ProtocolError, pack, read_message

__all__ = ["SimBackend", "parse_water_address", "water_options"]



def parse_water_address(value: Any) -> tuple[str, int]:
    """``"host:port"`` (or a bare port number, meaning 127.0.0.1) -> ``(host, port)``
    (:func:`bridge.mission.network.water_address`, which a mission's are checked with)."""
    address = water_address(value)
    if address is None:
        raise BackendError(f"sim backend: option 'water' must be 'host:port', got {value!r}")
    return address


def water_options(options: Mapping[str, Any]) -> dict[str, Any]:
    """The options of another backend's node that its emulated modem's :class:`SimBackend`
    takes (those a sim modem has), without ``broadcast`` (an emulator's water carries none)."""
    return {k: v for k, v in options.items() if k in SimOptions.model_fields and k != "broadcast"}


CLOCK_EPOCH = 1.7e9  # drift is counted from here, so clock readings stay near wall time


class SimBackend(ModemBackend):
    """A modem in the simulated water, reached over loopback TCP."""

    name: ClassVar[str] = "sim"
    options_model: ClassVar[type[ModemOptions]] = SimOptions
    options: SimOptions
    timed_send: ClassVar[bool] = True

    def __init__(self, setup: ModemSetup) -> None:
        super().__init__(setup)
        opts = self.options
        if opts.water is None:
            raise BackendError(
                f"sim backend of {setup.node!r}: option 'water' (host:port of `zab water`) "
                "is required"
            )
        self.water = parse_water_address(opts.water)
        self._timeout = opts.connect_timeout
        self._rx_size = opts.rx_queue
        self._inbox = Inbox(self.stats, self._rx_size)
        self._position = setup.position
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None
        self._task: asyncio.Task[None] | None = None
        self._pending: dict[int, asyncio.Future[float]] = {}
        self._ids = itertools.count(1)
        self._lock = asyncio.Lock()
        self._failure: BackendError | None = None
        self.preset_name: str | None = None
        self._clock_offset = opts.clock_offset_s
        self._clock_drift = opts.clock_drift_ppm * 1e-6
        self._stamp_jitter = opts.timestamp_jitter_s
        self._stamp_rng = random.Random(f"{opts.seed}/{setup.address}")
        self.broadcast = self.broadcast_address(setup.options)
        self.on_loss: Callable[[int, str, Any], None] | None = None
        """Told of each frame lost here after its signal arrived: ``(src, reason, dest)``."""

    # -- hooks ---------------------------------------------------------------------------------

    async def _open(self) -> None:
        host, port = self.water
        self._failure = None  # open may be retried after a failure
        self._inbox = Inbox(self.stats, self._rx_size)
        where = f"the water at {host}:{port}"
        try:
            # (asyncio.timeout, not wait_for: on Python 3.11 wait_for returns a result that lands
            # with a cancellation, and a fleet stopped while its modems greeted the water hung)
            async with asyncio.timeout(self._timeout):
                self._reader, self._writer = await asyncio.open_connection(host, port)
        except (OSError, TimeoutError) as exc:
            raise BackendError(
                f"sim modem {self.setup.node!r}: cannot reach {where} ({exc or 'timeout'}); "
                "is `zab water` running?"
            ) from None
        self._write(
            {
                "t": "hello",
                "v": PROTOCOL_VERSION,
                "addr": self.address,
                "name": self.setup.node,
                "pos": list(self._position) if self._position is not None else None,
                "losses": self.on_loss is not None,
            }
        )
        try:
            assert self._reader is not None  # (connected just above)
            async with asyncio.timeout(self._timeout):
                msg = await read_message(self._reader)
        except (OSError, TimeoutError, ProtocolError, asyncio.IncompleteReadError) as exc:
            raise BackendError(
                f"sim modem {self.setup.node!r}: no welcome from {where}: {exc or 'timeout'}"
            ) from None
        if msg is None or msg.get("t") != "welcome":
            reason = msg.get("error", msg) if msg else "connection closed"
            raise BackendError(f"sim modem {self.setup.node!r}: {where} refused: {reason}")
        self.preset_name = msg.get("preset")
        water_max = msg.get("frame_bytes")
        if isinstance(water_max, int) and water_max < self.frame_bytes:
            self.frame_bytes = water_max
        self._task = asyncio.create_task(self._read_loop(), name=f"sim-modem-{self.address}")

    async def _send(self, data: bytes, dest: int | None, ack: bool,
                    deadline: float | None) -> None:
        """Transmit now (the simulated water has no acknowledgements: ``ack`` is ignored)."""
        await self._transmit({"data": data, "dest": self.broadcast if dest is None else dest},
                             deadline)

    async def _send_timed(self, data: bytes, dest: int | None, ack: bool, at: float,
                          deadline: float | None) -> None:
        await self._transmit({"data": data, "dest": self.broadcast if dest is None else dest,
                              "at": self._wall(at)}, deadline)

    async def _transmit(self, request: dict[str, Any], deadline: float | None) -> None:
        async with self._lock:  # (behind a frame still on the air: the turn may end meanwhile)
            if self._failure is not None:
                raise self._failure
            self._check_turn(deadline, "its transmission")
            tx_id = next(self._ids)
            fut: asyncio.Future[float] = asyncio.get_running_loop().create_future()
            self._pending[tx_id] = fut
            try:
                self._write({"t": "tx", "id": tx_id, **request})
                await fut
            finally:
                self._pending.pop(tx_id, None)

    async def _recv(self) -> Reception:
        return await self._inbox.get()

    async def _close(self) -> None:
        self._fail(BackendError(f"sim modem {self.setup.node!r} is closed"))
        task, self._task = self._task, None
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        writer, self._writer = self._writer, None
        if writer is not None:
            writer.close()
            with contextlib.suppress(Exception):
                await writer.wait_closed()

    def set_position(self, x: float, y: float, depth: float) -> None:
        """Move this modem in the water (takes effect for the next frames)."""
        self._position = (float(x), float(y), float(depth))
        if self.is_open and self._failure is None:
            with contextlib.suppress(BackendError):  # a dead link shows up in send/recv
                self._write({"t": "pos", "pos": list(self._position)})

    # -- internals -----------------------------------------------------------------------------

    def _write(self, msg: dict[str, Any]) -> None:
        writer = self._writer
        if writer is None or writer.is_closing():
            raise self._failure or BackendError(f"sim modem {self.setup.node!r}: not connected")
        writer.write(pack(msg))

    def _fail(self, error: BackendError) -> None:
        """Enter the failed state once: wake every waiter with ``error``."""
        if self._failure is not None:
            return
        self._failure = error
        for fut in self._pending.values():
            if not fut.done():
                fut.set_exception(error)
        self._inbox.put(error)

    async def _read_loop(self) -> None:
        assert self._reader is not None
        where = f"{self.water[0]}:{self.water[1]}"
        try:
            while True:
                msg = await read_message(self._reader)
                if msg is None:
                    raise BackendError(
                        f"sim modem {self.setup.node!r}: the water at {where} closed the connection"
                    )
                self._on_message(msg)
        except asyncio.CancelledError:
            raise
        except BackendError as exc:
            self.stats["errors"] += 1
            self._fail(exc)
        except (OSError, ProtocolError, asyncio.IncompleteReadError) as exc:
            self.stats["errors"] += 1
            self._fail(
                BackendError(f"sim modem {self.setup.node!r}: lost the water at {where}: {exc}")
            )

    def clock(self) -> float:
        """This simulated modem's clock: wall time with the node's offset and drift."""
        return self._local(time.time())

    def _local(self, wall: float) -> float:
        return wall + self._clock_offset + self._clock_drift * (wall - CLOCK_EPOCH)

    def _wall(self, local: float) -> float:
        """Inverse of :meth:`_local`."""
        return (local - self._clock_offset + self._clock_drift * CLOCK_EPOCH) / (
            1 + self._clock_drift)

    def _stamp(self, wall: float) -> float:
        """A reception timestamp as this modem takes it: its clock, plus jitter."""
        jitter = self._stamp_rng.gauss(0.0, self._stamp_jitter) if self._stamp_jitter else 0.0
        return self._local(wall) + jitter

    def _on_message(self, msg: dict[str, Any]) -> None:
        kind = msg["t"]
        if kind == "rx":
            meta = dict(msg.get("meta") or {})
            if self.broadcast is not None and meta.get("dest") == self.broadcast:
                meta["dest"] = None  # a frame for every node
            end = float(msg["time"])
            if "start" in meta:
                meta["start"] = self._stamp(float(meta["start"]))
                end = meta["start"] + (end - float(msg["meta"]["start"]))
            else:
                end = self._stamp(end)
            self._deliver(Reception(data=bytes(msg["data"]), src=int(msg["src"]), time=end,
                                meta=meta))
        elif kind == "lost":
            if self.on_loss is not None:
                self.on_loss(int(msg["src"]), str(msg.get("reason")), msg.get("dest"))
        elif kind in ("txdone", "txerr"):
            fut = self._pending.get(msg.get("id", -1))
            if fut is None or fut.done():
                return
            if kind == "txdone":
                fut.set_result(float(msg["time"]))
            else:
                why = msg.get("error")
                error = BackendError(
                    f"sim modem {self.setup.node!r}: water refused the frame: {why}"
                )
                fut.set_exception(error)
        elif kind == "error":
            raise BackendError(f"sim modem {self.setup.node!r}: water error: {msg.get('error')}")
        else:
            raise ProtocolError(f"unknown message type {kind!r}")
