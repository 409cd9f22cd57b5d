"""Bit-level codec engine: field specs, field codecs (built-in, CCL, plug-ins) and layouts.

Sans-I/O: no zenoh, asyncio or serial imports anywhere in this package.
"""

from bridge.codec.bits import BitReader, BitWriter, bits_for, bytes_to_int, int_to_bytes
from bridge.codec.ccl import CclAltitude, CclDepth, CclLatitude, CclLongitude
from bridge.codec.fields import (
    ArrayCodec,
    BoolCodec,
    BytesCodec,
    EnumCodec,
    FieldCodec,
    FloatCodec,
    IntCodec,
    StringCodec,
)
from bridge.codec.layout import Layout, LayoutFile, find_layout_file
from bridge.codec.plugins import ENTRY_POINT_GROUP, known_codecs, register_codec, resolve_codec
from bridge.mission.fields import FieldSpec, FieldType, OutOfRange

__all__ = [
    "ENTRY_POINT_GROUP",
    "ArrayCodec",
    "BitReader",
    "BitWriter",
    "BoolCodec",
    "BytesCodec",
    "CclAltitude",
    "CclDepth",
    "CclLatitude",
    "CclLongitude",
    "EnumCodec",
    "FieldCodec",
    "FieldSpec",
    "FieldType",
    "FloatCodec",
    "IntCodec",
    "Layout",
    "LayoutFile",
    "OutOfRange",
    "StringCodec",
    "bits_for",
    "bytes_to_int",
    "find_layout_file",
    "int_to_bytes",
    "known_codecs",
    "register_codec",
    "resolve_codec",
]
