"""The WHOI Micro-Modem host protocol, pure: NMEA sentences, rates, and the host state machine.

The asyncio adapter is :mod:`bridge.backends.micromodem`; the emulator is
:mod:`bridge.emulators.micromodem`.
"""

from bridge.micromodem.nmea import ChecksumError, NmeaError, Sentence, checksum, parse_sentence
from bridge.micromodem.protocol import HostProtocol, TransferState, parse_event
from bridge.micromodem.rates import RATES, Rate, frame_bytes_for_rate, get_rate

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
