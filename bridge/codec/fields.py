"""Per-field codecs: the ``FieldCodec`` base class and the built-in value types.

A field codec maps one value to an unsigned int of exactly ``bits`` bits and back. These
per-field methods are the readable reference; :mod:`bridge.codec.compile` inlines the
built-in ones into one generated function per layout and checks itself against them.

Rules every codec follows:
- ``encode`` raises :class:`EncodeError` naming the field path for missing/garbage values
  (NaN, inf, wrong type); out-of-range values are clamped and counted in ``clamped``, or
  rejected with ``EncodeError`` when the field's ``on_out_of_range`` is ``reject``.
- ``decode`` raises only :class:`DecodeError` (for codes that no value encodes to).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Sequence
from typing import Any, ClassVar

from bridge.codec.bits import bits_for
from bridge.errors import DecodeError, EncodeError
from bridge.mission.fields import FieldSpec, decimals_of, resolution_levels

__all__ = [
    "ArrayCodec",
    "BoolCodec",
    "BytesCodec",
    "EnumCodec",
    "FieldCodec",
    "FloatCodec",
    "IntCodec",
    "StringCodec",
    "checked_decode",
    "checked_encode",
    "codec_for_type",
]

#: Generated-code helpers get the names they may use from a namespace dict.
Namespace = dict[str, Any]


def _num(x: float) -> str:
    """Short number for ``describe()``: 0.0 -> '0', 6.2831 -> '6.2831'."""
    return f"{x:.10g}"


class FieldCodec:
    """Base class of every field codec, built-in or plug-in (seed 000's ``Field`` plug-ins).

    Subclasses set ``self.bits`` in ``__init__`` and implement ``encode``/``decode``; they read
    their options from ``spec.params`` (available as ``self.params``). Raise ``ValueError`` or
    ``LayoutError`` from ``__init__`` for bad options.
    """

    #: Built-in codecs are trusted to return ints in range; plug-in results are checked.
    trusted: ClassVar[bool] = False
    bits: int = 0

    def __init__(self, spec: FieldSpec) -> None:
        self.spec = spec
        self.path: str = spec.field
        self.params: dict[str, Any] = dict(spec.params)
        self.reject: bool = spec.on_out_of_range == "reject"
        self.clamped: int = 0

    # -- the interface -------------------------------------------------------------------------
    def encode(self, value: Any) -> int:
        """Encode ``value`` into an int ``0 <= n < 2**bits``."""
        raise NotImplementedError

    def decode(self, n: int) -> Any:
        """Decode an int produced by ``encode``; raise ``DecodeError`` for invalid codes."""
        raise NotImplementedError

    def json_schema(self) -> dict[str, Any]:
        """JSON Schema of the (decoded) value."""
        return {}

    def describe(self) -> str:
        """One line for ``zab check``: kind, bits, range, step."""
        return f"{type(self).__name__} {self.bits} bit"

    # -- helpers for subclasses ----------------------------------------------------------------
    @property
    def name(self) -> str:
        """The field path for messages."""
        return self.path or "(payload)"

    def fail(self, message: str) -> EncodeError:
        """An ``EncodeError`` prefixed with the field path (``raise self.fail(...)``)."""
        return EncodeError(f"{self.name}: {message}")

    def bad_code(self, n: int) -> DecodeError:
        """A ``DecodeError`` for a code no value encodes to."""
        return DecodeError(f"{self.name}: invalid code {n}")

    def out_of_range(self, value: Any, lo: Any, hi: Any) -> None:
        """Reject (``EncodeError``) or count one clamped value; the caller then clamps."""
        if self.reject:
            raise self.fail(f"{value!r} is out of range [{lo}, {hi}]")
        self.clamped += 1

    def real(self, value: Any) -> float:
        """``value`` as a finite float, or ``EncodeError``."""
        if not isinstance(value, numbers.Real) or isinstance(value, bool):
            raise self.fail(f"expected a number, got {type(value).__name__} {value!r}")
        x = float(value)
        if not math.isfinite(x):
            raise self.fail(f"{x} is not a finite number")
        return x

    def with_description(self, schema: dict[str, Any]) -> dict[str, Any]:
        """Add the spec's ``description`` to a schema."""
        if self.spec.description:
            schema["description"] = self.spec.description
        return schema

    # -- code generation hooks (optional) ------------------------------------------------------
    def inline_encode(self, v: str, k: str, ns: Namespace, tag: str) -> list[str] | None:
        """Source lines setting ``k`` from ``v`` for the common case, else ``raise _F``.

        ``_F`` sends the whole value to the reference path, which counts/raises. Return None
        (the default) to have the generated code call ``encode`` instead.
        """
        return None

    def inline_decode(self, k: str, ns: Namespace, tag: str) -> tuple[list[str], str] | None:
        """(guard lines, expression) decoding ``k``; guards ``raise _F`` on invalid codes."""
        return None


class FloatCodec(FieldCodec):
    """Bounded float: ``bits`` over [min, max] (both exact), or a ``resolution`` grid."""

    trusted = True

    def __init__(self, spec: FieldSpec) -> None:
        super().__init__(spec)
        assert spec.min is not None and spec.max is not None
        self.lo, self.hi = float(spec.min), float(spec.max)
        span = self.hi - self.lo
        self.resolution = spec.resolution
        if spec.resolution is None:
            assert spec.bits is not None
            self.kmax = (1 << spec.bits) - 1
            self.step = span / self.kmax
            self.inv = self.kmax / span
        else:
            self.kmax = resolution_levels(self.lo, self.hi, spec.resolution) - 1
            self.step = float(spec.resolution)
            self.inv = 1.0 / self.step
        self.bits = bits_for(self.kmax + 1)
        # Exact decimal decoding (0.1 steps print as 12.3, not 12.300000000000001): the value
        # is (lo_units + k * step_units) / scale, a correctly rounded division of integers.
        self.scale = self.lo_units = self.step_units = 0
        if spec.resolution is not None:
            places = max(decimals_of(spec.resolution), decimals_of(self.lo))
            if places <= 15:
                scale = 10**places
                lo_units, step_units = round(self.lo * scale), round(self.step * scale)
                top = abs(lo_units) + self.kmax * step_units
                if top < 2**53 and step_units > 0:
                    self.scale, self.lo_units, self.step_units = scale, lo_units, step_units
        self.needs_cap = int((self.hi - self.lo) * self.inv + 0.5) > self.kmax

    def encode(self, value: Any) -> int:
        x = self.real(value)
        if x < self.lo or x > self.hi:
            self.out_of_range(value, _num(self.lo), _num(self.hi))
            x = self.lo if x < self.lo else self.hi
        return min(int((x - self.lo) * self.inv + 0.5), self.kmax)

    def decode(self, n: int) -> float:
        if n > self.kmax or n < 0:
            raise self.bad_code(n)
        if self.scale:
            return (self.lo_units + n * self.step_units) / self.scale
        return self.hi if n == self.kmax else self.lo + n * self.step

    def json_schema(self) -> dict[str, Any]:
        return self.with_description({"type": "number", "minimum": self.lo, "maximum": self.hi})

    def describe(self) -> str:
        step = f"{self.step:.3g}"
        return f"float {self.bits} bit [{_num(self.lo)}, {_num(self.hi)}] step {step}"

    def inline_encode(self, v: str, k: str, ns: Namespace, tag: str) -> list[str] | None:
        lo, hi, inv = repr(self.lo), repr(self.hi), repr(self.inv)
        offset = v if self.lo == 0.0 else f"({v} - {lo})"
        lines = [
            f"if {lo} <= {v} <= {hi} and {v}.__class__ is not bool:",
            f"    {k} = int({offset} * {inv} + 0.5)",
            "else:",
            "    raise _F",
        ]
        if self.needs_cap:
            lines.append(f"if {k} > {self.kmax}: {k} = {self.kmax}")
        return lines

    def inline_decode(self, k: str, ns: Namespace, tag: str) -> tuple[list[str], str] | None:
        guard = [] if self.kmax + 1 == 1 << self.bits else [f"if {k} > {self.kmax}: raise _F"]
        if self.scale:
            return guard, f"({self.lo_units} + {k} * {self.step_units}) / {self.scale}"
        return guard, f"({self.hi!r} if {k} == {self.kmax} else {self.lo!r} + {k} * {self.step!r})"


class IntCodec(FieldCodec):
    """Bounded int over [min, max] with an optional step (``resolution``, default 1)."""

    trusted = True

    def __init__(self, spec: FieldSpec) -> None:
        super().__init__(spec)
        assert spec.min is not None and spec.max is not None
        self.lo, self.hi = int(spec.min), int(spec.max)
        self.step = int(spec.resolution or 1)
        self.kmax = (self.hi - self.lo) // self.step
        self.bits = bits_for(self.kmax + 1)

    def encode(self, value: Any) -> int:
        if isinstance(value, numbers.Integral) and not isinstance(value, bool):
            x = int(value)
        else:
            f = self.real(value)
            x = math.floor(f + 0.5)
        if x < self.lo or x > self.hi:
            self.out_of_range(value, self.lo, self.hi)
            x = self.lo if x < self.lo else self.hi
        return min((x - self.lo + self.step // 2) // self.step, self.kmax)

    def decode(self, n: int) -> int:
        if n > self.kmax or n < 0:
            raise self.bad_code(n)
        return self.lo + n * self.step

    def json_schema(self) -> dict[str, Any]:
        schema: dict[str, Any] = {"type": "integer", "minimum": self.lo, "maximum": self.hi}
        if self.step != 1:
            schema["multipleOf"] = self.step  # exact when min is a multiple of the step
        return self.with_description(schema)

    def describe(self) -> str:
        step = f" step {self.step}" if self.step != 1 else ""
        return f"int {self.bits} bit [{self.lo}, {self.hi}]{step}"

    def inline_encode(self, v: str, k: str, ns: Namespace, tag: str) -> list[str] | None:
        if self.step == 1:
            expr = f"{v} - {self.lo}" if self.lo else v
        else:
            expr = f"({v} - {self.lo - self.step // 2}) // {self.step}"
        lines = [
            f"if {v}.__class__ is int and {self.lo} <= {v} <= {self.hi}:",
            f"    {k} = {expr}",
            "else:",
            "    raise _F",
        ]
        if self.step != 1 and (self.hi - self.lo + self.step // 2) // self.step > self.kmax:
            lines.append(f"if {k} > {self.kmax}: {k} = {self.kmax}")
        return lines

    def inline_decode(self, k: str, ns: Namespace, tag: str) -> tuple[list[str], str] | None:
        guard = [] if self.kmax + 1 == 1 << self.bits else [f"if {k} > {self.kmax}: raise _F"]
        expr = k if self.step == 1 else f"{k} * {self.step}"
        return guard, (f"{self.lo} + {expr}" if self.lo else expr)


class BoolCodec(FieldCodec):
    """One bit. Accepts ``True``/``False`` (and 0/1)."""

    trusted = True
    bits = 1
    _CODES: ClassVar[dict[Any, int]] = {False: 0, True: 1}

    def encode(self, value: Any) -> int:
        try:
            return self._CODES[value]
        except (KeyError, TypeError):
            raise self.fail(f"expected a bool, got {type(value).__name__} {value!r}") from None

    def decode(self, n: int) -> bool:
        if n not in (0, 1):
            raise self.bad_code(n)
        return n == 1

    def json_schema(self) -> dict[str, Any]:
        return self.with_description({"type": "boolean"})

    def describe(self) -> str:
        return "bool 1 bit"

    def inline_encode(self, v: str, k: str, ns: Namespace, tag: str) -> list[str] | None:
        ns["_BOOL"] = self._CODES
        return [f"{k} = _BOOL[{v}]"]

    def inline_decode(self, k: str, ns: Namespace, tag: str) -> tuple[list[str], str] | None:
        return [], f"{k} == 1"


class EnumCodec(FieldCodec):
    """One of ``values``: accepts the name (or its index), decodes to the name."""

    trusted = True

    def __init__(self, spec: FieldSpec) -> None:
        super().__init__(spec)
        assert spec.values
        self.names: tuple[str, ...] = tuple(spec.values)
        self.codes: dict[str, int] = {name: i for i, name in enumerate(self.names)}
        self.bits = bits_for(len(self.names))

    def encode(self, value: Any) -> int:
        if isinstance(value, str):
            try:
                return self.codes[value]
            except KeyError:
                known = ", ".join(self.names)
                raise self.fail(f"{value!r} is not one of: {known}") from None
        if isinstance(value, numbers.Integral) and not isinstance(value, bool):
            if 0 <= int(value) < len(self.names):
                return int(value)
            raise self.fail(f"index {value} is out of range 0..{len(self.names) - 1}")
        raise self.fail(f"expected a name or index, got {type(value).__name__} {value!r}")

    def decode(self, n: int) -> str:
        if not 0 <= n < len(self.names):
            raise self.bad_code(n)
        return self.names[n]

    def json_schema(self) -> dict[str, Any]:
        return self.with_description({"enum": list(self.names)})

    def describe(self) -> str:
        shown = ", ".join(self.names[:8]) + (", ..." if len(self.names) > 8 else "")
        return f"enum {self.bits} bit {{{shown}}}"

    def inline_encode(self, v: str, k: str, ns: Namespace, tag: str) -> list[str] | None:
        ns[f"_codes{tag}"] = self.codes
        return [f"{k} = _codes{tag}[{v}]"]

    def inline_decode(self, k: str, ns: Namespace, tag: str) -> tuple[list[str], str] | None:
        ns[f"_names{tag}"] = self.names
        return [], f"_names{tag}[{k}]"  # IndexError -> reference path -> DecodeError


class _ByteField(FieldCodec):
    """Shared by ``string`` and ``bytes``: fixed ``length`` or bounded ``max_length``.

    Fixed: N bytes, zero-padded. Bounded: a length prefix of ceil(log2(N+1)) bits, then N bytes
    (the channel keeps a fixed bit length). Too long = out of range: clamp truncates (counted).
    """

    trusted = True
    kind = "bytes"

    def __init__(self, spec: FieldSpec) -> None:
        super().__init__(spec)
        self.fixed = spec.length is not None
        self.size: int = spec.length if spec.length is not None else spec.max_length  # type: ignore[assignment]
        self.prefix_bits = 0 if self.fixed else bits_for(self.size + 1)
        self.bits = self.prefix_bits + 8 * self.size

    def to_bytes(self, value: Any) -> bytes:
        """The value's bytes before fitting."""
        raise NotImplementedError

    def truncate(self, data: bytes) -> bytes:
        """Cut ``data`` to ``size`` bytes."""
        return data[: self.size]

    def encode(self, value: Any) -> int:
        data = self.to_bytes(value)
        if len(data) > self.size:
            self.out_of_range(f"{len(data)} bytes", 0, f"{self.size} bytes")
            data = self.truncate(data)
        body = int.from_bytes(data.ljust(self.size, b"\0"), "big")
        return body if self.fixed else (len(data) << (8 * self.size)) | body

    def split(self, n: int) -> bytes:
        """The payload bytes held in code ``n``."""
        if n < 0 or n >> self.bits:
            raise self.bad_code(n)
        data = (n & ((1 << (8 * self.size)) - 1)).to_bytes(self.size, "big")
        if self.fixed:
            return data
        length = n >> (8 * self.size)
        if length > self.size:
            raise DecodeError(f"{self.name}: length {length} exceeds max_length {self.size}")
        return data[:length]

    def describe(self) -> str:
        size = f"{self.size} byte" if self.fixed else f"≤{self.size} byte"
        return f"{self.kind} {size} ({self.bits} bit)"


class StringCodec(_ByteField):
    """Strict UTF-8 text. Fixed length strips trailing NULs on decode. A value that is not
    valid Unicode (a lone surrogate, as a JSON ``"\\ud800"`` escape gives) is an
    ``EncodeError``, and bytes that are not valid UTF-8 a ``DecodeError``: never replaced."""

    kind = "string"

    def to_bytes(self, value: Any) -> bytes:
        if not isinstance(value, str):
            raise self.fail(f"expected a string, got {type(value).__name__}")
        try:
            return value.encode("utf-8")
        except UnicodeEncodeError as exc:
            raise self.fail(f"not valid Unicode text: {exc.reason} at {exc.start}") from None

    def truncate(self, data: bytes) -> bytes:
        # Never cut a character in half.
        return data[: self.size].decode("utf-8", errors="ignore").encode("utf-8")

    def decode(self, n: int) -> str:
        data = self.split(n)
        if self.fixed:
            data = data.rstrip(b"\0")
        try:
            return data.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise DecodeError(f"{self.name}: not valid UTF-8: {exc.reason} at byte {exc.start}"
                              ) from None

    def json_schema(self) -> dict[str, Any]:
        return self.with_description({"type": "string", "maxLength": self.size})


class BytesCodec(_ByteField):
    """Raw bytes. Fixed length pads short values with zero bytes and decodes all N bytes."""

    kind = "bytes"

    def to_bytes(self, value: Any) -> bytes:
        if not isinstance(value, bytes | bytearray | memoryview):
            raise self.fail(f"expected bytes, got {type(value).__name__}")
        return bytes(value)

    def decode(self, n: int) -> bytes:
        return self.split(n)

    def json_schema(self) -> dict[str, Any]:
        schema = {"type": "string", "contentEncoding": "base64", "x-max-bytes": self.size}
        return self.with_description(schema)


def checked_encode(codec: FieldCodec) -> Callable[[Any], int]:
    """``codec.encode``, wrapped for plug-ins so a bad result can never corrupt its neighbours."""
    if codec.trusted:
        return codec.encode
    limit = 1 << codec.bits

    def encode(value: Any) -> int:
        try:
            k = codec.encode(value)
        except EncodeError:
            raise
        except Exception as exc:
            raise codec.fail(f"{type(codec).__name__}.encode failed: {exc!r}") from exc
        if isinstance(k, bool) or not isinstance(k, numbers.Integral) or not 0 <= k < limit:
            raise codec.fail(f"{type(codec).__name__}.encode returned {k!r}, not 0..{limit - 1}")
        return int(k)

    return encode


def checked_decode(codec: FieldCodec) -> Callable[[int], Any]:
    """``codec.decode``, wrapped for plug-ins so it raises nothing but ``DecodeError``."""
    if codec.trusted:
        return codec.decode

    def decode(n: int) -> Any:
        try:
            return codec.decode(n)
        except DecodeError:
            raise
        except Exception as exc:
            raise DecodeError(
                f"{codec.name}: {type(codec).__name__}.decode failed: {exc!r}"
            ) from exc

    return decode


class ArrayCodec(FieldCodec):
    """``count`` values of one element codec; the payload value is a list (first = high bits)."""

    trusted = True

    def __init__(self, spec: FieldSpec, element: FieldCodec, count: int) -> None:
        self.element = element
        super().__init__(spec)
        self.count = count
        self.bits = element.bits * count
        self._encode_element = checked_encode(element)
        self._decode_element = checked_decode(element)

    @property
    def clamped(self) -> int:
        """Clamps counted by the element codec."""
        return self.element.clamped

    @clamped.setter
    def clamped(self, value: int) -> None:
        self.element.clamped = value

    def encode(self, value: Any) -> int:
        if isinstance(value, str | bytes) or not isinstance(value, Sequence):
            raise self.fail(f"expected a list of {self.count}, got {type(value).__name__}")
        if len(value) != self.count:
            raise self.fail(f"expected a list of {self.count}, got {len(value)} items")
        n, width = 0, self.element.bits
        for item in value:
            n = (n << width) | self._encode_element(item)
        return n

    def decode(self, n: int) -> list[Any]:
        if n < 0 or n >> self.bits:
            raise self.bad_code(n)
        width = self.element.bits
        mask = (1 << width) - 1
        shifts = range(width * (self.count - 1), -1, -width) if width else [0] * self.count
        return [self._decode_element((n >> s) & mask) for s in shifts]

    def json_schema(self) -> dict[str, Any]:
        return {
            "type": "array",
            "items": self.element.json_schema(),
            "minItems": self.count,
            "maxItems": self.count,
        }

    def describe(self) -> str:
        return f"{self.count} × {self.element.describe()}"


_BY_TYPE: dict[str, type[FieldCodec]] = {
    "float": FloatCodec,
    "int": IntCodec,
    "bool": BoolCodec,
    "enum": EnumCodec,
    "string": StringCodec,
    "bytes": BytesCodec,
}


def codec_for_type(kind: str) -> type[FieldCodec]:
    """Built-in codec class of a ``type``."""
    return _BY_TYPE[kind]
