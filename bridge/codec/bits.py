"""Bit-level helpers: level counts, int <-> bytes, and a small MSB-first bit writer/reader.

Everything here is pure and clock-free. A layout packs its fields into one Python ``int``
(first field in the most significant bits); frames concatenate such ints by shifting.
"""

from __future__ import annotations

from bridge.errors import DecodeError, EncodeError
from bridge.mission.fields import bits_for

__all__ = ["BitReader", "BitWriter", "bits_for", "bytes_to_int", "int_to_bytes", "nbytes_for"]


def nbytes_for(bits: int) -> int:
    """Whole bytes that hold ``bits`` bits."""
    return (bits + 7) >> 3


def int_to_bytes(n: int, bits: int) -> bytes:
    """``n`` (< 2**bits) as ``ceil(bits/8)`` big-endian bytes, zero pad bits at the end."""
    if n < 0 or n >> bits:
        raise EncodeError(f"value {n} does not fit in {bits} bits")
    pad = -bits % 8
    return (n << pad).to_bytes((bits + pad) >> 3, "big")


def bytes_to_int(data: bytes, bits: int) -> int:
    """Inverse of :func:`int_to_bytes`; exact length and zero pad bits are required."""
    nbytes = nbytes_for(bits)
    if len(data) != nbytes:
        raise DecodeError(f"expected {nbytes} bytes for {bits} bits, got {len(data)}")
    pad = -bits % 8
    n = int.from_bytes(data, "big")
    if n & ((1 << pad) - 1):
        raise DecodeError("non-zero pad bits")
    return n >> pad


class BitWriter:
    """Append unsigned fields MSB first; ``value`` / ``to_bytes()`` give the result."""

    __slots__ = ("bits", "value")

    def __init__(self) -> None:
        self.value = 0
        self.bits = 0

    def write(self, n: int, bits: int) -> None:
        """Append ``n`` as exactly ``bits`` bits."""
        if n < 0 or n >> bits:
            raise EncodeError(f"value {n} does not fit in {bits} bits")
        self.value = (self.value << bits) | n
        self.bits += bits

    def to_bytes(self) -> bytes:
        """Whole bytes, zero pad bits at the end."""
        return int_to_bytes(self.value, self.bits)


class BitReader:
    """Read unsigned fields MSB first from bytes (or an int of known width)."""

    __slots__ = ("_bits", "_n", "_pos")

    def __init__(self, data: bytes | int, bits: int | None = None) -> None:
        if isinstance(data, int):
            if bits is None:
                raise TypeError("bits is required when reading from an int")
            self._n, self._bits = data, bits
        else:
            self._n = int.from_bytes(data, "big")
            self._bits = len(data) * 8 if bits is None else bits
            if bits is not None:
                if bits > len(data) * 8:
                    raise DecodeError(f"need {bits} bits, only {len(data) * 8} given")
                self._n >>= len(data) * 8 - bits
        self._pos = 0

    @property
    def remaining(self) -> int:
        """Bits not read yet."""
        return self._bits - self._pos

    def read(self, bits: int) -> int:
        """Next ``bits`` bits as an unsigned int; DecodeError when the data runs out."""
        if bits > self._bits - self._pos:
            raise DecodeError(f"need {bits} bits, only {self._bits - self._pos} left")
        self._pos += bits
        return (self._n >> (self._bits - self._pos)) & ((1 << bits) - 1)
