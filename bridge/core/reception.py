"""What a modem hands the bridge: received frames and ranges it measured, and how it ranges
(pure data). The modem backends (:mod:`bridge.modems.base`, asyncio) build them; the core
takes them.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from types import MappingProxyType
from typing import Any

from bridge.frozen import direct_init

_EMPTY: Mapping[str, Any] = MappingProxyType({})


class RangingMode(StrEnum):
    """How a modem measures ranges itself."""

    PING = "ping"
    """When asked (:meth:`~bridge.modems.base.ModemBackend.ping`): a range takes a transmit
    opportunity of its own."""
    ACK = "ack"
    """From the acknowledgement of a unicast frame: a frame sent to the peer asks for it."""


@direct_init
@dataclass(frozen=True)
class Reception:
    """One frame received by the modem.

    ``time`` is the wall clock (``time.time()``) at the END of reception. ``meta`` holds link
    metadata the backend knows, e.g. ``start``, ``travel_time_s``, ``distance_m``, ``dest``.
    """

    data: bytes
    src: int
    time: float
    meta: Mapping[str, Any] = field(default_factory=lambda: _EMPTY)

    @property
    def dest(self) -> int | None:
        """The address the sender put on the frame (``None`` = broadcast or unknown)."""
        return self.meta.get("dest")


@dataclass(frozen=True)
class ModemRange:
    """A one-way travel time the modem itself measured to ``peer`` (an address).

    ``method`` is ``ping`` (a two-way ping, e.g. the Micro-Modem's ``$CCMPC``) or
    ``propagation`` (e.g. EvoLogics ``AT?T`` after an acknowledged message); ``time`` is the
    backend's :meth:`~ModemBackend.clock` when it was measured.
    """

    peer: int
    travel_time_s: float
    method: str
    time: float
