"""A frame built for the modem, with what it carries (pure data)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from bridge.core.builder import FramePlan
from bridge.core.families import Extra
from bridge.core.reliable import ReliableSender
from bridge.core.transfer import TransferSender
from bridge.frozen import direct_init

__all__ = ["OutFrame", "Sender"]

Sender = ReliableSender | TransferSender


@direct_init
@dataclass(frozen=True)
class OutFrame:
    """A frame ready for the modem: bytes, unicast address (None = broadcast), ack request,
    the modem-clock start it was built for, and what it carries."""

    data: bytes
    dest: int | None
    ack: bool | None
    at: float
    plan: FramePlan
    built: float
    streams: tuple[tuple[Sender, Any], ...] = ()
    acks: tuple[tuple[str, int], ...] = ()
    extras: tuple[Extra, ...] = ()
    link: str | None = None  # the link it goes out on (None: the node's only one)
    carried: tuple[Any, ...] = ()  # frames the node carries on for others (bridge.core.routing)
    own: OutFrame | None = None  # beside them, the node's own frame (a bundle)
