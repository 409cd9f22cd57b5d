"""An async byte stream to a modem through pyserial (serial device or any pyserial URL).

Shared by the real-modem backends. A serial path (``/dev/ttyUSB0``, a pty) or a pyserial URL
(``socket://127.0.0.1:9200`` for a modem's TCP port, ``loop://`` in tests) is opened with
:func:`serial.serial_for_url`. One reader thread per open transport polls the port with a short
timeout and hands chunks to the event loop, so the loop never blocks; :meth:`ByteTransport.close`
stops and joins that thread. A serial device is opened exclusively: a second opener (``zab
doctor`` beside a running bridge) gets "port busy". Every failure is a
:class:`~bridge.errors.BackendError`.
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
from typing import Any

import serial

from bridge.errors import BackendError

__all__ = ["READ_POLL_S", "WRITE_TIMEOUT_S", "ByteTransport"]

READ_POLL_S = 0.05
"""Read timeout of the reader thread: how quickly it notices ``close``."""

WRITE_TIMEOUT_S = 5.0
"""A write that the port does not accept within this time fails (a wedged device)."""

READ_CHUNK = 4096


class ByteTransport:
    """Async byte stream to a modem through pyserial: a serial device path, or any pyserial URL
    (``socket://127.0.0.1:9200`` for a modem's TCP port)."""

    def __init__(self, url: str, baudrate: int = 19200, *, name: str = "") -> None:
        self.url = url
        self.baudrate = int(baudrate)
        self.name = name or url
        self._serial: Any = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._queue: asyncio.Queue[bytes | BackendError] | None = None
        self._failure: BackendError | None = None
        self._write_lock = asyncio.Lock()

    def __repr__(self) -> str:
        return f"<ByteTransport {self.name} {'open' if self.is_open else 'closed'}>"

    @property
    def is_open(self) -> bool:
        """Opened, not closed, and the port has not failed."""
        return self._serial is not None and self._failure is None

    async def open(self) -> None:
        """Open the port; :class:`BackendError` if it is absent or cannot be opened."""
        if self._serial is not None:
            return
        loop = asyncio.get_running_loop()
        try:
            port = await loop.run_in_executor(None, self._open_blocking)
        except (serial.SerialException, OSError, ValueError) as exc:
            if "exclusively lock" in str(exc):  # pyserial's words when the flock is taken
                raise BackendError(
                    f"{self.name}: port {self.url} busy: another program (a running `zab run`, "
                    "a terminal) has it open"
                ) from None
            raise BackendError(
                f"{self.name}: port {self.url} absent or unusable ({_reason(exc)})"
            ) from None
        self._serial = port
        self._failure = None
        self._stop.clear()
        self._queue = asyncio.Queue()
        self._thread = threading.Thread(
            target=self._read_thread, args=(loop, port), name=f"serial-rx {self.name}", daemon=True
        )
        self._thread.start()

    def _open_blocking(self) -> Any:
        """Open the port exclusively (an ``flock`` on a serial device), so that a second
        opener is refused instead of sharing the modem's line."""
        return serial.serial_for_url(
            self.url,
            baudrate=self.baudrate,
            timeout=READ_POLL_S,
            write_timeout=WRITE_TIMEOUT_S,
            exclusive=True,
        )

    async def read(self) -> bytes:
        """Wait for at least one byte; :class:`BackendError` once the port is closed or lost."""
        queue = self._queue
        if queue is None:
            raise self._failure or BackendError(f"{self.name}: port {self.url} is not open")
        item = await queue.get()
        if isinstance(item, BackendError):
            queue.put_nowait(item)  # every later read fails the same way
            raise item
        chunks = [item]
        while not queue.empty():  # coalesce what is already waiting
            more = queue.get_nowait()
            if isinstance(more, BackendError):
                queue.put_nowait(more)
                break
            chunks.append(more)
        return b"".join(chunks)

    async def write(self, data: bytes) -> None:
        """Write all of ``data``; :class:`BackendError` if the port is closed or fails."""
        async with self._write_lock:
            port = self._serial
            if port is None or self._failure is not None:
                raise self._failure or BackendError(f"{self.name}: port {self.url} is not open")
            try:
                await asyncio.get_running_loop().run_in_executor(None, port.write, bytes(data))
            except (serial.SerialException, OSError, ValueError, AttributeError, TypeError) as exc:
                # AttributeError/TypeError: pyserial internals after a concurrent close
                error = BackendError(f"{self.name}: write to {self.url} failed ({_reason(exc)})")
                self._set_failure(error)
                raise error from None

    async def close(self) -> None:
        """Close the port and end the reader thread; a pending read fails. Idempotent."""
        port, self._serial = self._serial, None
        if port is None:
            return
        self._set_failure(BackendError(f"{self.name}: port {self.url} was closed"))
        self._stop.set()
        with contextlib.suppress(Exception):
            port.cancel_read()  # wakes a posix read blocked in select
        thread, self._thread = self._thread, None
        if thread is not None:
            await asyncio.get_running_loop().run_in_executor(None, thread.join, 2.0)
        with contextlib.suppress(Exception):
            port.close()

    # -- internals -----------------------------------------------------------------------------

    def _set_failure(self, error: BackendError) -> None:
        if self._failure is not None:
            return
        self._failure = error
        if self._queue is not None:
            self._queue.put_nowait(error)

    def _read_thread(self, loop: asyncio.AbstractEventLoop, port: Any) -> None:
        """Reader thread: poll the port, hand chunks (or the failure) to the loop."""
        while not self._stop.is_set():
            try:
                data = port.read(max(1, min(READ_CHUNK, port.in_waiting)))
            except Exception as exc:  # SerialException, OSError, or a port closed under us
                if self._stop.is_set():
                    return
                error = BackendError(f"{self.name}: lost port {self.url} ({_reason(exc)})")
                self._post(loop, error)
                return
            if data:
                self._post(loop, data)

    def _post(self, loop: asyncio.AbstractEventLoop, item: bytes | BackendError) -> None:
        def deliver() -> None:
            if isinstance(item, BackendError):
                self._set_failure(item)
            elif self._queue is not None and self._failure is None:
                self._queue.put_nowait(item)

        with contextlib.suppress(RuntimeError):  # the loop is already closed
            loop.call_soon_threadsafe(deliver)


def _reason(exc: BaseException) -> str:
    return str(exc) or type(exc).__name__
