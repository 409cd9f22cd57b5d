"""``udp``: an ideal link over UDP datagrams, for running a mission without any water model.

Options: the table at the end. ``port`` is required (0 = any free port, see
:attr:`UdpBackend.port`); without ``allow_remote`` only loopback addresses are accepted, for
this node and its peers. Each peer whose options have a ``port`` (and optional ``host``) is a
UDP peer.

Broadcast sends one datagram to every UDP peer; ``dest`` sends to that peer only. Each datagram
starts with a 5-byte header: magic ``0xA5``, source address (u16), destination address (u16,
``0xFFFF`` = broadcast), all big-endian. No delay, loss or collision is modelled, and ``send``
returns as soon as the datagrams are handed to the kernel. A :attr:`~UdpBackend.direct`
backend: it sends from any thread and hears on a thread of its own.
"""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import socket
import struct
import threading
import time
from typing import Any, ClassVar

from bridge.errors import BackendError
from bridge.mission.backends import ModemOptions, UdpOptions
from bridge.modems.base import Inbox, ModemBackend, ModemSetup, Reception

__all__ = ["BROADCAST", "HEADER", "MAGIC", "UdpBackend", "is_loopback"]

MAGIC = 0xA5
BROADCAST = 0xFFFF
HEADER = struct.Struct(">BHH")


def is_loopback(host: str) -> bool:
    """True for ``localhost`` and loopback IP literals (no DNS lookup)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class UdpBackend(ModemBackend):
    """Frames as UDP datagrams between the nodes' ports.

    :attr:`direct`: a frame is sent from whichever thread calls :meth:`send_now`, and a
    thread of the backend's own, blocked on the socket, hands each datagram to
    :attr:`on_reception` (or to the loop, for :meth:`recv`).
    """

    name: ClassVar[str] = "udp"
    options_model: ClassVar[type[ModemOptions]] = UdpOptions
    options: UdpOptions
    direct: ClassVar[bool] = True

    def __init__(self, setup: ModemSetup) -> None:
        super().__init__(setup)
        opts = self.options
        if not 0 <= setup.address < BROADCAST:
            raise BackendError(f"udp backend: address {setup.address} outside 0..65534")
        if opts.port is None:
            raise BackendError(f"udp backend of {setup.node!r}: option 'port' is required")
        self.host = opts.host
        self.port = opts.port
        self._peers: dict[int, tuple[str, int]] = {}
        for addr, popts in setup.peers.items():
            if "port" not in popts:
                continue
            self._peers[addr] = (str(popts.get("host", "127.0.0.1")), _port(popts["port"], addr))
        if not opts.allow_remote:
            for where in [self.host, *(h for h, _ in self._peers.values())]:
                if not is_loopback(where):
                    raise BackendError(
                        f"udp backend of {setup.node!r}: {where!r} is not a loopback address; "
                        "set allow_remote: true to send off this machine"
                    )
        self._inbox = Inbox(self.stats, opts.rx_queue)
        self._sock: socket.socket | None = None
        self._targets: dict[int, Any] = {}  # peer address -> resolved socket address
        self._reader: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._closing = False
        self.stats.update({"malformed": 0, "unreachable": 0})

    async def _open(self) -> None:
        self._loop = asyncio.get_running_loop()
        try:
            family, _, _, _, where = socket.getaddrinfo(
                self.host, self.port, type=socket.SOCK_DGRAM)[0]
            sock = socket.socket(family, socket.SOCK_DGRAM)
        except OSError as exc:
            raise BackendError(
                f"udp backend of {self.setup.node!r}: cannot resolve {self.host}: {exc}") from None
        try:
            sock.bind(where)
            for addr, (host, port) in self._peers.items():
                self._targets[addr] = _resolve(host, port, family)
        except OSError as exc:
            sock.close()
            raise BackendError(
                f"udp backend of {self.setup.node!r}: cannot bind {self.host}:{self.port} "
                f"or reach its peers: {exc}"
            ) from None
        self._sock = sock
        self.port = sock.getsockname()[1]
        self._reader = threading.Thread(target=self._read, args=(sock,), daemon=True,
                                        name=f"udp-{self.setup.node}")
        self._reader.start()

    async def _send(self, data: bytes, dest: int | None, ack: bool,
                    deadline: float | None) -> None:
        self._send_now(data, dest, ack)  # at once, never retried: the base checked ``until``

    def _send_now(self, data: bytes, dest: int | None, ack: bool) -> None:
        """One datagram per target (an ideal link: ``ack`` is ignored), never blocking: a
        full socket buffer is an error."""
        sock = self._sock
        if sock is None or self._closing:
            raise BackendError(f"udp backend of {self.setup.node!r}: socket is closed")
        if dest is None:
            targets = list(self._targets.values())
        elif dest in self._targets:
            targets = [self._targets[dest]]
        else:
            known = ", ".join(map(str, sorted(self._targets))) or "none"
            raise BackendError(
                f"udp backend of {self.setup.node!r}: no UDP peer with address {dest} "
                f"(known: {known})"
            )
        datagram = HEADER.pack(MAGIC, self.address, BROADCAST if dest is None else dest) + data
        for target in targets:
            try:
                sock.sendto(datagram, socket.MSG_DONTWAIT, target)
            except ConnectionRefusedError:  # an earlier datagram found no peer: not fatal
                self.stats["unreachable"] += 1
            except OSError as exc:
                raise BackendError(
                    f"udp backend of {self.setup.node!r}: cannot send to {target}: {exc}"
                ) from None

    async def _recv(self) -> Reception:
        return await self._inbox.get()

    async def _close(self) -> None:
        self._closing = True
        sock, self._sock = self._sock, None
        if sock is not None:
            with contextlib.suppress(OSError):  # wakes the reader (ENOTCONN, yet it wakes)
                sock.shutdown(socket.SHUT_RD)
            if self._reader is not None:
                await asyncio.to_thread(self._reader.join, 1.0)
            sock.close()
        self._inbox.put(BackendError(f"udp backend of {self.setup.node!r} is closed"))

    def _read(self, sock: socket.socket) -> None:
        """The reader thread: each datagram, until the socket is shut."""
        while not self._closing:
            try:
                data, addr = sock.recvfrom(65536)
            except ConnectionRefusedError:  # ICMP port unreachable: a peer not up yet
                self.stats["unreachable"] += 1
                continue
            except OSError as exc:
                if not self._closing:
                    self._to_loop(BackendError(
                        f"udp backend of {self.setup.node!r}: receive failed: {exc}"))
                return
            if self._closing:
                return
            self._on_datagram(data, addr)

    def _to_loop(self, item: Reception | BackendError) -> None:
        """For :meth:`recv`: queued on the loop (the inbox is the loop's)."""
        assert self._loop is not None
        with contextlib.suppress(RuntimeError):  # the loop is gone: nobody reads any more
            self._loop.call_soon_threadsafe(self._inbox.put, item)

    def _on_datagram(self, data: bytes, addr: tuple[Any, int]) -> None:
        if len(data) <= HEADER.size or data[0] != MAGIC:
            self.stats["malformed"] += 1
            return
        _, src, dest = HEADER.unpack_from(data)
        now = time.time()
        rx = Reception(
            data=data[HEADER.size :],
            src=src,
            time=now,
            meta={
                "dest": None if dest == BROADCAST else dest,
                "start": now,
                "travel_time_s": 0.0,
                "from": f"{addr[0]}:{addr[1]}",
            },
        )
        if self.on_reception is not None:
            self._deliver(rx)  # here, on this thread
        else:
            self._to_loop(rx)


def _resolve(host: str, port: int, family: int) -> Any:
    """A peer's socket address in the family of this node's socket."""
    return socket.getaddrinfo(host, port, family, socket.SOCK_DGRAM)[0][4]


def _port(value: Any, who: object) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 65535:
        raise BackendError(f"udp backend: port of {who!r} must be an integer 0..65535")
    return value
