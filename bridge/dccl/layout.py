"""A DCCL message as a channel element: the same interface as :class:`bridge.codec.Layout`.

The element's bits are the message's DCCL bytes, zero-padded to its maximum size, so a frame
carries exactly the bytes libdccl would produce (padding after them: DCCL decoders stop where
the message ends). ``pack``/``unpack`` give them as a big-endian int, first byte most
significant, as the frame packs layouts.
"""

from __future__ import annotations

import hashlib
import json
import random
from pathlib import Path
from types import SimpleNamespace
from typing import TYPE_CHECKING, Any

from bridge.dccl.analyze import analyze
from bridge.dccl.codecs import (
    BoolCodec,
    BytesCodec,
    EnumCodec,
    FieldCodec,
    FixedBytesCodec,
    MessageCodec,
    NumericCodec,
    RepeatedCodec,
    StringCodecV3,
)
from bridge.dccl.message import DcclMessage
from bridge.dccl.numeric import DEFAULT_RULE
from bridge.dccl.schema import DcclSchemaError, load_proto
from bridge.errors import DecodeError, EncodeError

if TYPE_CHECKING:
    from bridge.mission.model import Dccl

__all__ = ["DcclLayout", "parse_reference"]


def parse_reference(ref: str) -> tuple[str, str]:
    """``"file.proto:Message"`` → ``("file.proto", "Message")``."""
    path, sep, name = ref.rpartition(":")
    if not sep or not path or not name:
        raise DcclSchemaError(f"expected 'file.proto:Message', got {ref!r}")
    return path, name


def _schema(codec: FieldCodec) -> dict[str, Any]:
    if isinstance(codec, RepeatedCodec):
        return {"type": "array", "items": _schema(codec.element),
                "minItems": codec.min_repeat, "maxItems": codec.max_repeat}
    if isinstance(codec, EnumCodec):  # a value name, or a value number as protobuf has it
        return {"anyOf": [{"enum": list(codec.names)},
                          {"type": "integer", "enum": sorted(set(codec.numbers))}]}
    if isinstance(codec, NumericCodec):
        if codec.is_float:
            return {"type": "number", "minimum": codec.lo, "maximum": codec.hi}
        return {"type": "integer", "minimum": int(codec.lo), "maximum": int(codec.hi)}
    if isinstance(codec, BoolCodec):
        return {"type": "boolean"}
    if isinstance(codec, StringCodecV3):
        return {"type": "string", "maxLength": codec.max_length}
    if isinstance(codec, FixedBytesCodec):
        return {"type": "string", "contentEncoding": "base64", "x-max-bytes": codec.max_length}
    if isinstance(codec, BytesCodec):
        if codec.text:
            return {"type": "string", "maxLength": codec.max_length}
        return {"type": "string", "contentEncoding": "base64", "x-max-bytes": codec.max_length}
    assert isinstance(codec, MessageCodec)
    return _object(codec.fields)


def _object(fields: Any) -> dict[str, Any]:
    return {"type": "object", "properties": {n: _schema(c) for n, c in fields},
            "required": [n for n, c in fields if c.required]}


def _wire_facts(codec: FieldCodec) -> list[Any]:
    """What decides a codec's bits, and nothing else (no names of files, no line numbers)."""
    facts: list[Any] = [type(codec).__name__, codec.required, codec.min_bits, codec.max_bits]
    if isinstance(codec, NumericCodec):
        facts += [codec.kind, codec.lo, codec.hi, codec.res]
        if codec.is_float:  # the numeric rule decides a float's bits, not an integer's
            facts.append(codec.rule)
    if isinstance(codec, EnumCodec):
        facts += [codec.names, codec.numbers, codec.packed]
    if isinstance(codec, BytesCodec | StringCodecV3 | FixedBytesCodec):
        facts += [codec.max_length]
    if isinstance(codec, RepeatedCodec):
        facts += [codec.min_repeat, codec.max_repeat, _wire_facts(codec.element)]
    if isinstance(codec, MessageCodec):
        facts += [[[n, _wire_facts(c)] for n, c in codec.fields], codec.oneofs]
    return facts


def signature(message: DcclMessage) -> str:
    """A short text that differs when two definitions would put different bits on the wire
    (it goes into the mission fingerprint): every field's codec parameters, not where the
    ``.proto`` file is."""
    facts = [message.name, message.id, message.omit_id, message.version,
             [[n, _wire_facts(c)] for n, c in message.head], _wire_facts(message.body_codec)]
    digest = hashlib.sha256(json.dumps(facts).encode()).hexdigest()[:12]
    return f"dccl {message.name} id={message.id} v{message.version} {digest}"


class _Payload:
    """The single "field" of a DCCL element: the whole payload (for describe/fingerprint)."""

    path = ""
    clamped = 0

    def __init__(self, layout: DcclLayout) -> None:
        self._layout = layout
        self.bits = layout.bits
        self.spec = SimpleNamespace(description=layout.description, units=None)

    def describe(self) -> str:
        return self._layout.signature

    def json_schema(self) -> dict[str, Any]:
        return self._layout.json_schema()


class DcclLayout:
    """Layout-compatible wrapper of a :class:`DcclMessage` (``strict``: out of range raises)."""

    def __init__(self, message: DcclMessage, strict: bool = False, source: str = "") -> None:
        self.message = message
        self.strict = strict
        self.nbytes = message.max_size
        self.bits = 8 * self.nbytes
        self.description = f"DCCL {message.name} (id {message.id}) from {source or '?'}"
        self.signature = signature(message)
        self.fields: tuple[Any, ...] = (_Payload(self),)

    @classmethod
    def from_reference(cls, ref: str, base: Path | None = None, strict: bool = False,
                       options: Dccl | None = None) -> DcclLayout:
        """``ref`` is ``file.proto:Message``; a relative file is taken from ``base``.
        ``options``: the mission's ``dccl`` settings (numeric rule, include path)."""
        path, name = parse_reference(ref)
        file = Path(path)
        if not file.is_absolute() and base is not None:
            file = base / file
        rule = options.numeric if options is not None else DEFAULT_RULE
        proto = load_proto(file, options.proto_path if options is not None else ())
        return cls(DcclMessage.from_proto(proto, name, rule), strict, path)

    @property
    def clamped(self) -> dict[str, int]:
        return {}

    def encode(self, value: Any) -> bytes:
        """DCCL bytes of ``value`` zero-padded to the message's maximum size."""
        return self.message.encode(value, self.strict).ljust(self.nbytes, b"\0")

    def decode(self, data: bytes) -> Any:
        if not isinstance(data, bytes | bytearray | memoryview) or len(data) != self.nbytes:
            raise DecodeError(f"expected {self.nbytes} bytes of DCCL {self.message.name}")
        return self.message.decode(bytes(data))

    def pack(self, value: Any) -> int:
        return int.from_bytes(self.encode(value), "big")

    def unpack(self, n: int) -> Any:
        if n.__class__ is not int or n < 0 or n >> self.bits:
            raise DecodeError(f"{n!r} does not fit in {self.bits} bits")
        return self.message.decode(n.to_bytes(self.nbytes, "big"))

    def synthetic_value(self, rng: random.Random, draws: int = 8) -> Any:
        """A value this message encodes (for simulations): random head and body codes after
        the identifier, decoded; else all-zero codes (every field's minimum or absence)."""
        m = self.message
        ident = 0 if m.omit_id else (m.id << 1) | (m.id >= 128)
        size = m.max_size
        for _ in range(draws):
            n = rng.getrandbits(8 * size - m.id_bits) << m.id_bits | ident
            try:
                value = m.decode(n.to_bytes(size, "little"))
                m.encode(value, strict=True)  # codes past max decode but are out of range
                return value
            except (DecodeError, EncodeError):
                continue
        return m.decode(ident.to_bytes(size, "little"))

    def json_schema(self) -> dict[str, Any]:
        m = self.message
        schema = _object([*m.head, *m.body])
        return {"$schema": "https://json-schema.org/draft/2020-12/schema", **schema,
                "description": self.description}

    def describe(self) -> str:
        return analyze(self.message)

    def __repr__(self) -> str:
        return f"<DcclLayout {self.message.name} {self.bits} bits>"
