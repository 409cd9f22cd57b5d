"""Generate one Python ``encode`` and one ``decode`` function per DCCL message.

Fixed-size fields (bounded numbers, bools, enums, fixed-count repeats of those, required
embedded messages made of them) are inlined with constant shifts; anything else (strings,
bytes, variable repeats, optional messages, float32 fields) calls its reference codec and the
rest of the message continues at a running bit offset.

As in :mod:`bridge.codec.compile`, the generated code handles only the ordinary case: a wrong
type, a missing key, an out-of-range value, a quotient within rounding error of a half (where
a double division could round differently from libdccl's exact division), a truncated buffer
or an invalid code raises, and the whole call is redone by the message's reference path. So
the two paths can never disagree, about bytes or about errors.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

from bridge.dccl import numeric
from bridge.dccl.codecs import (
    ABSENT,
    INT_RANGES,
    BitReader,
    BoolCodec,
    EnumCodec,
    FieldCodec,
    MessageCodec,
    NumericCodec,
    RepeatedCodec,
)

__all__ = ["Compiled", "DcclMessage", "compile_message"]


class DcclMessage(Protocol):
    """What compiling reads of a :class:`bridge.dccl.message.DcclMessage` (which compiles
    itself when built: a protocol here, so the two files do not import each other)."""

    name: str
    id: int
    omit_id: bool
    id_bits: int
    head: list[tuple[str, FieldCodec]]
    head_bytes: int
    body: list[tuple[str, FieldCodec]]
    body_codec: MessageCodec

    def encode_head(self, value: Any, strict: bool = False) -> bytes: ...

    def encode_reference(self, value: Any, strict: bool = False) -> bytes: ...

    def decode_reference(self, data: Any) -> tuple[dict[str, Any], int]: ...

#: Largest margin around a half (quotient units) sent to the exact reference division; a
#: field whose double quotient may be further off than this is never inlined.
_MAX_GUARD = 1e-3


def _guard(c: NumericCodec) -> float:
    """Bound on |double quotient - exact quotient| for ``c``'s in-range values, with room:
    a correctly rounded division is within half an ulp of the largest quotient (2**-53)."""
    return (max(abs(c.lo), abs(c.hi)) / c.res + 2) * 2.0**-50 + 1e-12


def _small(c: NumericCodec) -> bool:
    """Fewer than 2**47 steps from zero to either bound: then, for an integer ``n`` of the
    field, ``(n / inv) * inv`` and the like are within 0.25 of ``n`` (a few roundings of at
    most 2**-53 each, relative), so libdccl's ``floor(... + 0.5)`` gives ``n`` itself and the
    generated code may use ``n`` without computing the roundings."""
    return max(abs(c.lo), abs(c.hi)) / c.res < 2.0**47 and c.bits <= 47


def _steps(value: float, res: float) -> int:
    """dccl-4.2's quantisation of ``value`` in steps: ``floor(value / res + 0.5)`` as libdccl
    computes it (multiplying by ``1 / res`` below 1)."""
    return math.floor(value / res + 0.5) if res >= 1 else math.floor(value * (1.0 / res) + 0.5)


def _minus(x: str, c: float) -> str:
    """Code for the double ``x - c``: the same double as C's (``x - 0.0`` is ``x``, and
    subtracting a negative is adding its magnitude)."""
    if c == 0:
        return x
    return f"({x} - {c!r})" if c > 0 else f"({x} + {-c!r})"


class _Fallback(Exception):
    """Internal: leave the fast path."""


@dataclass(frozen=True)
class Compiled:
    """The generated functions and their source."""

    source: str
    encode: Callable[[Any], bytes]
    encode_strict: Callable[[Any], bytes]
    decode: Callable[[bytes], tuple[dict[str, Any], int]]


def _inline_numeric(c: FieldCodec) -> bool:
    """A numeric codec the generated code computes itself."""
    if isinstance(c, EnumCodec):
        return True
    if not isinstance(c, NumericCodec) or c.single or c.bits > 53:
        return False
    if c.is_float:  # dccl-2026: the double quotient must be within the guard of the exact one
        return c.rule == "dccl-4.2" or _guard(c) < _MAX_GUARD
    # integers in steps of 1 whose codes and values are exact doubles and never wrap
    low, high = INT_RANGES[c.kind]
    return (c.res == 1.0 and c.lo == int(c.lo) and max(abs(c.lo), abs(c.hi)) < 2.0**53
            and low <= c.lo and c.lo + (1 << c.bits) - 1 <= high)


def _fixed(c: FieldCodec) -> bool:
    """Inlined with constant widths (the offset after it is known at compile time)."""
    if isinstance(c, BoolCodec) or _inline_numeric(c):
        return True
    if isinstance(c, RepeatedCodec):
        return c.min_repeat == c.max_repeat and _fixed(c.element)
    if isinstance(c, MessageCodec):
        return (c.required and not c.oneofs
                and all(_fixed(f) for _, f in c.fields))
    return False


def _certain(c: FieldCodec) -> bool:
    """Decoded by the generated code into a value, never ``ABSENT`` (a required field that
    is inlined, or a list)."""
    return isinstance(c, RepeatedCodec) or (c.required and _fixed(c))


class _Gen:
    """Accumulates generated lines and constants."""

    def __init__(self) -> None:
        self.ns: dict[str, Any] = {"_F": _Fallback, "_floor": math.floor, "_BR": BitReader,
                                   "_ABSENT": ABSENT}
        self.lines: list[str] = []
        self.count = 0

    def name(self, prefix: str) -> str:
        self.count += 1
        return f"{prefix}{self.count}"

    def const(self, prefix: str, value: Any) -> str:
        name = self.name(prefix)
        self.ns[name] = value
        return name


# -- encoder ------------------------------------------------------------------------------------
class _Enc:
    """Emits code that ORs each field's code into ``acc`` at offset ``o`` (+ static part)."""

    def __init__(self, gen: _Gen, acc: str) -> None:
        self.g, self.acc = gen, acc
        self.static = 0  # bits since the dynamic offset ``o`` (or since 0 when not dynamic)
        self.dynamic = False
        self.terms: list[str] = []

    def put(self, code: str, width: int, ind: str) -> None:
        if width == 0:
            return
        if not self.dynamic:
            self.terms.append(f"{code} << {self.static}" if self.static else code)
        else:
            shift = f"(o + {self.static})" if self.static else "o"
            self.g.lines.append(f"{ind}{self.acc} |= {code} << {shift}")
        self.static += width

    def flush(self, ind: str) -> None:
        """Before a variable-size field: fold the constant terms, start the running offset."""
        if not self.dynamic:
            if self.terms:
                self.g.lines.append(f"{ind}{self.acc} |= " + " | ".join(self.terms))
            self.terms = []
            self.g.lines.append(f"{ind}o = {self.static}")
            self.dynamic = True
        elif self.static:
            self.g.lines.append(f"{ind}o += {self.static}")
        self.static = 0

    def numeric(self, c: NumericCodec, x: str, ind: str) -> str:
        g, k = self.g, self.g.name("k")
        lines = g.lines
        if isinstance(c, EnumCodec):
            table = {n: (i if c.packed else num - int(c.lo)) + c.offset
                     for i, (n, num) in enumerate(zip(c.names, c.numbers, strict=True))}
            lines.append(f"{ind}{k} = {g.const('_E', table)}[{x}]")
            return k
        lo_t, hi_t = c.lo - c.res / 2, c.hi + c.res / 2
        if c.is_float and c.rule == "dccl-4.2":  # libdccl's own double arithmetic
            return self._release_float(c, x, ind)
        if c.is_float:  # an int divides as float(int) would, as the reference converts it
            lines.append(f"{ind}if {x}.__class__ is not float and {x}.__class__ is not int or "
                         f"not {lo_t!r} <= {x} < {hi_t!r}: raise _F")
            a = g.name("a")
            lines.append(f"{ind}{a} = {x} / {c.res!r}")
            # rounding half up, not away from zero: the guard below sends every half away
            if c.lo >= 0:  # then a >= -1/2 and int() is floor
                lines.append(f"{ind}{k} = int({a} + 0.5)")
            else:
                lines.append(f"{ind}{k} = _floor({a} + 0.5)")
            guard = _guard(c)
            shift = c.offset - numeric.round_div(c.lo, c.res)
            lines.append(f"{ind}if not {-0.5 + guard!r} < {a} - {k} < {0.5 - guard!r} or not "
                         f"{-shift} <= {k} <= {(1 << c.bits) - 1 - shift}: raise _F")
        else:
            lines.append(f"{ind}if {x}.__class__ is not int or not {lo_t!r} <= {x} < {hi_t!r}: "
                         "raise _F")
            k = x
            shift = c.offset - int(c.lo)
        return f"({k} + {shift})" if shift > 0 else f"({k} - {-shift})" if shift else k

    def _release_float(self, c: NumericCodec, x: str, ind: str) -> str:
        """dccl-4.2: quantise (``F = floor(x / res + 0.5)``, the quantised value ``F * res``),
        check the bounds on the quantised value, and the code: the rounded scaled difference from
        the quantised minimum, which for a field of fewer than 2**47 steps is exactly ``F - Q``
        (``Q`` the minimum's ``F``; see :func:`_small`). NaN, infinities and codes out of the
        field go to the reference path."""
        lines, f, q = self.g.lines, self.g.name("f"), self.g.name("q")
        lines.append(f"{ind}if {x}.__class__ is not float and {x}.__class__ is not int: raise _F")
        if c.res >= 1:
            lines.append(f"{ind}{f} = _floor({x} / {c.res!r} + 0.5)")
            lines.append(f"{ind}{q} = {f} * {c.res!r}")
        else:
            inv = 1.0 / c.res
            lines.append(f"{ind}{f} = _floor({x} * {inv!r} + 0.5)")
            lines.append(f"{ind}{q} = {f} / {inv!r}")
        if _small(c):
            first = _steps(c.lo, c.res)
            last = first + (1 << c.bits) - 1 - c.offset
            lines.append(f"{ind}if not ({c.lo!r} <= {q} <= {c.hi!r} and "
                         f"{first} <= {f} <= {last}): raise _F")
            shift = c.offset - first
            return f"({f} + {shift})" if shift > 0 else f"({f} - {-shift})" if shift else f
        a = self.g.name("a")
        diff = _minus(q, numeric.quantize_float(c.lo, c.res))
        scaled = f"{diff} / {c.res!r}" if c.res >= 1 else f"{diff} * {1.0 / c.res!r}"
        lines.append(f"{ind}{a} = {scaled} + 0.5")
        lines.append(f"{ind}if not ({c.lo!r} <= {q} <= {c.hi!r} and "
                     f"0.0 <= {a} < {float((1 << c.bits) - c.offset)!r}): raise _F")
        return f"(int({a}) + {c.offset})" if c.offset else f"int({a})"

    def field(self, c: FieldCodec, x: str, ind: str) -> None:
        """Encode the value named ``x`` (already looked up; ``None`` = absent) with ``c``."""
        g = self.g
        if not _fixed(c):
            self.flush(ind)
            fn = g.const("_enc", c.encode)
            k, w = g.name("k"), g.name("w")
            g.lines.append(f"{ind}{k}, {w} = {fn}({x}, False)")
            g.lines.append(f"{ind}{self.acc} |= {k} << o")
            g.lines.append(f"{ind}o += {w}")
            return
        if isinstance(c, RepeatedCodec):
            n = c.max_repeat
            items = [g.name("x") for _ in range(n)]
            g.lines.append(f"{ind}if {x}.__class__ is not list and {x}.__class__ is not tuple "
                           f"or len({x}) != {n}: raise _F")
            g.lines.append(f"{ind}{', '.join(items)}{',' if n == 1 else ''} = {x}")
            for item in items:
                self.field(c.element, item, ind)
            return
        if isinstance(c, MessageCodec):
            g.lines.append(f"{ind}if {x}.__class__ is not dict: raise _F")
            for name, sub in c.fields:
                y = g.name("x")
                g.lines.append(f"{ind}{y} = {x}[{name!r}]" if sub.required
                               else f"{ind}{y} = {x}.get({name!r})")
                self.field(sub, y, ind)
            return
        if not c.required:
            # optional scalar: code 0 when absent, else the value's code (offset includes +1)
            k = g.name("k")
            g.lines.append(f"{ind}if {x} is None:")
            g.lines.append(f"{ind}    {k} = 0")
            g.lines.append(f"{ind}else:")
            inner = self._scalar(c, x, ind + "    ")
            g.lines.append(f"{ind}    {k} = {inner}")
            self.put(k, c.max_bits, ind)
            return
        self.put(self._scalar(c, x, ind), c.max_bits, ind)

    def _scalar(self, c: FieldCodec, x: str, ind: str) -> str:
        if isinstance(c, BoolCodec):
            k = self.g.name("k")
            base = 0 if c.required else 1
            self.g.lines.append(f"{ind}if {x} is True: {k} = {base + 1}")
            self.g.lines.append(f"{ind}elif {x} is False: {k} = {base}")
            self.g.lines.append(f"{ind}else: raise _F")
            return k
        assert isinstance(c, NumericCodec)
        return self.numeric(c, x, ind)

    def result(self) -> tuple[str, str]:
        """The accumulated int's expression and its width's expression."""
        if not self.dynamic:
            expr = " | ".join(self.terms) if self.terms else "0"
            return f"({expr})", str(self.static)
        return self.acc, f"o + {self.static}" if self.static else "o"


def _encode_source(msg: DcclMessage, g: _Gen) -> list[str]:
    ind = "        "
    g.lines = ["def encode(value):", "    try:", f"{ind}if value.__class__ is not dict: raise _F"]
    head = 0 if msg.omit_id else (msg.id << 1) | (msg.id >= 128)
    head_parts = [str(head)] if head else []
    if msg.head and not all(_fixed(c) for _, c in msg.head):
        g.ns["_head_ref"] = msg.encode_head
        g.lines.append(f"{ind}hb = _head_ref(value)")
    elif msg.head:
        enc = _Enc(g, "h")
        enc.static = msg.id_bits
        for name, c in msg.head:
            x = g.name("x")
            g.lines.append(f"{ind}{x} = value[{name!r}]" if c.required
                           else f"{ind}{x} = value.get({name!r})")
            enc.field(c, x, ind)
        head_parts += enc.terms
    if not msg.head or all(_fixed(c) for _, c in msg.head):
        head_expr = " | ".join(head_parts) if head_parts else "0"
        g.lines.append(f"{ind}hb = ({head_expr}).to_bytes({msg.head_bytes}, 'little')")
    body = _Enc(g, "acc")
    g.lines.append(f"{ind}acc = 0")
    if msg.body_codec.oneofs:  # oneof cases lead the body: the reference body codec does it
        fn = g.const("_enc", msg.body_codec.encode)
        g.lines.append(f"{ind}acc, width = {fn}(value, False)")
        g.lines.append(f"{ind}return hb + acc.to_bytes((width + 7) >> 3, 'little')")
        g.lines += ["    except Exception:", "        return _encode_ref(value)"]
        return g.lines
    for name, c in msg.body:
        x = g.name("x")
        required = c.required and not isinstance(c, RepeatedCodec)
        g.lines.append(f"{ind}{x} = value[{name!r}]" if required
                       else f"{ind}{x} = value.get({name!r})")
        if isinstance(c, RepeatedCodec) and _fixed(c):
            g.lines.append(f"{ind}if {x} is None: raise _F")
        body.field(c, x, ind)
    expr, width = body.result()
    if body.dynamic:
        g.lines.append(f"{ind}width = {width}")
        g.lines.append(f"{ind}return hb + {expr}.to_bytes((width + 7) >> 3, 'little')")
    else:
        nbytes = (int(width) + 7) // 8
        g.lines.append(f"{ind}return hb + {expr}.to_bytes({nbytes}, 'little')")
    g.lines += ["    except Exception:", "        return _encode_ref(value)"]
    return g.lines


# -- decoder ------------------------------------------------------------------------------------
class _Dec:
    """Emits code extracting fields from ``src`` (an int) at offset ``p`` (+ static part)."""

    def __init__(self, gen: _Gen, src: str, limit: str, start: int) -> None:
        self.g, self.src, self.limit = gen, src, limit
        self.static = start
        self.dynamic = False

    def bits(self, width: int, ind: str) -> str:
        k = self.g.name("k")
        mask = (1 << width) - 1
        if not self.dynamic:
            shift = f"{self.src} >> {self.static}" if self.static else self.src
        else:
            at = f"(p + {self.static})" if self.static else "p"
            shift = f"{self.src} >> {at}"
        self.g.lines.append(f"{ind}{k} = {shift} & {mask}")
        self.static += width
        return k

    def go_dynamic(self, ind: str) -> None:
        if not self.dynamic:
            self.g.lines.append(f"{ind}p = {self.static}")
            self.dynamic = True
        elif self.static:
            self.g.lines.append(f"{ind}p += {self.static}")
        self.static = 0

    def numeric_value(self, c: NumericCodec, k: str, ind: str) -> str:
        g = self.g
        if isinstance(c, EnumCodec):
            if c.packed:
                return f"{g.const('_N', tuple(c.names))}[{k}]"
            table = {num - int(c.lo): n for n, num in reversed(list(zip(c.names, c.numbers,
                                                                         strict=True)))}
            return f"{g.const('_N', table)}[{k}]"
        if not c.is_float:
            lo = int(c.lo)
            return f"({k} + {lo})" if lo > 0 else f"({k} - {-lo})" if lo else k
        inv = 1.0 / c.res
        # dccl-4.2: k * res plus the quantised minimum Q * res, re-quantised; dccl-2026:
        # (k + qm) * res (negating before or after a rounded product gives the same double, so
        # this is the reference's sign-magnitude product), re-quantised. For a field of fewer
        # than 2**47 steps the re-quantisation lands on the integer exactly (see _small).
        qm = _steps(c.lo, c.res) if c.rule == "dccl-4.2" else numeric.round_div(c.lo, c.res)
        t = f"({k} + {qm})" if qm > 0 else f"({k} - {-qm})" if qm else k
        if _small(c):
            return f"{t} * {c.res!r}" if c.res >= 1 else f"{t} / {inv!r}"
        if c.rule == "dccl-4.2":
            qlo = numeric.quantize_float(c.lo, c.res)
            if c.res >= 1:
                return f"_floor({_minus(f'{k} * {c.res!r}', -qlo)} / {c.res!r} + 0.5) * {c.res!r}"
            return f"_floor({_minus(f'{k} / {inv!r}', -qlo)} * {inv!r} + 0.5) / {inv!r}"
        if c.res >= 1:
            return f"_floor({t} * {c.res!r} / {c.res!r} + 0.5) * {c.res!r}"
        return f"_floor({t} * {c.res!r} * {inv!r} + 0.5) / {inv!r}"

    def field(self, c: FieldCodec, ind: str) -> str:
        """Code leaving the decoded value in a name (or the ``_ABSENT`` marker); returns it."""
        g = self.g
        if not _fixed(c):
            self.go_dynamic(ind)
            r, v = g.name("r"), g.name("v")
            fn = g.const("_dec", c.decode)
            g.lines.append(f"{ind}{r} = _BR({self.src}, {self.limit}, p)")
            g.lines.append(f"{ind}{v} = {fn}({r})")
            g.lines.append(f"{ind}p = {r}.pos")
            return v
        if isinstance(c, RepeatedCodec):
            items = [self.field(c.element, ind) for _ in range(c.max_repeat)]
            return f"[{', '.join(items)}]"
        if isinstance(c, MessageCodec):
            got = [(n, self.field(sub, ind), sub) for n, sub in c.fields]
            v = g.name("v")
            parts = [f"{n!r}: {x}" for n, x, sub in got if sub.required]
            g.lines.append(f"{ind}{v} = {{{', '.join(parts)}}}")
            for n, x, sub in got:
                if not sub.required:
                    g.lines.append(f"{ind}if {x} is not _ABSENT: {v}[{n!r}] = {x}")
            return v
        k = self.bits(c.max_bits, ind)
        v = g.name("v")
        if isinstance(c, BoolCodec):
            if c.required:
                g.lines.append(f"{ind}{v} = {k} == 1")
            else:
                g.lines.append(f"{ind}{v} = _ABSENT if {k} == 0 else {k} != 1")
            return v
        assert isinstance(c, NumericCodec)
        if c.required:
            g.lines.append(f"{ind}{v} = {self.numeric_value(c, k, ind)}")
            return v
        g.lines.append(f"{ind}if {k}:")
        g.lines.append(f"{ind}    {k} -= 1")
        value = self.numeric_value(c, k, ind + "    ")
        g.lines.append(f"{ind}    {v} = {value}")
        g.lines.append(f"{ind}else:")
        g.lines.append(f"{ind}    {v} = _ABSENT")
        return v

    def end(self) -> str:
        if not self.dynamic:
            return str(self.static)
        return f"p + {self.static}" if self.static else "p"


def _decode_source(msg: DcclMessage, g: _Gen) -> list[str]:
    ind = "        "
    lines = ["def decode(data):", "    try:", f"{ind}if data.__class__ is not bytes: raise _F"]
    g.lines = lines
    hb = msg.head_bytes
    lines.append(f"{ind}if len(data) < {hb}: raise _F")
    if not msg.omit_id:
        first = (msg.id << 1) & 0xFF | (msg.id >= 128)
        lines.append(f"{ind}if data[0] != {first}: raise _F")
        if msg.id >= 128:
            lines.append(f"{ind}if data[1] != {msg.id >> 7}: raise _F")
    values: list[tuple[str, str, FieldCodec]] = []
    if msg.head:
        lines.append(f"{ind}h = int.from_bytes(data[:{hb}], 'little')")
        head = _Dec(g, "h", str(8 * hb), msg.id_bits)
        values += [(n, head.field(c, ind), c) for n, c in msg.head]
    lines.append(f"{ind}n = int.from_bytes(data[{hb}:], 'little')")
    lines.append(f"{ind}limit = (len(data) - {hb}) << 3")
    if msg.body_codec.oneofs:  # the reference body codec, then the head values
        fn = g.const("_dec", msg.body_codec.decode_fields)
        lines += [f"{ind}r = _BR(n, limit, 0)", f"{ind}out = {fn}(r)"]
        for n, v, c in values:
            lines.append(f"{ind}out[{n!r}] = {v}" if _certain(c)
                         else f"{ind}if {v} is not _ABSENT: out[{n!r}] = {v}")
        lines.append(f"{ind}return out, {hb} + ((r.pos + 7) >> 3)")
        lines += ["    except Exception:", "        return _decode_ref(data)"]
        return lines
    body = _Dec(g, "n", "limit", 0)
    values += [(n, body.field(c, ind), c) for n, c in msg.body]
    lines.append(f"{ind}end = {body.end()}")
    lines.append(f"{ind}if end > limit: raise _F")
    certain = [f"{n!r}: {v}" for n, v, c in values if _certain(c)]
    lines.append(f"{ind}out = {{{', '.join(certain)}}}")
    for n, v, c in values:  # an optional field, or a required one libdccl may leave unset
        if not _certain(c):
            lines.append(f"{ind}if {v} is not _ABSENT: out[{n!r}] = {v}")
    lines.append(f"{ind}return out, {hb} + ((end + 7) >> 3)")
    lines += ["    except Exception:", "        return _decode_ref(data)"]
    return lines


def compile_message(msg: DcclMessage) -> Compiled:
    """Generate and ``exec`` the fast functions of ``msg``."""
    g = _Gen()
    g.ns["_encode_ref"] = msg.encode_reference
    g.ns["_decode_ref"] = msg.decode_reference
    enc = _encode_source(msg, g)
    dec = _decode_source(msg, g)
    source = "\n".join([*enc, "", *dec]) + "\n"
    exec(compile(source, f"<bridge.dccl {msg.name}>", "exec"), g.ns)

    def encode_strict(value: Any) -> bytes:
        return msg.encode_reference(value, True)

    return Compiled(source, g.ns["encode"], encode_strict, g.ns["decode"])
