"""Check a :class:`~bridge.dccl.schema.MessageDef` as libdccl's ``Codec::load`` does and build
its field codecs. Every refusal is a :class:`DcclSchemaError` at the field's ``file:line`` with
libdccl's reason (or, for what zab does not implement, zab's)."""

from __future__ import annotations

from dataclasses import dataclass

from bridge.dccl import numeric
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
from bridge.dccl.schema import DcclSchemaError, FieldDef, MessageDef, ProtoFile

__all__ = ["VERSIONS", "Scheme", "build_fields", "build_message", "check_message_options"]

#: Codec versions whose default codecs zab implements (version 5's field and message codecs
#: are version 4's: GobySoft/dccl ``src/codecs5/`` aliases each of them).
VERSIONS = (3, 4, 5)
_DEFAULT_CODECS = {"_default", ""}
_WIRE_LIMITS = {
    "int32": (-2.0**31, 2.0**31 - 1), "sint32": (-2.0**31, 2.0**31 - 1),
    "sfixed32": (-2.0**31, 2.0**31 - 1), "int64": (-2.0**63, 2.0**63 - 1),
    "sint64": (-2.0**63, 2.0**63 - 1), "sfixed64": (-2.0**63, 2.0**63 - 1),
    "uint32": (0.0, 2.0**32 - 1), "fixed32": (0.0, 2.0**32 - 1),
    "uint64": (0.0, 2.0**64 - 1), "fixed64": (0.0, 2.0**64 - 1),
    "float": (-3.4028234663852886e38, 3.4028234663852886e38),
    "double": (-1.7976931348623157e308, 1.7976931348623157e308),
}
_UNSUPPORTED_FIELD_OPTIONS = {
    "dynamic_conditions": "dynamic_conditions are not implemented by zab",
    "num_days": "num_days applies to dccl.time codecs, which zab does not implement",
    "static_value": "static_value applies to the dccl.static codec, which zab does not implement",
}


def _fail(f: FieldDef | MessageDef, reason: str) -> DcclSchemaError:
    return DcclSchemaError(reason, f.file, f.line)


def check_message_options(m: MessageDef) -> None:
    """The ``(dccl.msg)`` checks of ``Codec::load`` (and zab's codec-version limit)."""
    o = m.options
    if m.syntax != "proto2":
        raise _fail(m, f"{m.full_name}: zab reads proto2 DCCL messages only (got {m.syntax})")
    if "id" not in o and not o.get("omit_id"):
        raise _fail(m, "Missing message option `(dccl.msg).id`")
    if "max_bytes" not in o:
        raise _fail(m, "Missing message option `(dccl.msg).max_bytes`")
    version = o.get("codec_version", 2)
    if version not in VERSIONS:
        raise _fail(m, f"(dccl.msg).codec_version = {version}: zab implements the default "
                    "codecs of codec versions 3, 4 and 5 (set option (dccl.msg).codec_version)")
    for key in ("codec", "codec_group"):
        if o.get(key, f"dccl.default{version}") not in _DEFAULT_CODECS | {f"dccl.default{version}"}:
            raise _fail(m, f"(dccl.msg).{key} {o[key]!r} is not implemented by zab")
    ident = o.get("id", 0)
    if not 0 <= ident <= 32767:
        raise _fail(m, f"dccl.id provided ({ident}) exceeds maximum: 32767")


def _numeric(f: FieldDef, path: str, required: bool, rule: str) -> NumericCodec:
    o = f.options
    if "min" not in o:
        raise _fail(f, "missing (dccl.field).min")
    if "max" not in o:
        raise _fail(f, "missing (dccl.field).max")
    if "precision" in o and "resolution" in o:
        raise _fail(f, "at most one of either (dccl.field).precision or (dccl.field).resolution "
                    "can be set")
    res = 10.0 ** -o["precision"] if "precision" in o else float(o.get("resolution", 1.0))
    if res <= 0:
        raise _fail(f, "(dccl.field).resolution must be greater than 0")
    lo, hi = float(o["min"]), float(o["max"])
    low, high = _WIRE_LIMITS[f.type]
    if lo < low:
        raise _fail(f, "(dccl.field).min must be >= minimum of this field type.")
    if hi > high:
        raise _fail(f, "(dccl.field).max must be <= maximum of this field type.")
    if "resolution" in o:
        for name, bound in (("min", lo), ("max", hi)):
            if abs(numeric.quantize_float(bound, res) - bound) >= 1e-10:
                raise _fail(f, f"(dccl.field).{name} must be an exact multiple of "
                            "(dccl.field).resolution")
    if hi < lo:
        raise _fail(f, "(dccl.field).max must be >= (dccl.field).min")
    if not numeric.fits_double(lo, hi, res):
        raise _fail(f, "[(dccl.field).max-(dccl.field).min]/(dccl.field).resolution must fit in "
                    "a double-precision floating point value. Please increase min, decrease "
                    "max, or decrease precision.")
    return NumericCodec(path, required, f.type, lo, hi, res, rule)


@dataclass(frozen=True)
class Scheme:
    """What decides a message's codecs besides its definition: the ``.proto`` files it comes
    from, its codec version and the numeric rule."""

    proto: ProtoFile
    version: int
    rule: str = numeric.DEFAULT_RULE


def _codec(f: FieldDef, path: str, scheme: Scheme, stack: tuple[str, ...]) -> FieldCodec:
    o, version = f.options, scheme.version
    default = f"dccl.default{version}"
    codec_name = o.get("codec", default)
    # dccl.var_bytes is version 4's (and 5's) default bytes codec under its own name
    var_bytes = f.type == "bytes" and (version > 3 or codec_name == "dccl.var_bytes")
    if codec_name not in _DEFAULT_CODECS | {default} and not (codec_name == "dccl.var_bytes"
                                                               and f.type == "bytes"):
        raise _fail(f, f"(dccl.field).codec {codec_name!r} is not implemented by zab")
    for key, reason in _UNSUPPORTED_FIELD_OPTIONS.items():
        if key in o:
            raise _fail(f, reason)
    if f.oneof is not None and o.get("in_head"):
        raise _fail(f, "Oneof field used in header - oneof fields cannot be encoded in the "
                    "header.")
    # use_required(): versions 4 and 5 also encode oneof members as required
    required = f.label in ("required", "repeated") or (version > 3 and f.oneof is not None)
    if f.type == "bool":
        codec: FieldCodec = BoolCodec(path, required)
    elif f.type in ("string", "bytes"):
        if "max_length" not in o:
            raise _fail(f, "missing (dccl.field).max_length")
        size = int(o["max_length"])
        if f.type == "string" and version == 3:
            codec = StringCodecV3(path, required, size)
        elif f.type == "bytes" and not var_bytes:
            codec = FixedBytesCodec(path, required, size)
        else:
            codec = BytesCodec(path, required, size, f.type == "string")
    elif f.type == "enum":
        if not f.enum_values:
            raise _fail(f, "enum has no values")
        codec = EnumCodec(path, required, f.enum_values, bool(o.get("packed_enum", True)))
    elif f.type == "message":
        assert f.message_type is not None
        if f.message_type in stack:
            raise _fail(f, f"{f.message_type} contains itself: DCCL messages cannot recurse")
        inner = scheme.proto.message(f.message_type)
        codec = build_message(inner, scheme, path, required, (*stack, f.message_type))
    elif f.type == "group":
        raise _fail(f, "groups are not supported by DCCL")
    else:
        codec = _numeric(f, path, required, scheme.rule)
    codec.codec_name = codec_name if codec_name == "dccl.var_bytes" else default
    if f.label == "repeated":
        if "max_repeat" not in o:
            raise _fail(f, "Missing (dccl.field).max_repeat option on `repeated` field")
        lo_rep, hi_rep = int(o.get("min_repeat", 0)), int(o["max_repeat"])
        if hi_rep < 1:
            raise _fail(f, "(dccl.field).max_repeat must not be less than 1")
        if hi_rep < lo_rep:
            raise _fail(f, "(dccl.field).max_repeat must not be less than (dccl.field).min_repeat")
        codec = RepeatedCodec(path, codec, lo_rep, hi_rep)
    return codec


def build_fields(m: MessageDef, scheme: Scheme, prefix: str = "",
                 stack: tuple[str, ...] = ()) -> list[tuple[str, FieldCodec]]:
    """``(name, codec)`` of every field DCCL encodes (``omit`` fields left out), in order."""
    stack = stack or (m.full_name,)
    out: list[tuple[str, FieldCodec]] = []
    for f in m.fields:
        if f.options.get("omit"):
            continue
        path = f"{prefix}.{f.name}" if prefix else f.name
        if f.options.get("in_head") and prefix:
            raise _fail(f, "in_head inside an embedded message is not implemented by zab "
                        "(set in_head on the top-level field)")
        out.append((f.name, _codec(f, path, scheme, stack)))
    return out


def build_message(m: MessageDef, scheme: Scheme, path: str, required: bool,
                  stack: tuple[str, ...] = (), names: set[str] | None = None) -> MessageCodec:
    """A :class:`MessageCodec` for ``m`` (only the fields in ``names``, if given); ``path``
    empty for the root message."""
    if scheme.version == 3 and m.oneofs:
        first = next(f for f in m.fields if f.oneof is not None)
        raise _fail(first, "Version 3 does not support 'oneof' (set (dccl.msg).codec_version "
                    "to 4 or more)")
    fields = build_fields(m, scheme, path, stack or (m.full_name,))
    if names is not None:
        fields = [(n, c) for n, c in fields if n in names]
    # a oneof's case counts every member, omitted ones included (oneof_size)
    oneofs = [(o, [f.name for f in m.fields if f.oneof == o]) for o in m.oneofs]
    if names is not None:
        oneofs = [(o, members) for o, members in oneofs if set(members) & names]
    codec = MessageCodec(path, required, fields, {f.name: f.number for f in m.fields}, oneofs)
    codec.codec_name = f"dccl.default{scheme.version}"
    return codec
