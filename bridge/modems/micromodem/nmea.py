"""NMEA 0183 sentences as the WHOI Micro-Modem speaks them (pure: no I/O, no clock).

A sentence is ``$TTXXX,f1,f2,...[*hh]\\r\\n``: a two-letter talker (``CC`` host → modem, ``CA``
modem → host, also ``SN`` and ``GP``), a three-letter type, comma-separated fields and an
optional checksum: the XOR of every byte after ``$`` up to ``*``, two upper-case hex digits
(reference 2.1 [V]), or on MM2 an eight-digit CRC-32 (:func:`checksum32`). Both are checked,
and both must be upper case: NMEA 0183 writes the checksum with the characters 0-9 and A-F,
and the modem prints it so; a lower-case checksum is refused as a line that did not come
from a modem. Hex data fields may be either case (a real ``$CAMUA`` carries ``1fab``).
:func:`parse_sentence` raises :class:`NmeaError` and nothing else.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import reduce

from bridge.errors import DecodeError

__all__ = [
    "MAX_SENTENCE_BYTES",
    "ChecksumError",
    "LineBuffer",
    "NmeaError",
    "Sentence",
    "checksum",
    "checksum32",
    "from_modem",
    "parse_sentence",
]

MAX_SENTENCE_BYTES = 8192
"""Longest line accepted. A rate-5 ``$CARXD`` carries 256 B as 512 hex digits and an MM2
``$CARDP`` up to 2048 B as 4096; anything far longer is line noise, not a sentence."""

_ADDRESS = re.compile(r"[A-Z]{2}[A-Z0-9]{3,4}")
"""Talker and type: ``CACYC``, and MM2's four-letter ``CAUSB2``."""
_HEX = re.compile(r"[0-9A-Fa-f]{2}|[0-9A-Fa-f]{8}")

CRC32_POLY_REVERSED = 0xD663B05D
"""The MM2's 32-bit NMEA checksum polynomial in reflected form (Koopman's 0xBA0DC66B), with
initial value and final XOR 0xFFFFFFFF. Read from pyacomms' ``nmeaChecksum32`` table (entry
128 of a reflected table is the reflected polynomial); the table here is computed from it."""


def _crc32_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = (crc >> 1) ^ CRC32_POLY_REVERSED if crc & 1 else crc >> 1
        table.append(crc)
    return tuple(table)


_CRC32 = _crc32_table()


class NmeaError(DecodeError):
    """A line is not a well-formed NMEA sentence (the one error the parser raises)."""


class ChecksumError(NmeaError):
    """The sentence's ``*hh`` does not match its contents."""


def checksum(body: str) -> str:
    """The NMEA XOR checksum of ``body`` (the text between ``$`` and ``*``), e.g. ``"5B"``."""
    return f"{reduce(lambda acc, ch: acc ^ ord(ch), body, 0):02X}"


def checksum32(body: str) -> str:
    """The MM2 CRC-32 checksum of ``body`` as eight upper-case hex digits."""
    crc = 0xFFFFFFFF
    for byte in body.encode("latin-1"):
        crc = (crc >> 8) ^ _CRC32[(crc ^ byte) & 0xFF]
    return f"{crc ^ 0xFFFFFFFF:08X}"


@dataclass(frozen=True)
class Sentence:
    """One sentence: ``talker`` (``"CA"``), ``kind`` (``"CYC"``) and its text ``fields``."""

    talker: str
    kind: str
    fields: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if not _ADDRESS.fullmatch(self.talker + self.kind) or len(self.talker) != 2:
            raise ValueError(f"bad NMEA address {self.talker + self.kind!r}")
        for f in self.fields:
            if any(c in f for c in ",*$\r\n") or not f.isascii():
                raise ValueError(f"NMEA field {f!r} contains a reserved or non-ASCII character")

    @property
    def name(self) -> str:
        """Talker and type together, e.g. ``"CACYC"``."""
        return self.talker + self.kind

    def body(self) -> str:
        """The text between ``$`` and ``*``."""
        return ",".join((self.name, *self.fields))

    def to_line(self, *, with_checksum: bool = True, crc32: bool = False) -> str:
        """The sentence as text, without the line end (``crc32``: the MM2's 8-digit sum)."""
        body = self.body()
        if not with_checksum:
            return f"${body}"
        return f"${body}*{checksum32(body) if crc32 else checksum(body)}"

    def encode(self, *, with_checksum: bool = True, crc32: bool = False) -> bytes:
        """The sentence as bytes on the wire, ending in ``\\r\\n``."""
        line = self.to_line(with_checksum=with_checksum, crc32=crc32)
        return (line + "\r\n").encode("ascii")

    def __str__(self) -> str:
        line = self.to_line()
        return line if len(line) <= 120 else f"{line[:100]}…({len(line)} chars)"


def parse_sentence(line: bytes | str) -> Sentence:
    """Parse one line (line end optional). Raises :class:`NmeaError` (or :class:`ChecksumError`).

    The checksum is optional, as on the modem's input [V]. Two hex digits are the XOR sum,
    eight the MM2's CRC-32 (:func:`checksum32`); either must match and be upper case.
    """
    if isinstance(line, bytes):
        try:
            text = line.decode("ascii")
        except UnicodeDecodeError:
            raise NmeaError("non-ASCII bytes in sentence") from None
    else:
        text = line
    text = text.strip("\r\n")
    if len(text) > MAX_SENTENCE_BYTES:
        raise NmeaError(f"sentence longer than {MAX_SENTENCE_BYTES} characters")
    if not text.startswith("$"):
        raise NmeaError(f"sentence must start with '$': {text[:40]!r}")
    body, star, given = text[1:].partition("*")
    if star:
        if not _HEX.fullmatch(given):
            raise NmeaError(f"bad checksum field {given[:12]!r} (2 or 8 hex digits)")
        if given != given.upper():
            raise NmeaError(f"lower-case checksum {given!r}: the modem prints 0-9 and A-F")
        want = checksum(body) if len(given) == 2 else checksum32(body)
        if given != want:
            raise ChecksumError(f"checksum mismatch in ${body[:40]}: got {given}, computed {want}")
    if not body.isascii() or not body.isprintable() or "$" in body:
        raise NmeaError(f"unprintable or reserved characters in sentence {body[:40]!r}")
    address, *fields = body.split(",")
    if not _ADDRESS.fullmatch(address):
        raise NmeaError(f"bad talker/type {address[:12]!r} (want CACYC or CAUSB2)")
    return Sentence(address[:2], address[2:], tuple(fields))


MODEM_TALKERS = ("CA", "SN")
"""The talkers of the sentences a Micro-Modem writes of its own (``GP`` it passes on)."""


def from_modem(line: bytes) -> bool:
    """Whether ``line`` is a sentence a Micro-Modem writes: talker ``CA`` or ``SN``, with a
    checksum that matches if it has one."""
    try:
        return parse_sentence(line).talker in MODEM_TALKERS
    except NmeaError:
        return False


class LineBuffer:
    """Splits a byte stream into lines at ``\r`` and/or ``\n`` (empty lines skipped).

    A line longer than :data:`MAX_SENTENCE_BYTES` is cut off: its start is returned through
    ``overflow`` and the rest is skipped up to the next line end.
    """

    def __init__(self) -> None:
        self._buffer = bytearray()
        self._skipping = False

    def feed(self, data: bytes) -> tuple[list[bytes], bytes | None]:
        """Add bytes; returns the complete lines and the start of an overlong line (or None)."""
        self._buffer += data
        lines: list[bytes] = []
        while True:
            ends = [i for i in (self._buffer.find(b"\r"), self._buffer.find(b"\n")) if i >= 0]
            if not ends:
                break
            cut = min(ends)
            line = bytes(self._buffer[:cut])
            del self._buffer[: cut + 1]
            if self._skipping:
                self._skipping = False
            elif line:
                lines.append(line)
        overflow = None
        if len(self._buffer) > MAX_SENTENCE_BYTES:
            overflow = bytes(self._buffer[:80])
            self._buffer.clear()
            self._skipping = True
        return lines, overflow

    def clear(self) -> None:
        """Forget a partial line (e.g. after the port was reopened)."""
        self._buffer.clear()
        self._skipping = False
