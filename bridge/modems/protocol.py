"""What the modems' sans-I/O protocol parsers share (pure).

Each vendor's ``HostProtocol`` takes bytes with ``receive_data`` and hands back one event at a
time with ``next_event``, which returns :data:`NEED_DATA` while no complete event is buffered
(h11's shape); ``events()`` yields every buffered event.
"""

from __future__ import annotations

import enum
from typing import Final

__all__ = ["NEED_DATA", "NeedData"]


class NeedData(enum.Enum):
    """The type of :data:`NEED_DATA` (an enum, so ``Event | NeedData`` type-checks)."""

    NEED_DATA = "NEED_DATA"

    def __repr__(self) -> str:
        return "NEED_DATA"


NEED_DATA: Final = NeedData.NEED_DATA
"""Returned by ``next_event`` (and the emulators' readers) when more bytes are needed."""
