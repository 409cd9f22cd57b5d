"""Which kind of modem a device is, from the lines it writes back: a serial modem that does
not start may be another kind than its backend drives (``zab doctor`` says which).

Each serial backend has a harmless :attr:`~bridge.modems.base.ModemBackend.probe` and tells its
own protocol's lines (:meth:`~bridge.modems.base.ModemBackend.speaks`). :func:`identify` writes
the probes to the device one after the other, until a line it writes back is in one of the
protocols; :func:`speaker` (pure) names it.
"""

from __future__ import annotations

import asyncio
import re
from collections.abc import Iterable, Mapping

from bridge.errors import BackendError
from bridge.modems.base import ModemBackend
from bridge.modems.transport import ByteTransport

__all__ = ["PROBE_WAIT_S", "identify", "speaker"]

PROBE_WAIT_S = 1.0
"""How long the lines a probe brings back are gathered."""

_LINE_END = re.compile(rb"[\r\n]+")


def speaker(lines: Iterable[bytes], backends: Mapping[str, type[ModemBackend]]
            ) -> tuple[str | None, bytes | None]:
    """The first of ``lines`` in a protocol of ``backends``, and the backend's name; else
    (None, the first line), or (None, None) when there are no lines."""
    first = None
    for line in lines:
        first = first or line
        for name, backend in backends.items():
            if backend.speaks(line):
                return name, line
    return None, first


async def identify(device: str, baud: int, backends: Mapping[str, type[ModemBackend]],
                   wait_s: float = PROBE_WAIT_S) -> tuple[str | None, bytes | None]:
    """Write each backend's probe to ``device`` (in their order) until the device answers in
    one of their protocols: :func:`speaker` of the lines it wrote (none if the port does not
    open)."""
    transport = ByteTransport(device, baud, name=f"probe of {device}")
    lines: list[bytes] = []
    try:
        await transport.open()
        rest = b""
        for backend in backends.values():
            if backend.probe is None:
                continue
            await transport.write(backend.probe)
            rest = await _gather(transport, rest, lines, wait_s)
            if speaker(lines, backends)[0] is not None:
                break
        if rest.strip():  # (a line never ended: noise at the wrong baud rate)
            lines.append(rest)
    except BackendError:
        pass
    finally:
        await transport.close()
    return speaker(lines, backends)


async def _gather(transport: ByteTransport, rest: bytes, lines: list[bytes],
                  wait_s: float) -> bytes:
    """Add to ``lines`` those the device ends within ``wait_s``; returns the unended rest."""
    loop = asyncio.get_running_loop()
    end = loop.time() + wait_s
    while (left := end - loop.time()) > 0:
        try:
            async with asyncio.timeout(left):
                rest += await transport.read()
        except TimeoutError:
            break
        *ended, rest = _LINE_END.split(rest)
        lines += [line for line in ended if line.strip()]
    return rest
