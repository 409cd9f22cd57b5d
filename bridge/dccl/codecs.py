"""libdccl's default field codecs (``dccl.default4``, and 3 and 5), the readable reference path.

Every codec turns one value into ``(code, width)``: ``code`` holds ``width`` bits, least
significant bit first on the wire (DCCL's Bitset grows toward the most significant end and is
written out least significant byte first). Absent optional values are ``None``.

* numeric (int*/uint*/float/double/enum): ``ceil_log2((max-min)/res + 1 [+1 if optional])``
  bits; optional fields reserve code 0 for "not present"; the code is computed by the
  mission's numeric rule (:mod:`bridge.dccl.numeric`). Out of range: strict → error, otherwise
  all-zero bits (so an optional field arrives absent, a required one as ``min``).
* bool: 1 bit required, 2 bits optional (0 absent, 1 false, 2 true).
* string / bytes (``VarBytesCodec``): [presence bit if optional][length:
  ``ceil_log2(max_length+1)`` bits][bytes]; too long: strict → error, otherwise truncated.
* embedded message: [presence bit if optional][fields]; absent: the single 0 bit.
* repeated: [count - min_repeat: ``ceil_log2(max_repeat-min_repeat+1)`` bits][elements];
  elements use the required encoding.

Decoding keeps what libdccl keeps: a required field whose code means "none" (an enum code past
the values, a version 3 empty string) is left unset, a string that is not UTF-8 comes back as
its bytes, a length or count past ``max_length``/``max_repeat`` is decoded whole (but more
embedded messages than ``max_repeat`` is refused, as libdccl has only that many to fill).

"Optional" means codec version 4's ``use_required() == False``: an ``optional`` field that is
neither repeated nor part of a ``oneof``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from bridge.dccl import numeric
from bridge.errors import DecodeError, EncodeError

__all__ = ["ABSENT", "BitReader", "BoolCodec", "BytesCodec", "DcclRangeError", "FieldCodec",
           "FixedBytesCodec", "MessageCodec", "NumericCodec", "RepeatedCodec", "StringCodecV3"]


class _Absent:
    def __repr__(self) -> str:
        return "ABSENT"


#: What a decoder returns for a field that is not present.
ABSENT: Any = _Absent()


class DcclRangeError(EncodeError):
    """A value outside its bounds in strict mode (libdccl's ``OutOfRangeException``)."""


class BitReader:
    """Reads little-endian bit fields from an int holding ``limit`` bits."""

    __slots__ = ("limit", "n", "pos")

    def __init__(self, n: int, limit: int, pos: int = 0) -> None:
        self.n, self.limit, self.pos = n, limit, pos

    def read(self, width: int) -> int:
        end = self.pos + width
        if end > self.limit:
            raise DecodeError(f"truncated: needs bit {end}, the buffer has {self.limit}")
        value = (self.n >> self.pos) & ((1 << width) - 1)
        self.pos = end
        return value


class FieldCodec:
    """Base: a named field codec with DCCL's size facts."""

    codec_name = "dccl.default4"
    min_bits = 0
    max_bits = 0

    def __init__(self, path: str, required: bool) -> None:
        self.path = path
        self.required = required

    def encode(self, value: Any, strict: bool) -> tuple[int, int]:
        raise NotImplementedError

    def encode_empty(self) -> tuple[int, int]:
        """An element libdccl adds to reach ``min_repeat``, or an absent field: zero bits."""
        return 0, self.min_bits

    def decode(self, reader: BitReader) -> Any:
        raise NotImplementedError

    @property
    def variable(self) -> bool:
        return self.min_bits != self.max_bits


INT_RANGES = {
    "int32": (-(1 << 31), (1 << 31) - 1), "sint32": (-(1 << 31), (1 << 31) - 1),
    "sfixed32": (-(1 << 31), (1 << 31) - 1), "int64": (-(1 << 63), (1 << 63) - 1),
    "sint64": (-(1 << 63), (1 << 63) - 1), "sfixed64": (-(1 << 63), (1 << 63) - 1),
    "uint32": (0, (1 << 32) - 1), "fixed32": (0, (1 << 32) - 1),
    "uint64": (0, (1 << 64) - 1), "fixed64": (0, (1 << 64) - 1),
}


class NumericCodec(FieldCodec):
    """Bounded integer, float or double (``DefaultNumericFieldCodec``) under a numeric rule
    (:data:`bridge.dccl.numeric.RULES`)."""

    def __init__(self, path: str, required: bool, kind: str, lo: float, hi: float,
                 res: float, rule: str = numeric.DEFAULT_RULE) -> None:
        super().__init__(path, required)
        self.kind, self.lo, self.hi, self.res, self.rule = kind, lo, hi, res, rule
        self.is_float = kind in ("double", "float")
        self.single = kind == "float"
        self.wire = kind if self.is_float else numeric.wire_kind(kind)
        self.bits = numeric.size_bits(lo, hi, res, required)
        self.min_bits = self.max_bits = self.bits
        self.offset = 0 if required else 1

    def in_range(self, v: Any) -> bool:
        return numeric.in_range(v, self.lo, self.hi, self.res, self.wire, self.rule)

    def to_wire(self, value: Any) -> Any:
        """Check the Python type; the number the codec sees (float32-rounded for floats)."""
        if self.is_float:
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise EncodeError(f"{self.path}: expected a number, got {type(value).__name__}")
            try:
                value = float(value)
            except OverflowError:
                raise EncodeError(f"{self.path}: {value} is too large for a double") from None
            return numeric.f32(value) if self.single else value
        if isinstance(value, bool) or not isinstance(value, int):
            raise EncodeError(f"{self.path}: expected an int, got {type(value).__name__}")
        lo, hi = INT_RANGES[self.kind]
        if not lo <= value <= hi:
            raise EncodeError(f"{self.path}: {value} does not fit a {self.kind}")
        return value

    def code(self, v: Any, strict: bool) -> int:
        """Code of a wire value: the bits libdccl writes (before masking)."""
        if not self.in_range(v):
            if strict:
                raise DcclRangeError(f"{self.path}: {v!r} exceeds min/max bounds "
                                     f"[{self.lo:g}, {self.hi:g}]")
            return 0
        if self.is_float:
            k = numeric.encode_float(v, self.lo, self.res, self.single, self.rule)
        else:
            k = numeric.encode_int(v, self.lo, self.res, self.wire)
        return (k + self.offset) & ((1 << self.bits) - 1)

    def encode(self, value: Any, strict: bool) -> tuple[int, int]:
        if value is None:
            return 0, self.bits
        return self.code(self.to_wire(value), strict), self.bits

    def value_of(self, k: int) -> Any:
        """Decoded value of a code (``ABSENT`` for an optional field's 0)."""
        if not self.required:
            if k == 0:
                return ABSENT
            k -= 1
        if self.is_float:
            return numeric.decode_float(k, self.lo, self.res, self.single, self.rule)
        return numeric.decode_int(k, self.lo, self.res, self.wire)

    def decode(self, reader: BitReader) -> Any:
        return self.value_of(reader.read(self.bits))


class EnumCodec(NumericCodec):
    """Enum by declaration index (``packed_enum``, the default) or by value number."""

    def __init__(self, path: str, required: bool, values: Sequence[tuple[str, int]],
                 packed: bool) -> None:
        self.names = [n for n, _ in values]
        self.numbers = [v for _, v in values]
        self.packed = packed
        if packed:
            lo, hi = 0, len(values) - 1
            self.index: dict[str | int, int] = {n: i for i, n in enumerate(self.names)}
            self.index.update({v: i for i, v in enumerate(self.numbers) if v not in self.index})
        else:
            lo, hi = min(self.numbers), max(self.numbers)
        self.by_number = {v: n for n, v in reversed(values)}
        super().__init__(path, required, "int32", lo, hi, 1.0)

    def to_wire(self, value: Any) -> Any:
        if isinstance(value, str):
            if value not in self.names:
                raise EncodeError(f"{self.path}: {value!r} is not one of {self.names}")
            i = self.names.index(value)
            return i if self.packed else self.numbers[i]
        if isinstance(value, int) and not isinstance(value, bool) and value in self.by_number:
            return self.names.index(self.by_number[value]) if self.packed else value
        raise EncodeError(f"{self.path}: {value!r} is not a value of the enum")

    def value_of(self, k: int) -> Any:
        if not self.required:
            if k == 0:
                return ABSENT
            k -= 1
        if self.packed:
            return self.names[k] if k < len(self.names) else ABSENT
        return self.by_number.get(k + int(self.lo), ABSENT)


class BoolCodec(FieldCodec):
    """``DefaultBoolCodec``: 1 bit, or 2 with the "not present" value when optional."""

    def __init__(self, path: str, required: bool) -> None:
        super().__init__(path, required)
        self.bits = self.min_bits = self.max_bits = 1 if required else 2

    def encode(self, value: Any, strict: bool) -> tuple[int, int]:
        if value is None:
            return 0, self.bits
        if not isinstance(value, bool):
            raise EncodeError(f"{self.path}: expected a bool, got {type(value).__name__}")
        return int(value) + (0 if self.required else 1), self.bits

    def decode(self, reader: BitReader) -> Any:
        k = reader.read(self.bits)
        if self.required:
            return bool(k)
        return ABSENT if k == 0 else bool(k - 1)


def text(data: bytes) -> str | bytes:
    """A decoded string: ``str`` when its bytes are UTF-8, else the bytes as libdccl holds them
    (a protobuf ``string`` field is not checked); string fields encode such bytes back."""
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return data


class BytesCodec(FieldCodec):
    """``VarBytesCodec`` (strings and bytes in codec version 4)."""

    def __init__(self, path: str, required: bool, max_length: int, text: bool) -> None:
        super().__init__(path, required)
        self.max_length, self.text = max_length, text
        self.presence = 0 if required else 1
        self.prefix = numeric.ceil_log2(max_length + 1)
        self.min_bits = self.prefix if required else self.presence
        self.max_bits = self.presence + self.prefix + 8 * max_length

    def encode(self, value: Any, strict: bool) -> tuple[int, int]:
        if value is None:
            return 0, self.min_bits
        if self.text and isinstance(value, str):
            data = value.encode("utf-8")
        elif isinstance(value, bytes | bytearray | memoryview):
            data = bytes(value)  # a string field's bytes that are not UTF-8, as decoded
        else:
            kind = "a string" if self.text else "bytes"
            raise EncodeError(f"{self.path}: expected {kind}, got {type(value).__name__}")
        if len(data) > self.max_length:
            if strict:
                raise DcclRangeError(f"{self.path}: {len(data)} bytes exceed max_length "
                                     f"{self.max_length}")
            data = data[: self.max_length]
        head = len(data) << self.presence | self.presence
        width = self.presence + self.prefix
        return head | int.from_bytes(data, "little") << width, width + 8 * len(data)

    def decode(self, reader: BitReader) -> Any:
        if self.presence and not reader.read(1):
            return ABSENT
        length = reader.read(self.prefix)
        data = reader.read(8 * length).to_bytes(length, "little")
        return text(data) if self.text else data


class StringCodecV3(FieldCodec):
    """Codec version 3's string: [length: ``ceil_log2(max_length+1)`` bits][bytes], no presence
    bit; an absent string is length 0, and length 0 decodes as absent (required or repeated
    alike, as libdccl leaves the field unset)."""

    def __init__(self, path: str, required: bool, max_length: int) -> None:
        super().__init__(path, required)
        self.max_length = max_length
        self.prefix = numeric.ceil_log2(max_length + 1)
        self.min_bits = self.prefix
        self.max_bits = self.prefix + 8 * max_length

    def encode(self, value: Any, strict: bool) -> tuple[int, int]:
        if value is None:
            return 0, self.prefix
        if isinstance(value, str):
            data = value.encode("utf-8")
        elif isinstance(value, bytes | bytearray | memoryview):
            data = bytes(value)  # bytes that are not UTF-8, as decoded
        else:
            raise EncodeError(f"{self.path}: expected a string, got {type(value).__name__}")
        if len(data) > self.max_length:
            if strict:
                raise DcclRangeError(f"{self.path}: {len(data)} bytes exceed max_length "
                                     f"{self.max_length}")
            data = data[: self.max_length]
        return len(data) | int.from_bytes(data, "little") << self.prefix, (
            self.prefix + 8 * len(data))

    def decode(self, reader: BitReader) -> Any:
        length = reader.read(self.prefix)
        if not length:
            return ABSENT
        return text(reader.read(8 * length).to_bytes(length, "little"))


class FixedBytesCodec(FieldCodec):
    """Codec versions 2 and 3's bytes: always ``max_length`` bytes (shorter values zero-padded,
    longer ones cut), after a presence bit when optional."""

    def __init__(self, path: str, required: bool, max_length: int) -> None:
        super().__init__(path, required)
        self.max_length = max_length
        self.presence = 0 if required else 1
        self.max_bits = 8 * max_length + self.presence
        self.min_bits = self.max_bits if required else 1

    def encode(self, value: Any, strict: bool) -> tuple[int, int]:
        if value is None:
            return 0, self.min_bits
        if not isinstance(value, bytes | bytearray | memoryview):
            raise EncodeError(f"{self.path}: expected bytes, got {type(value).__name__}")
        data = bytes(value)
        if len(data) > self.max_length:
            if strict:
                raise DcclRangeError(f"{self.path}: {len(data)} bytes exceed max_length "
                                     f"{self.max_length}")
            data = data[: self.max_length]
        return int.from_bytes(data, "little") << self.presence | self.presence, self.max_bits

    def decode(self, reader: BitReader) -> Any:
        if self.presence and not reader.read(1):
            return ABSENT
        return reader.read(8 * self.max_length).to_bytes(self.max_length, "little")


class RepeatedCodec(FieldCodec):
    """A repeated field: count prefix (offset by ``min_repeat``), then the elements."""

    def __init__(self, path: str, element: FieldCodec, min_repeat: int, max_repeat: int) -> None:
        super().__init__(path, True)
        self.element, self.min_repeat, self.max_repeat = element, min_repeat, max_repeat
        self.prefix = numeric.ceil_log2(max_repeat - min_repeat + 1)
        self.min_bits = self.prefix + element.min_bits * min_repeat
        self.max_bits = self.prefix + element.max_bits * max_repeat
        self.codec_name = element.codec_name

    def encode(self, value: Any, strict: bool) -> tuple[int, int]:
        if value is None:
            value = []
        if not isinstance(value, list | tuple):
            raise EncodeError(f"{self.path}: expected a list, got {type(value).__name__}")
        n = len(value)
        if strict and n > self.max_repeat:
            raise DcclRangeError(f"{self.path}: {n} values exceed max_repeat {self.max_repeat}")
        if strict and n < self.min_repeat:
            raise DcclRangeError(f"{self.path}: {n} values are fewer than min_repeat "
                                 f"{self.min_repeat}")
        if n > self.max_repeat and isinstance(self.element, MessageCodec):
            for item in value[self.max_repeat:]:  # protobuf checks the dropped tail too
                if isinstance(item, dict) and self.element.missing(item) is not None:
                    raise EncodeError(f"{self.path}: required field missing past max_repeat "
                                      "(DCCL: Message is not properly initialized)")
        count = max(self.min_repeat, min(self.max_repeat, n))
        code, width = count - self.min_repeat, self.prefix
        for i in range(count):
            if i < n:
                if value[i] is None:
                    raise EncodeError(f"{self.path}[{i}]: missing")
                k, w = self.element.encode(value[i], strict)
            else:
                k, w = self.element.encode_empty()
            code |= k << width
            width += w
        return code, width

    def decode(self, reader: BitReader) -> Any:
        count = reader.read(self.prefix) + self.min_repeat
        if count > self.max_repeat and isinstance(self.element, MessageCodec):
            # libdccl decodes into max_repeat messages made beforehand, and refuses more; a
            # longer list of other values, or a string past max_length, it decodes whole
            raise DecodeError(f"{self.path}: {count} messages exceed max_repeat "
                              f"{self.max_repeat}")
        out = []
        for _ in range(count):
            v = self.element.decode(reader)
            if v is not ABSENT:  # a v3 empty string, an enum code past the values
                out.append(v)
        return out


class MessageCodec(FieldCodec):
    """An embedded message (``DefaultMessageCodec`` v4): presence bit when optional, then one
    case per ``oneof`` (``ceil_log2(members + 1)`` bits: 0 unset, else the member's index + 1),
    then the fields in declaration order, a ``oneof`` member only when it is the one set."""

    def __init__(self, path: str, required: bool, fields: Sequence[tuple[str, FieldCodec]],
                 numbers: dict[str, int] | None = None,
                 oneofs: Sequence[tuple[str, Sequence[str]]] = ()) -> None:
        super().__init__(path, required)
        self.fields = tuple(fields)
        self.numbers = numbers or {}  # field numbers, for analyze
        self.oneofs = tuple((name, tuple(members)) for name, members in oneofs)
        self.case_bits = tuple(numeric.ceil_log2(len(m) + 1) for _, m in self.oneofs)
        self.member_of = {n: (i, j) for i, (_, members) in enumerate(self.oneofs)
                          for j, n in enumerate(members)}
        self.presence = 0 if required else 1
        sizes = dict(self.fields)
        plain = [c for n, c in self.fields if n not in self.member_of]
        cases = sum(self.case_bits)
        inner_min = cases + sum(c.min_bits for c in plain)
        self.max_bits = (self.presence + cases + sum(c.max_bits for c in plain)
                         + sum(max((sizes[n].max_bits for n in m if n in sizes), default=0)
                               for _, m in self.oneofs))
        self.min_bits = 1 if not required else inner_min

    def encode(self, value: Any, strict: bool) -> tuple[int, int]:
        if value is None:
            return 0, self.min_bits
        if not isinstance(value, dict):
            raise EncodeError(f"{self.path}: expected a mapping, got {type(value).__name__}")
        code, width = self.presence, self.presence
        for (oneof, members), bits in zip(self.oneofs, self.case_bits, strict=True):
            chosen = [j for j, n in enumerate(members) if value.get(n) is not None]
            if len(chosen) > 1:
                raise EncodeError(f"{self.path or 'message'}: oneof {oneof!r} has more than one "
                                  f"of {', '.join(members[j] for j in chosen)} set")
            code |= (chosen[0] + 1 if chosen else 0) << width
            width += bits
        for name, codec in self.fields:
            item = value.get(name)
            if name in self.member_of:
                if item is None:
                    continue
            elif item is None and codec.required and not isinstance(codec, RepeatedCodec):
                raise EncodeError(f"{codec.path}: required field missing")
            k, w = codec.encode(item, strict)
            code |= k << width
            width += w
        return code, width

    def encode_empty(self) -> tuple[int, int]:
        return 0, self.min_bits

    def missing(self, value: dict[str, Any]) -> str | None:
        """The path of a required field that ``value`` leaves unset, here or in an embedded
        message (every element of a list, past ``max_repeat`` too), as protobuf's
        ``IsInitialized`` finds it; None if there is none."""
        for name, codec in self.fields:
            item = value.get(name)
            repeated = isinstance(codec, RepeatedCodec)
            if item is None:
                if codec.required and not repeated and name not in self.member_of:
                    return codec.path
                continue
            inner = codec.element if isinstance(codec, RepeatedCodec) else codec
            if isinstance(inner, MessageCodec):
                for element in item if repeated and isinstance(item, list | tuple) else [item]:
                    found = inner.missing(element) if isinstance(element, dict) else None
                    if found is not None:
                        return found
        return None

    def decode_fields(self, reader: BitReader) -> dict[str, Any]:
        out: dict[str, Any] = {}
        cases = [reader.read(bits) for bits in self.case_bits]
        for name, codec in self.fields:
            if name in self.member_of:
                i, j = self.member_of[name]
                if cases[i] != j + 1:
                    continue
            v = codec.decode(reader)
            if v is not ABSENT:  # a required field may come back unset, as from libdccl
                out[name] = v
        return out

    def decode(self, reader: BitReader) -> Any:
        if self.presence and not reader.read(1):
            return ABSENT
        return self.decode_fields(reader)
