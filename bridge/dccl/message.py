"""A whole DCCL message: identifier, head and body, as libdccl 4's ``Codec::encode`` lays them.

Wire layout: ``[id][in_head fields][pad to a byte] [body fields][pad to a byte]``. The id is
DCCL's default identifier codec: one byte ``id << 1`` for ids below 128, else two bytes
``(id << 1) | 1`` (little-endian); ``omit_id`` messages have none. Bits fill each byte from
its least significant bit, fields in declaration order. Before anything else ``encode`` checks
that every required field is set (protobuf's ``IsInitialized``, list elements past
``max_repeat`` included), as libdccl does before any bound.

``encode``/``decode`` are generated per message (:mod:`bridge.dccl.compile`) and fall back to
the ``*_reference`` methods here for anything unusual, which raise the precise errors.
"""

from __future__ import annotations

from typing import Any

from bridge.dccl import numeric
from bridge.dccl.build import Scheme, build_fields, build_message, check_message_options
from bridge.dccl.codecs import ABSENT, BitReader, FieldCodec, MessageCodec
from bridge.dccl.compile import compile_message
from bridge.dccl.schema import DcclSchemaError, MessageDef, ProtoFile
from bridge.errors import DecodeError, EncodeError

__all__ = ["DcclMessage", "id_bits", "peek_id"]


def id_bits(ident: int) -> int:
    """Bits of DCCL's default identifier for ``ident``: 8 below 128, else 16."""
    return 8 if ident < 128 else 16


def peek_id(data: bytes) -> int:
    """The DCCL id at the start of ``data`` (``DecodeError`` if there is none)."""
    if not data:
        raise DecodeError("truncated: no DCCL identifier")
    if data[0] & 1:
        if len(data) < 2:
            raise DecodeError("truncated: two-byte DCCL identifier cut short")
        return (data[0] | data[1] << 8) >> 1
    return data[0] >> 1


class DcclMessage:
    """Encoder/decoder of one DCCL message type (default codecs of codec version 3, 4 or 5)
    under a numeric rule (:data:`bridge.dccl.numeric.RULES`)."""

    def __init__(self, mdef: MessageDef, proto: ProtoFile,
                 rule: str = numeric.DEFAULT_RULE) -> None:
        check_message_options(mdef)
        if rule not in numeric.RULES:
            raise DcclSchemaError(f"unknown numeric rule {rule!r} (one of "
                                  f"{', '.join(numeric.RULES)})")
        self.definition = mdef
        self.name = mdef.full_name
        self.rule = rule
        self.id: int = int(mdef.options.get("id", 0))
        self.max_bytes: int = int(mdef.options["max_bytes"])
        self.omit_id: bool = bool(mdef.options.get("omit_id", False))
        self.version: int = int(mdef.options.get("codec_version", 2))
        scheme = Scheme(proto, self.version, rule)
        fields = build_fields(mdef, scheme)
        head_names = {f.name for f in mdef.fields if f.options.get("in_head")}
        self.head = [(n, c) for n, c in fields if n in head_names]
        self.body = [(n, c) for n, c in fields if n not in head_names]
        self.body_codec = build_message(mdef, scheme, "", True, names={n for n, _ in self.body})
        # head and body together, for the required-field check
        self._whole = MessageCodec("", True, fields, oneofs=self.body_codec.oneofs)
        self.lines = {f.name: f.line for f in mdef.fields}
        for name, codec in self.head:
            if codec.variable:
                raise DcclSchemaError("Variable size codec used in header - header fields must "
                                      "be encoded with fixed size codec.", mdef.file,
                                      self.lines[name])
        self.id_bits = 0 if self.omit_id else id_bits(self.id)
        self.head_bits = self.id_bits + sum(c.max_bits for _, c in self.head)
        self.head_bytes = (self.head_bits + 7) // 8
        self.body_min_bits = self.body_codec.min_bits
        self.body_max_bits = self.body_codec.max_bits
        self.min_bytes = self.head_bytes + (self.body_min_bits + 7) // 8
        self.max_size = self.head_bytes + (self.body_max_bits + 7) // 8
        if self.max_size > self.max_bytes:
            raise DcclSchemaError(
                f"Actual maximum size of message ({self.max_size} bytes) exceeds allowed maximum "
                f"(dccl.max_bytes = {self.max_bytes}). Tighten bounds, remove fields, improve "
                "codecs, or increase the allowed dccl.max_bytes", mdef.file, mdef.line)
        self.fixed = self.body_min_bits == self.body_max_bits
        compiled = compile_message(self)
        self.source = compiled.source
        self._encode_fast = compiled.encode
        self._decode_fast = compiled.decode
        self._encode_strict = compiled.encode_strict

    @classmethod
    def from_proto(cls, proto: ProtoFile, name: str,
                   rule: str = numeric.DEFAULT_RULE) -> DcclMessage:
        return cls(proto.message(name), proto, rule)

    # -- public API ------------------------------------------------------------------------------
    def encode(self, value: dict[str, Any], strict: bool = False) -> bytes:
        """DCCL bytes of ``value`` (a dict by field name; enums by value name)."""
        return self._encode_strict(value) if strict else self._encode_fast(value)

    def decode(self, data: bytes) -> dict[str, Any]:
        """The message at the start of ``data``; ``DecodeError`` for anything invalid."""
        return self._decode_fast(data)[0]

    def decode_prefix(self, data: bytes) -> tuple[dict[str, Any], int]:
        """The message at the start of ``data`` and the bytes it took (for concatenations)."""
        return self._decode_fast(data)

    def size(self, value: dict[str, Any]) -> int:
        """Bytes ``encode(value)`` produces."""
        return len(self.encode(value))

    def __repr__(self) -> str:
        return f"<DcclMessage {self.name} id={self.id} {self.min_bytes}-{self.max_size} bytes>"

    # -- reference path --------------------------------------------------------------------------
    def _encode_part(self, fields: list[tuple[str, FieldCodec]], value: Any, strict: bool,
                     code: int, width: int) -> tuple[int, int]:
        for name, codec in fields:
            k, w = codec.encode(value.get(name), strict)
            code |= k << width
            width += w
        return code, width

    def encode_head(self, value: Any, strict: bool = False) -> bytes:
        """The head bytes (identifier and ``in_head`` fields) of ``value``."""
        head = 0 if self.omit_id else (self.id << 1) | (self.id >= 128)
        head, _ = self._encode_part(self.head, value, strict, head, self.id_bits)
        return head.to_bytes(self.head_bytes, "little")

    def encode_reference(self, value: Any, strict: bool = False) -> bytes:
        """Field by field through the codecs (the readable twin of the generated encoder)."""
        if not isinstance(value, dict):
            raise EncodeError(f"{self.name}: expected a mapping, got {type(value).__name__}")
        missing = self._whole.missing(value)
        if missing is not None:  # libdccl checks this first, before any bound
            raise EncodeError(f"{missing}: required field missing (DCCL: Message is not "
                              "properly initialized)")
        head = self.encode_head(value, strict)
        body, width = self.body_codec.encode(value, strict)
        return head + body.to_bytes((width + 7) // 8, "little")

    def decode_reference(self, data: Any) -> tuple[dict[str, Any], int]:
        """Decode field by field; ``(value, bytes used)``; ``DecodeError`` on any fault."""
        if not isinstance(data, bytes | bytearray | memoryview):
            raise DecodeError(f"expected bytes, got {type(data).__name__}")
        data = bytes(data)
        if len(data) < self.head_bytes:
            raise DecodeError(f"truncated: {len(data)} bytes, the DCCL head needs "
                              f"{self.head_bytes}")
        if not self.omit_id:
            found = peek_id(data)
            if found != self.id:
                raise DecodeError(f"DCCL id {found} is not {self.name}'s id {self.id}")
        out: dict[str, Any] = {}
        head = BitReader(int.from_bytes(data[: self.head_bytes], "little"), 8 * self.head_bytes,
                         self.id_bits)
        self._decode_part(self.head, head, out)
        body_data = data[self.head_bytes:]
        body = BitReader(int.from_bytes(body_data, "little"), 8 * len(body_data))
        out.update(self.body_codec.decode_fields(body))
        return out, self.head_bytes + (body.pos + 7) // 8

    @staticmethod
    def _decode_part(fields: list[tuple[str, FieldCodec]], reader: BitReader,
                     out: dict[str, Any]) -> None:
        for name, codec in fields:
            v = codec.decode(reader)
            if v is not ABSENT:  # a required field may come back unset, as from libdccl
                out[name] = v
