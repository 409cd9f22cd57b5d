"""EvoLogics S2C AT interface, sans I/O: :mod:`.protocol` (modem bytes -> events) and
:mod:`.commands` (command builders, and the modem-side command reader used by the emulator)."""

from bridge.modems.evologics.commands import CommandReader, send_im, set_value
from bridge.modems.evologics.protocol import (
    BROADCAST,
    IM_MAX_BYTES,
    Event,
    HostProtocol,
    LocalProtocolError,
    Mode,
    parse_body,
    wrap,
)

__all__ = [
    "BROADCAST",
    "IM_MAX_BYTES",
    "CommandReader",
    "Event",
    "HostProtocol",
    "LocalProtocolError",
    "Mode",
    "parse_body",
    "send_im",
    "set_value",
    "wrap",
]
