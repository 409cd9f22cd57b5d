"""The WHOI Micro-Modem host protocol, pure: NMEA sentences, rates, and the host state machine.

The asyncio adapter is :mod:`bridge.modems.micromodem.driver`; the emulator is
:mod:`bridge.modems.micromodem.emulator`.
"""

from bridge.modems.micromodem.nmea import (
    ChecksumError,
    NmeaError,
    Sentence,
    checksum,
    parse_sentence,
)
from bridge.modems.micromodem.protocol import HostProtocol, TransferState, parse_event
from bridge.modems.micromodem.rates import RATES, Rate, frame_bytes_for_rate, get_rate

__all__ = [
    "RATES",
    "ChecksumError",
    "HostProtocol",
    "NmeaError",
    "Rate",
    "Sentence",
    "TransferState",
    "checksum",
    "frame_bytes_for_rate",
    "get_rate",
    "parse_event",
    "parse_sentence",
]
