"""``udp``: an ideal link over UDP datagrams, for running a mission without any water model.

Options: ``port`` (required; 0 = any free port, see :attr:`UdpBackend.port`), ``host``
(default ``127.0.0.1``), ``allow_remote`` (default false: only loopback addresses are accepted,
for this node and its peers), ``rx_queue`` (default 256). Each peer whose options have a
``port`` (and optional ``host``) is a UDP peer.

Broadcast sends one datagram to every UDP peer; ``dest`` sends to that peer only. Each datagram
starts with a 5-byte header: magic ``0xA5``, source address (u16), destination address (u16,
``0xFFFF`` = broadcast), all big-endian. No delay, loss or collision is modelled, and ``send``
returns as soon as the datagrams are handed to the kernel.
"""

from __future__ import annotations

import asyncio
import ipaddress
import struct
import time
from typing import Any, ClassVar

from bridge.errors import BackendError
from bridge.modems.base import Inbox, ModemBackend, ModemSetup, Reception

__all__ = ["BROADCAST", "HEADER", "MAGIC", "UdpBackend", "is_loopback"]

MAGIC = 0xA5
BROADCAST = 0xFFFF
HEADER = struct.Struct(">BHH")
DEFAULT_RX_QUEUE = 256


def is_loopback(host: str) -> bool:
    """True for ``localhost`` and loopback IP literals (no DNS lookup)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class _Protocol(asyncio.DatagramProtocol):
    def __init__(self, backend: UdpBackend) -> None:
        self.backend = backend

    def datagram_received(self, data: bytes, addr: tuple[str | Any, int]) -> None:
        self.backend._on_datagram(data, addr)

    def error_received(self, exc: Exception) -> None:
        # e.g. ICMP port unreachable when a peer is not running yet: counted, not fatal
        self.backend.stats["unreachable"] += 1


class UdpBackend(ModemBackend):
    """Frames as UDP datagrams between the nodes' ports."""

    name: ClassVar[str] = "udp"

    def __init__(self, setup: ModemSetup) -> None:
        super().__init__(setup)
        opts = setup.options
        allow_remote = bool(opts.get("allow_remote", False))
        if not 0 <= setup.address < BROADCAST:
            raise BackendError(f"udp backend: address {setup.address} outside 0..65534")
        if "port" not in opts:
            raise BackendError(f"udp backend of {setup.node!r}: option 'port' is required")
        self.host = str(opts.get("host", "127.0.0.1"))
        self.port = _port(opts["port"], setup.node)
        self._peers: dict[int, tuple[str, int]] = {}
        for addr, popts in setup.peers.items():
            if "port" not in popts:
                continue
            self._peers[addr] = (str(popts.get("host", "127.0.0.1")), _port(popts["port"], addr))
        if not allow_remote:
            for where in [self.host, *(h for h, _ in self._peers.values())]:
                if not is_loopback(where):
                    raise BackendError(
                        f"udp backend of {setup.node!r}: {where!r} is not a loopback address; "
                        "set allow_remote: true to send off this machine"
                    )
        self._inbox = Inbox(self.stats, int(opts.get("rx_queue", DEFAULT_RX_QUEUE)))
        self._transport: asyncio.DatagramTransport | None = None
        self.stats.update({"malformed": 0, "unreachable": 0})

    async def _open(self) -> None:
        loop = asyncio.get_running_loop()
        try:
            transport, _ = await loop.create_datagram_endpoint(
                lambda: _Protocol(self), local_addr=(self.host, self.port)
            )
        except OSError as exc:
            raise BackendError(
                f"udp backend of {self.setup.node!r}: cannot bind {self.host}:{self.port}: {exc}"
            ) from None
        self._transport = transport
        self.port = transport.get_extra_info("sockname")[1]

    async def _send(self, data: bytes, dest: int | None, ack: bool) -> None:
        """One datagram (an ideal link: ``ack`` is ignored)."""
        transport = self._transport
        if transport is None or transport.is_closing():
            raise BackendError(f"udp backend of {self.setup.node!r}: socket is closed")
        if dest is None:
            targets = list(self._peers.values())
        elif dest in self._peers:
            targets = [self._peers[dest]]
        else:
            known = ", ".join(map(str, sorted(self._peers))) or "none"
            raise BackendError(
                f"udp backend of {self.setup.node!r}: no UDP peer with address {dest} "
                f"(known: {known})"
            )
        datagram = HEADER.pack(MAGIC, self.address, BROADCAST if dest is None else dest) + data
        for target in targets:
            transport.sendto(datagram, target)

    async def _recv(self) -> Reception:
        return await self._inbox.get()

    async def _close(self) -> None:
        transport, self._transport = self._transport, None
        if transport is not None:
            transport.close()
        self._inbox.put(BackendError(f"udp backend of {self.setup.node!r} is closed"))

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
        self._deliver(rx)


def _port(value: Any, who: object) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 65535:
        raise BackendError(f"udp backend: port of {who!r} must be an integer 0..65535")
    return value
