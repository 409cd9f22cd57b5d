"""The host side of an emulated modem: a pseudo-terminal (or a TCP port) that a driver opens.

:class:`PtyHost` opens a pty pair. The driver opens the *slave* path with pyserial exactly as it
would open ``/dev/ttyUSB0``; the emulator reads and writes the *master* on the event loop
(``add_reader``/``add_writer``, never blocking). The host keeps its own handle on the slave so that
a driver closing and reopening the port does not end the pty. :meth:`PtyHost.unplug` closes the
pair (the driver's reads fail, the path and the ``link`` disappear) and :meth:`PtyHost.replug`
opens a fresh one behind the same ``link``: an unplugged and replugged USB cable.

:class:`TcpHost` has the same callback shape for a modem's TCP port (EvoLogics listens on 9200):
one client at a time, a newer connection replaces the older one.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import os
import pty
import tty
from collections.abc import Callable
from pathlib import Path

from bridge.errors import BackendError

__all__ = ["MAX_PENDING_OUTPUT", "PtyHost", "TcpHost"]

MAX_PENDING_OUTPUT = 1 << 20
"""Bytes kept for a host that does not read (a closed port); older output beyond this is dropped,
as a real modem's UART would lose it."""


class PtyHost:
    """The host side of an emulated modem on a pseudo-terminal: opens a pty pair, exposes the
    slave path (optionally also as a stable symlink ``link``), hands bytes written by the host to
    ``on_data``, and writes bytes back. Can close and reopen the pty (an unplugged/replugged
    cable)."""

    def __init__(self, on_data: Callable[[bytes], None], *, link: Path | None = None) -> None:
        self.on_data = on_data
        self.link = Path(link) if link is not None else None
        self.path: str | None = None
        self.dropped = 0
        self._master: int | None = None
        self._slave: int | None = None
        self._out = bytearray()
        self._writing = False
        self._loop: asyncio.AbstractEventLoop | None = None

    @property
    def is_open(self) -> bool:
        return self._master is not None

    @property
    def device(self) -> str | None:
        """What a driver should open: the link if there is one, else the slave path."""
        if self.path is None:
            return None
        return str(self.link) if self.link is not None else self.path

    async def open(self) -> str:
        """Open the pty pair (no-op if open); returns the slave device path (or the link).

        The link is pointed at the new pty in one step (it never goes missing), replacing a
        symlink already there: an emulator opens its pty last, once it is up (joined the
        water), so one that cannot start leaves a running emulator's link alone.
        :class:`BackendError` if ``link`` is something else than a symlink."""
        if self._master is not None:
            assert self.device is not None
            return self.device
        self._loop = asyncio.get_running_loop()
        master, slave = pty.openpty()
        try:
            tty.setraw(slave)  # no echo, no CR/LF translation: a plain 8-bit line
            os.set_blocking(master, False)
            path = os.ttyname(slave)
            if self.link is not None:
                _point(self.link, path)
            self.path = path
        except BaseException:
            os.close(master)
            os.close(slave)
            raise
        self._master, self._slave = master, slave
        self._loop.add_reader(master, self._readable)
        assert self.device is not None
        return self.device

    def write(self, data: bytes) -> None:
        """Queue ``data`` for the host (returns at once; written as the pty accepts it)."""
        if self._master is None or not data:
            return
        self._out += data
        if len(self._out) > MAX_PENDING_OUTPUT:
            excess = len(self._out) - MAX_PENDING_OUTPUT
            del self._out[:excess]
            self.dropped += excess
        self._flush()

    async def close(self) -> None:
        """Close the pty pair and remove the link if it still points to this pty (not one it
        never made, nor one another emulator has made since). Idempotent."""
        master, slave = self._master, self._slave
        self._master = self._slave = None
        self._out.clear()
        if master is not None:
            assert self._loop is not None
            self._loop.remove_reader(master)
            if self._writing:
                self._loop.remove_writer(master)
                self._writing = False
            os.close(master)
        if slave is not None:
            os.close(slave)
        if self.link is not None and self.path is not None and _points_to(self.link, self.path):
            with contextlib.suppress(FileNotFoundError):
                self.link.unlink()
        self.path = None

    async def unplug(self) -> None:
        """Pull the cable: the driver's reads and writes fail, the device path is gone."""
        await self.close()

    async def replug(self) -> str:
        """Plug a cable back in: a fresh pty behind the same ``link``; returns the device."""
        await self.close()
        return await self.open()

    # -- internals -----------------------------------------------------------------------------

    def _readable(self) -> None:
        master = self._master
        if master is None:
            return
        try:
            data = os.read(master, 65536)
        except BlockingIOError:
            return
        except OSError as exc:
            if exc.errno == errno.EIO:  # cannot happen while we hold the slave; be safe
                return
            raise
        if data:
            self.on_data(data)

    def _flush(self) -> None:
        master = self._master
        if master is None:
            return
        while self._out:
            try:
                n = os.write(master, self._out)
            except BlockingIOError:
                break
            except OSError:
                self._out.clear()  # the pty went away: output is lost, like on a cut wire
                return
            del self._out[:n]
        assert self._loop is not None
        if self._out and not self._writing:
            self._loop.add_writer(master, self._flush)
            self._writing = True
        elif not self._out and self._writing:
            self._loop.remove_writer(master)
            self._writing = False


def _point(link: Path, target: str) -> None:
    """Make ``link`` a symlink to ``target`` at once (a new symlink renamed over the old one);
    :class:`BackendError` when ``link`` is there and not a symlink (a file, a real device)."""
    if os.path.lexists(link) and not link.is_symlink():
        raise BackendError(f"{link} exists and is not a symlink: not replacing it with a link "
                           "to the emulated modem (give another --link)")
    fresh = link.with_name(f".{link.name}.{os.getpid()}.{id(link):x}")
    with contextlib.suppress(FileNotFoundError):
        fresh.unlink()
    fresh.symlink_to(target)
    try:
        os.replace(fresh, link)
    except BaseException:
        with contextlib.suppress(OSError):
            fresh.unlink()
        raise


def _points_to(link: Path, target: str) -> bool:
    """Whether ``link`` is a symlink to ``target``."""
    try:
        return os.readlink(link) == target
    except OSError:
        return False


class TcpHost:
    """A modem's TCP port on 127.0.0.1 with the :class:`PtyHost` callback shape.

    ``on_connect`` (optional) is called when a client connects, e.g. to reset a line parser.
    """

    def __init__(
        self,
        on_data: Callable[[bytes], None],
        *,
        host: str = "127.0.0.1",
        port: int = 0,
        on_connect: Callable[[], None] | None = None,
    ) -> None:
        self.on_data = on_data
        self.on_connect = on_connect
        self.host = host
        self.port = port
        self._server: asyncio.Server | None = None
        self._writer: asyncio.StreamWriter | None = None
        self._tasks: set[asyncio.Task[None]] = set()

    @property
    def connected(self) -> bool:
        return self._writer is not None and not self._writer.is_closing()

    async def open(self) -> int:
        """Listen; returns the bound port."""
        if self._server is None:
            self._server = await asyncio.start_server(self._client, self.host, self.port)
            self.port = self._server.sockets[0].getsockname()[1]
        return self.port

    def write(self, data: bytes) -> None:
        """Send ``data`` to the connected client (dropped when nobody is connected)."""
        if self.connected and data:
            assert self._writer is not None
            self._writer.write(data)

    def drop(self) -> None:
        """Cut the current client's connection (a TCP drop)."""
        writer, self._writer = self._writer, None
        if writer is not None:
            writer.close()

    async def close(self) -> None:
        """Stop listening and cut the client. Idempotent."""
        server, self._server = self._server, None
        if server is not None:
            server.close()
        self.drop()
        tasks = list(self._tasks)
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        if server is not None:
            with contextlib.suppress(Exception):
                await server.wait_closed()

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._tasks.add(task)
        self.drop()
        self._writer = writer
        if self.on_connect is not None:
            self.on_connect()
        try:
            while data := await reader.read(65536):
                self.on_data(data)
        except (ConnectionError, OSError):
            pass
        finally:
            if self._writer is writer:
                self._writer = None
            writer.close()
            self._tasks.discard(task)
