"""The bit budget of a DCCL message, laid out like ``dccl --analyze`` (libdccl's
``Codec::info``): sizes in bits, ``min-max`` for variable-size fields, dotted to column 40."""

from __future__ import annotations

from typing import TYPE_CHECKING

from bridge.dccl.codecs import FieldCodec, MessageCodec, RepeatedCodec

if TYPE_CHECKING:
    from bridge.dccl.message import DcclMessage

__all__ = ["analyze"]

_WIDTH = 40
_INDENT = 8


def _size(codec: FieldCodec) -> str:
    return (f"{codec.min_bits}-{codec.max_bits}" if codec.min_bits != codec.max_bits
            else str(codec.max_bits))


def _line(indent: int, name: str, size: str, codec: str, width: int = _WIDTH) -> str:
    return f"{' ' * indent}{name}{size.rjust(max(1, width - len(name)), '.')} {{{codec}}}"


def _field(name: str, codec: FieldCodec, depth: int, numbers: dict[str, int],
           extra: int = 0) -> list[str]:
    label = f"{numbers.get(name, 0)}. {name}"
    if isinstance(codec, RepeatedCodec):
        span = f"{codec.min_repeat}-" if codec.min_repeat else ""
        label += f"[{span}{codec.max_repeat}]"
    lines = []
    if codec.max_bits:
        lines.append(_line(_INDENT * depth + extra, label, _size(codec), codec.codec_name))
    inner = codec.element if isinstance(codec, RepeatedCodec) else codec
    if isinstance(inner, MessageCodec):
        lines += _fields(inner, list(inner.fields), depth + 1)
    return lines


def _fields(owner: MessageCodec, fields: list[tuple[str, FieldCodec]], depth: int) -> list[str]:
    """Oneofs first (each with its members, indented by half a step), then the other fields."""
    lines = []
    sizes = dict(fields)
    for index, ((name, members), bits) in enumerate(zip(owner.oneofs, owner.case_bits,
                                                        strict=True)):
        most = max((sizes[m].max_bits for m in members if m in sizes), default=0)
        label = f"{index}. {name} [oneof]"
        indent = " " * (_INDENT * depth)
        lines.append(f"{indent}{label}{f'{bits}-{bits + most}'.rjust(_WIDTH - len(label), '.')} {{")
        for m in members:
            if m in sizes:
                lines += _field(m, sizes[m], depth, owner.numbers, _INDENT // 2)
        lines.append(f"{indent}}}")
    for name, codec in fields:
        if name not in owner.member_of:
            lines += _field(name, codec, depth, owner.numbers)
    return lines


def analyze(msg: DcclMessage) -> str:
    """The report for one message (header, body, sizes), as text."""
    numbers = {f.name: f.number for f in msg.definition.fields}
    head_user = sum(c.max_bits for _, c in msg.head)
    pad = 8 * msg.head_bytes - msg.head_bits
    body_bits = msg.body_max_bits
    body_pad = -body_bits % 8
    total_bits = 8 * msg.max_size
    title = f" {msg.id}: {msg.name} "
    out = [title.center(60, "="),
           f"Actual maximum size of message: {msg.max_size} bytes / {total_bits} bits",
           _dots(_INDENT, "dccl.id head", msg.id_bits),
           _dots(_INDENT, "user head", head_user),
           _dots(_INDENT, "body", body_bits),
           _dots(_INDENT, "padding to full byte", pad + body_pad),
           f"Allowed maximum size of message: {msg.max_bytes} bytes / {8 * msg.max_bytes} bits",
           " Header ".center(60, "-")]
    if msg.id_bits:
        out.append(_line(0, "dccl.id head", str(msg.id_bits), "dccl.default.id", _WIDTH + _INDENT))
    out += [line for n, c in msg.head for line in _field(n, c, 1, numbers)]
    out.append(" Body ".center(60, "-"))
    size = (f"{msg.body_min_bits}-{body_bits}" if msg.body_min_bits != body_bits
            else str(body_bits))
    out.append(_line(0, msg.name, size, f"dccl.default{msg.version}", _WIDTH + _INDENT))
    out += _fields(msg.body_codec, msg.body, 1)
    return "\n".join(out)


def _dots(indent: int, name: str, bits: int) -> str:
    return f"{' ' * indent}{name}{str(bits).rjust(_WIDTH - len(name), '.')}"
