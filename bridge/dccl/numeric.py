"""DCCL's numeric rules, computed exactly as libdccl computes them, in two versions.

libdccl changed how it turns a floating point value into its code in January 2026 (GobySoft/dccl
pull request #152, ``src/numeric.h``), after its latest release. A mission picks the rule its
fleet's libdccl has (:data:`RULES`):

* ``dccl-4.2`` — the 4.2.0 release (``DefaultNumericFieldCodec`` in ``src/codecs2/
  field_codec_default.h``): the value is quantised first, ``floor(v / res + 0.5)`` in the
  field's own type (C ``float`` arithmetic for a ``float`` field), the bounds are checked on the
  quantised value (NaN passes them), and the code is the rounded scaled difference from the
  quantised minimum. Every step is IEEE arithmetic, so zab repeats it operation by operation.
* ``dccl-2026`` — GobySoft/dccl after pull request #152: the bounds are checked on the value
  (``min - res/2 <= v < max + res/2``; NaN fails them), and the code is
  ``round(|v| / res) - round(|min| / res)`` with each quotient rounded half away from zero
  *exactly* on the binary values (zab uses rationals); a ``float`` field decodes through the
  double resolution.

Integers follow the C++ integer arithmetic of ``encode``/``decode``/``quantize`` (the same in
both rules), with the conversions of a double to an integer done as x86-64 does them (a value
past the type's range gives the "integer indefinite", so a ``uint64`` past ``2**64 - 1`` is 0).
Sizes: ``ceil_log2(ceil((max - min) / resolution + 1 + null))`` in IEEE doubles.
"""

from __future__ import annotations

import math
import struct
from fractions import Fraction

__all__ = ["DEFAULT_RULE", "RULES", "ceil_log2", "decode_float", "decode_int", "encode_float",
           "encode_int", "f32", "fits_double", "in_range", "quantize_float", "round_div",
           "size_bits", "wire_kind"]

#: The numeric rules and the libdccl each matches (docs/dccl.md gives the commits).
RULES: dict[str, str] = {
    "dccl-4.2": "libdccl 4.2.0, the latest release",
    "dccl-2026": "libdccl since pull request #152 (January 2026, not yet released)",
}
#: The rule of the latest libdccl release.
DEFAULT_RULE = "dccl-4.2"

_EPS = 2.220446049250313e-16  # std::numeric_limits<double>::epsilon()
MASK64 = (1 << 64) - 1
_TWO63 = float(1 << 63)
#: protobuf field type -> the C++ type libdccl computes in (its ``WireType``).
_WIRE = {"int32": "int32", "sint32": "int32", "sfixed32": "int32", "int64": "int64",
         "sint64": "int64", "sfixed64": "int64", "uint32": "uint32", "fixed32": "uint32",
         "uint64": "uint64", "fixed64": "uint64", "enum": "int32"}
_BITS = {"int32": 32, "int64": 64, "uint32": 32, "uint64": 64}


def wire_kind(field_type: str) -> str:
    """The C++ integer type libdccl's numeric codec uses for a protobuf integer type."""
    return _WIRE[field_type]


def ceil_log2(v: int) -> int:
    """Bits for ``v`` distinct values: ``ceil(log2(v))`` (0 for 0 and 1)."""
    return (v - 1).bit_length() if v > 1 else 0


def size_bits(lo: float, hi: float, res: float, required: bool) -> int:
    """Bits of a bounded numeric field (one extra value for "not present" if optional)."""
    span = (hi - lo) / res + 1 + (0 if required else 1)
    return ceil_log2(math.ceil(span))


def fits_double(lo: float, hi: float, res: float) -> bool:
    """libdccl's load check: ``log2(max - min) - log2(resolution) <= 53``."""
    span = hi - lo
    return span <= 0 or math.log2(span) - math.log2(res) <= 53


def f32(x: float) -> float:
    """``x`` rounded to a C ``float`` (what a protobuf ``float`` field holds); beyond the
    float range, an infinity as the C conversion gives."""
    try:
        rounded: float = struct.unpack("<f", struct.pack("<f", x))[0]
        return rounded
    except OverflowError:
        return math.copysign(math.inf, x)


def _f32_of_int(n: int) -> float:
    """A C ``(float)`` of a 64-bit integer: rounded once, to nearest even."""
    if abs(n) < 1 << 53:
        return f32(float(n))
    shift = abs(n).bit_length() - 24
    q, r = divmod(abs(n), 1 << shift)
    half = 1 << (shift - 1)
    if r > half or (r == half and q & 1):
        q += 1
    return math.copysign(f32(float(q << shift)), n)


# -- C++ conversions and integer arithmetic ------------------------------------------------------
def _cvtt64(x: float) -> int:
    """x86-64 ``cvttsd2si`` to 64 bits: truncation, or -2**63 when out of range or NaN."""
    if x != x or not -_TWO63 <= x < _TWO63:
        return -(1 << 63)
    return int(x)


def to_int(x: float, kind: str) -> int:
    """A C++ conversion of the double ``x`` to ``kind`` as gcc compiles it for x86-64."""
    if kind == "int64":
        return _cvtt64(x)
    if kind == "int32":
        return int(x) if -2.0**31 - 1 < x < 2.0**31 else -(1 << 31)
    if kind == "uint32":  # through a 64-bit conversion, then the low 32 bits
        return _cvtt64(x) & 0xFFFFFFFF
    if x == x and x >= _TWO63:  # uint64: x - 2**63 converted, then its top bit flipped
        return (_cvtt64(x - _TWO63) ^ (1 << 63)) & MASK64
    return _cvtt64(x) & MASK64


def _wrap(n: int, kind: str) -> int:
    """``n`` reduced to the C++ type ``kind`` (two's complement for the signed types)."""
    bits = _BITS[kind]
    n &= (1 << bits) - 1
    if kind in ("int32", "int64") and n >> (bits - 1):
        n -= 1 << bits
    return n


def _crem(a: int, b: int) -> int:
    """C++ ``a % b`` (sign of the dividend)."""
    r = abs(a) % abs(b)
    return -r if a < 0 else r


def quantize_int(value: int, interval: float, kind: str) -> int:
    """``dccl::quantize`` for integers (a fractional interval leaves the value alone)."""
    if interval - float(to_int(interval, "uint64")) >= _EPS:
        return value
    rem = _crem(value, to_int(interval, kind))
    value -= rem
    if rem >= interval / 2:
        value = to_int(value + interval, kind)
    return value


def encode_int(value: int, lo: float, res: float, kind: str) -> int:
    """The unsigned code of an in-range integer (before the optional +1)."""
    wire = _wrap(quantize_int(value, res, kind) - quantize_int(to_int(lo, kind), res, kind),
                 kind)
    wire = to_int(wire / res, kind) if res >= 1 else to_int(wire * (1.0 / res), kind)
    return wire & MASK64


def decode_int(code: int, lo: float, res: float, kind: str) -> int:
    """Inverse of :func:`encode_int`."""
    wire = _wrap(code, kind)
    wire = to_int(wire * res, kind) if res >= 1 else to_int(wire / (1.0 / res), kind)
    total = _wrap(wire + quantize_int(to_int(lo, kind), res, kind), kind)
    return quantize_int(total, res, kind)


# -- floating point ------------------------------------------------------------------------------
def quantize_float(value: float, res: float) -> float:
    """``dccl::quantize`` for doubles: snap to the nearest multiple of ``res``."""
    if res >= 1:
        return math.floor(value / res + 0.5) * res
    inv = 1.0 / res
    return math.floor(value * inv + 0.5) / inv


def _floor(x: float) -> float:
    """C ``floor``: NaN and the infinities stay as they are."""
    return math.floor(x) if math.isfinite(x) else x


def _quantize(value: float, res: float, single: bool) -> float:
    """``dccl::quantize`` in the field's type (computed in double, returned as a float)."""
    inv = 1.0 / res
    q = _floor(value / res + 0.5) * res if res >= 1 else _floor(value * inv + 0.5) / inv
    return f32(q) if single else q


def in_range(value: float, lo: float, hi: float, res: float, kind: str, rule: str) -> bool:
    """Whether libdccl encodes ``value`` (of C++ type ``kind``: ``double``, ``float`` or an
    integer type; a float already rounded to one) rather than zeros."""
    if rule == "dccl-2026":
        return lo - res / 2 <= float(value) < hi + res / 2
    if kind in ("double", "float"):
        q = _quantize(value, res, kind == "float")
    else:
        q = float(quantize_int(int(value), res, kind))
    return not (q < lo or q > hi)


def round_div(x: float, res: float) -> int:
    """``x / res`` rounded half away from zero, computed exactly on the binary values."""
    q = Fraction(abs(x)) / Fraction(res)
    n = math.floor(q + Fraction(1, 2))
    return -n if x < 0 else n


def encode_float(value: float, lo: float, res: float, single: bool, rule: str) -> int:
    """The unsigned code of an in-range float or double (before the optional +1)."""
    if rule == "dccl-2026":  # min and resolution as the field's type, then exact division
        if single:
            lo, res = f32(lo), f32(res)
        return (round_div(value, res) - round_div(lo, res)) & (0xFFFFFFFF if single else MASK64)
    cast = f32 if single else float
    wire = _quantize(value, res, single)
    wire = cast(wire - _quantize(cast(lo), res, single))
    wire = cast(wire / res) if res >= 1 else cast(wire * (1.0 / res))
    return to_int(cast(_floor(wire + 0.5)), "uint64")


def decode_float(code: int, lo: float, res: float, single: bool, rule: str) -> float:
    """Inverse of :func:`encode_float` (``single``: the field is a protobuf ``float``)."""
    if rule == "dccl-2026":
        total = code + (round_div(f32(lo), f32(res)) if single else round_div(lo, res))
        magnitude = abs(total) & (0xFFFFFFFF if single else MASK64)
        value = quantize_float(-(magnitude * res) if total < 0 else magnitude * res, res)
        return f32(value) if single else value
    if single:
        wire = _f32_of_int(code)
        wire = f32(wire * res) if res >= 1 else f32(wire / (1.0 / res))
        return _quantize(f32(wire + _quantize(f32(lo), res, True)), res, True)
    wire = float(code) * res if res >= 1 else float(code) / (1.0 / res)
    return quantize_float(wire + quantize_float(lo, res), res)
