"""DCCL's numeric rules, computed exactly as libdccl 4 computes them.

Sizes: ``ceil_log2(ceil((max - min) / resolution + 1 + null))`` in IEEE doubles. Floating
point values: ``round(|v| / res) - round(|min| / res)`` with each quotient rounded half away
from zero *exactly* (libdccl's ``numeric.h`` divides the significands as integers since
DCCL 4.2); decoding multiplies back in doubles and re-quantises. Integers follow the C++
integer arithmetic of ``encode``/``decode``/``quantize`` in ``numeric.h``/``common.h``.
"""

from __future__ import annotations

import math
import struct
from fractions import Fraction

__all__ = ["ceil_log2", "decode_float", "decode_int", "encode_float", "encode_int", "f32",
           "quantize_float", "round_div", "size_bits"]

_EPS = 2.220446049250313e-16  # std::numeric_limits<double>::epsilon()
MASK64 = (1 << 64) - 1


def ceil_log2(v: int) -> int:
    """Bits for ``v`` distinct values: ``ceil(log2(v))`` (0 for 0 and 1)."""
    return (v - 1).bit_length() if v > 1 else 0


def size_bits(lo: float, hi: float, res: float, required: bool) -> int:
    """Bits of a bounded numeric field (one extra value for "not present" if optional)."""
    span = (hi - lo) / res + 1 + (0 if required else 1)
    return ceil_log2(math.ceil(span))


def f32(x: float) -> float:
    """``x`` rounded to a C ``float`` (what a protobuf ``float`` field holds); beyond the
    float range, an infinity as the C conversion gives."""
    try:
        return struct.unpack("<f", struct.pack("<f", x))[0]
    except OverflowError:
        return math.copysign(math.inf, x)


def round_div(x: float, res: float) -> int:
    """``x / res`` rounded half away from zero, computed exactly on the binary values."""
    q = Fraction(abs(x)) / Fraction(res)
    n = math.floor(q + Fraction(1, 2))
    return -n if x < 0 else n


def encode_float(value: float, lo: float, res: float) -> int:
    """The unsigned code of an in-range float/double (before the optional +1)."""
    return (round_div(value, res) - round_div(lo, res)) & MASK64


def quantize_float(value: float, res: float) -> float:
    """``dccl::quantize`` for doubles: snap to the nearest multiple of ``res``."""
    if res >= 1:
        return math.floor(value / res + 0.5) * res
    inv = 1.0 / res
    return math.floor(value * inv + 0.5) / inv


def decode_float(code: int, lo: float, res: float, single: bool) -> float:
    """Inverse of :func:`encode_float` (``single``: the field is a protobuf ``float``)."""
    total = code + round_div(lo, res)
    value = float(abs(total)) * res
    if total < 0:
        value = -value
    value = quantize_float(value, res)
    return f32(value) if single else value


def _trunc(x: float) -> int:
    """C++ floating → integer conversion (toward zero)."""
    return int(x)


def _crem(a: int, b: int) -> int:
    """C++ ``a % b`` (sign of the dividend)."""
    r = abs(a) % abs(b)
    return -r if a < 0 else r


def quantize_int(value: int, interval: float) -> int:
    """``dccl::quantize`` for integers (a fractional interval leaves the value alone)."""
    if interval - float(int(interval)) >= _EPS:
        return value
    rem = _crem(value, int(interval))
    value -= rem
    if rem >= interval / 2:
        value = _trunc(value + interval)
    return value


def encode_int(value: int, lo: float, res: float) -> int:
    """The unsigned code of an in-range integer (before the optional +1)."""
    wire = quantize_int(value, res) - quantize_int(_trunc(lo), res)
    wire = _trunc(wire / res) if res >= 1 else _trunc(wire * (1.0 / res))
    return wire & MASK64


def decode_int(code: int, lo: float, res: float) -> int:
    """Inverse of :func:`encode_int`."""
    wire = _trunc(code * res) if res >= 1 else _trunc(code / (1.0 / res))
    return quantize_int(wire + quantize_int(_trunc(lo), res), res)
