"""Generate one specialised Python function per layout operation (pack/unpack/encode/decode).

Constants are inlined, dict lookups shared, and every field's bits combined in one expression.
The generated code handles only the common, valid case; anything else (missing key, wrong type,
out-of-range, NaN, invalid code) raises ``_F`` or a builtin error and the whole call is redone
by the layout's reference path, which counts clamps and raises the precise ``EncodeError`` or
``DecodeError``. So the fast path can never disagree with the reference about an error.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from bridge.codec.fields import ArrayCodec, FieldCodec, checked_decode, checked_encode

__all__ = ["Compiled", "compile_layout"]


LITERAL_DIGITS = 1000
"""Integers up to this many decimal digits go into the generated code as literals; larger
ones (a mask over a long bytes field) as names bound in its namespace: Python refuses to
write out an int of over 4300 digits (a mission with a 1.8 kB bytes field after another
field crashed ``zab check``)."""


def _constant(ns: dict[str, Any], name: str, value: int) -> str:
    """``value`` as the generated code writes it: a literal, or ``name`` bound in ``ns``."""
    if value.bit_length() <= LITERAL_DIGITS * 3:  # (3 bits a digit at least)
        return str(value)
    ns[name] = value
    return name


class _Fallback(Exception):
    """Internal: leave the fast path."""


class Compiled:
    """The generated functions and their source (for debugging and tests)."""

    def __init__(self, source: str, functions: dict[str, Callable[..., Any]]) -> None:
        self.source = source
        self.pack: Callable[[Any], int] = functions["pack"]
        self.unpack: Callable[[int], Any] = functions["unpack"]
        self.encode: Callable[[Any], bytes] = functions["encode"]
        self.decode: Callable[[bytes], Any] = functions["decode"]



def _indent(lines: list[str], depth: int = 2) -> list[str]:
    return [" " * (4 * depth) + line for line in lines]


def _leaves(codec: FieldCodec, i: int) -> list[tuple[FieldCodec, str]]:
    """(element codec, suffix) for each value slot of field ``i``."""
    if isinstance(codec, ArrayCodec) and codec.element.inline_encode("v", "k", {}, "") is not None:
        return [(codec.element, f"{i}_{j}") for j in range(codec.count)]
    return [(codec, f"{i}")]


def _encode_body(fields: Sequence[FieldCodec], ns: dict[str, Any]) -> tuple[list[str], str]:
    """Lines computing every ``k*`` from ``value``, and the combining expression."""
    lookups: list[str] = []
    objects: dict[tuple[str, ...], str] = {(): "value"}
    inline: list[str] = []
    calls: list[str] = []
    terms: list[tuple[str, int]] = []
    shift = sum(f.bits for f in fields)
    for i, codec in enumerate(fields):
        parts = tuple(codec.path.split(".")) if codec.path else ()
        for depth in range(1, len(parts)):
            prefix = parts[:depth]
            if prefix not in objects:
                objects[prefix] = f"_o{len(objects)}"
                lookups.append(f"{objects[prefix]} = {objects[prefix[:-1]]}[{prefix[-1]!r}]")
        v = f"v{i}"
        lookups.append(f"{v} = {objects[parts[:-1]]}[{parts[-1]!r}]" if parts else f"{v} = value")
        shift -= codec.bits
        leaves = _leaves(codec, i)
        if leaves[0][0] is not codec:
            names = ", ".join(f"v{s}" for _, s in leaves) + ("," if len(leaves) == 1 else "")
            lookups.append(f"if {v}.__class__ is not list and {v}.__class__ is not tuple: raise _F")
            lookups.append(f"{names} = {v}")
        width = leaves[0][0].bits
        for j, (leaf, suffix) in enumerate(leaves):
            lines = leaf.inline_encode(f"v{suffix}", f"k{suffix}", ns, suffix)
            if lines is None:
                ns[f"_enc{suffix}"] = checked_encode(leaf)
                calls.append(f"k{suffix} = _enc{suffix}(v{suffix})")
            else:
                inline.extend(lines)
            terms.append((f"k{suffix}", shift + (len(leaves) - 1 - j) * width))
    # Inline conversions first: a fallback then happens before any plug-in counted a clamp.
    body = lookups + inline + calls
    pieces = [name if s == 0 else f"({name} << {s})" for name, s in terms]
    expr = " | ".join(pieces) if len(pieces) > 1 else f"{pieces[0]} | 0" if pieces else "0"
    return body, expr


def _dict_literal(tree: dict[str, Any]) -> str:
    items = ", ".join(
        f"{key!r}: {_dict_literal(sub) if isinstance(sub, dict) else sub}"
        for key, sub in tree.items()
    )
    return "{" + items + "}"


def _decode_body(
    fields: Sequence[FieldCodec], ns: dict[str, Any], total: int
) -> tuple[list[str], str]:
    """Lines splitting ``n`` into ``k*`` with guards, and the result expression."""
    split: list[str] = []
    guards: list[str] = []
    tree: dict[str, Any] = {}
    whole: str | None = None
    shift = total
    for i, codec in enumerate(fields):
        shift -= codec.bits
        leaves = _leaves(codec, i)
        width = leaves[0][0].bits
        exprs: list[str] = []
        for j, (leaf, suffix) in enumerate(leaves):
            s = shift + (len(leaves) - 1 - j) * width
            k = f"k{suffix}"
            mask = _constant(ns, f"_mask{suffix}", (1 << width) - 1)
            if width == 0:
                split.append(f"{k} = 0")
            elif s + width == total:
                split.append(f"{k} = n >> {s}" if s else f"{k} = n")
            else:
                split.append(f"{k} = n >> {s} & {mask}" if s else f"{k} = n & {mask}")
            inline = leaf.inline_decode(k, ns, suffix)
            if inline is None:
                ns[f"_dec{suffix}"] = checked_decode(leaf)
                exprs.append(f"_dec{suffix}({k})")
            else:
                guards.extend(inline[0])
                exprs.append(f"({inline[1]})")
        expr = f"[{', '.join(exprs)}]" if len(leaves) > 1 or leaves[0][0] is not codec else exprs[0]
        if not codec.path:
            whole = expr
            continue
        node = tree
        parts = codec.path.split(".")
        for part in parts[:-1]:
            node = node.setdefault(part, {})
        node[parts[-1]] = expr
    return split + guards, whole if whole is not None else _dict_literal(tree)


def compile_layout(
    fields: Sequence[FieldCodec],
    reference: dict[str, Callable[..., Any]],
) -> Compiled:
    """Generate and ``exec`` the fast functions; ``reference`` maps each name to its fallback."""
    total = sum(f.bits for f in fields)
    nbytes = (total + 7) // 8
    pad = -total % 8
    ns: dict[str, Any] = {"_F": _Fallback}
    for name, fn in reference.items():
        ns[f"_{name}_ref"] = fn
    enc_lines, enc_expr = _encode_body(fields, ns)
    dec_lines, dec_expr = _decode_body(fields, ns, total)
    to_bytes = f"(({enc_expr}) << {pad})" if pad else f"({enc_expr})"
    src: list[str] = []
    src += ["def pack(value):", "    try:", *_indent(enc_lines)]
    src += [
        f"        return {enc_expr}",
        "    except Exception:",
        "        return _pack_ref(value)",
    ]
    src += ["", "def encode(value):", "    try:", *_indent(enc_lines)]
    src += [f"        return {to_bytes}.to_bytes({nbytes}, 'big')"]
    src += ["    except Exception:", "        return _encode_ref(value)"]
    src += ["", "def unpack(n):", "    try:"]
    src += [f"        if n.__class__ is not int or n < 0 or n >> {total}: raise _F"]
    src += [*_indent(dec_lines), f"        return {dec_expr}"]
    src += ["    except Exception:", "        return _unpack_ref(n)"]
    src += ["", "def decode(data):", "    try:"]
    src += [
        f"        if len(data) != {nbytes}: raise _F",
        "        n = int.from_bytes(data, 'big')",
    ]
    if pad:
        src += [f"        if n & {_constant(ns, '_pad_mask', (1 << pad) - 1)}: raise _F",
                f"        n >>= {pad}"]
    src += [*_indent(dec_lines), f"        return {dec_expr}"]
    src += ["    except Exception:", "        return _decode_ref(data)"]
    source = "\n".join(src) + "\n"
    exec(compile(source, "<bridge.codec layout>", "exec"), ns)
    functions = {name: ns[name] for name in ("pack", "unpack", "encode", "decode")}
    return Compiled(source, functions)
