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


@dataclass(frozen=True)
class ModemFix:
    """Where the modem's own USBL head located ``peer`` (an address), relative to the head.

    ``east_m``/``north_m``/``down_m`` come from ``range_m`` (one-way travel time × sound
    speed), ``azimuth_deg`` (from north, clockwise) and ``elevation_deg`` (down positive);
    ``covariance`` is the 3×3 ENU covariance in m² when the modem's line gives one (row by
    row), else None. ``time`` is the backend's :meth:`~ModemBackend.clock`.
    """

    peer: int
    time: float
    range_m: float
    azimuth_deg: float
    elevation_deg: float
    east_m: float
    north_m: float
    down_m: float
    covariance: tuple[float, ...] | None = None

    def payload(self) -> dict[str, Any]:
        """As published on Zenoh (``@zab/<mission>/<node>/usbl/<peer>``)."""
        return {"time": self.time, "range_m": self.range_m, "azimuth_deg": self.azimuth_deg,
                "elevation_deg": self.elevation_deg, "east_m": self.east_m,
                "north_m": self.north_m, "down_m": self.down_m,
                "covariance": None if self.covariance is None else list(self.covariance)}
