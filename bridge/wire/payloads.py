"""Payloads on Zenoh keys: msgpack by default, JSON accepted, chosen by the sample's encoding.

Payloads come from anyone on the Zenoh network, so decoding is bounded: a payload longer than
its key's cap (:func:`payload_cap`, from the bits its channels keep of it) is refused before it
is parsed, text must be strict UTF-8 and nesting at most :data:`MAX_DEPTH` deep; anything else
(a map whose keys are maps or arrays too) is a :class:`DecodeError` (a counted drop for the
caller), never a ``RecursionError`` or a ``TypeError``.
"""

from __future__ import annotations

import contextlib
import json
import math
import re
from itertools import accumulate
from typing import Any

import msgpack

from bridge.errors import DecodeError

MSGPACK = "application/msgpack"
JSON = "application/json"

MAX_DEPTH = 32
"""Deepest nesting of lists and maps a payload may have. Channel fields address values by
dotted paths a few levels deep; 32 leaves ample room while keeping every parser (and every
walk over a decoded value) far from Python's recursion limit (1000), which a 200 000-deep
``[[[[...`` would otherwise hit inside ``json.loads``."""

# A JSON string, from its opening quote to its closing one or to the end of the text. The pattern
# can always match once it starts, so the regex engine never retries it further on: linear time,
# even for text full of unterminated strings and escaped quotes.
PAYLOAD_FLOOR_BYTES = 16 * 1024
"""Every input key accepts payloads this long whatever its channels keep: room for field names,
fields no channel reads and a ROS 2 message's header and covariances."""
PAYLOAD_BYTES_PER_BIT_BYTE = 16
"""And this many payload bytes per byte of the values its channels keep: a string of ``n`` bytes
is at most ``6 n`` as JSON escapes, a byte array ``4 n`` as a JSON list."""


def payload_cap(bits: int) -> int:
    """The longest payload accepted on a key whose channels keep ``bits`` bits of it."""
    return PAYLOAD_FLOOR_BYTES + PAYLOAD_BYTES_PER_BIT_BYTE * ((bits + 7) // 8)


_JSON_STRING = re.compile(r'"(?:[^"\\]|\\.?)*"?', re.DOTALL)
_NOT_BRACKET = re.compile(r"[^\[\]{}]+")
_STEP = {"[": 1, "{": 1, "]": -1, "}": -1}


def _json_text(data: bytes) -> str:
    """``data`` as JSON text: UTF-8 (or the UTF-16/32 JSON allows), strictly decoded, no
    deeper than :data:`MAX_DEPTH` (checked before parsing, in linear time)."""
    try:
        text = data.decode(json.detect_encoding(data))  # strict: no lone surrogates either
    except UnicodeDecodeError as exc:
        raise DecodeError(f"not valid UTF-8: {exc}") from None
    if text.count("[") + text.count("{") > MAX_DEPTH:  # else it cannot nest deeper
        brackets = _NOT_BRACKET.sub("", _JSON_STRING.sub("", text))
        if max(accumulate(map(_STEP.__getitem__, brackets)), default=0) > MAX_DEPTH:
            raise DecodeError(f"nested deeper than {MAX_DEPTH} levels")
    return text


_CONTAINERS = (dict, list, tuple)


def _check_depth(value: Any) -> Any:
    """``value`` unchanged, or :class:`DecodeError` if it nests deeper than :data:`MAX_DEPTH`.

    Walks one level of containers at a time (scalars are looked at once, never stacked)."""
    if value.__class__ is dict:  # the usual payload, a flat map: one look at its values
        for child in value.values():
            if isinstance(child, _CONTAINERS):
                break
        else:
            return value
    level = [value] if isinstance(value, _CONTAINERS) else []
    depth = 0
    while level:
        if depth >= MAX_DEPTH:
            raise DecodeError(f"nested deeper than {MAX_DEPTH} levels")
        depth += 1
        inner = []
        for item in level:
            for child in item.values() if isinstance(item, dict) else item:
                if isinstance(child, _CONTAINERS):
                    inner.append(child)
        level = inner
    return value


def _json(data: bytes) -> Any:
    text = _json_text(data)
    try:
        return json.loads(text)
    except ValueError:
        raise
    except Exception as exc:  # whatever else the parser meets is still a bad payload
        raise ValueError(f"{type(exc).__name__}: {exc}") from None


def _msgpack(data: bytes) -> Any:
    # strict UTF-8 for str (msgpack's default); msgpack's own stack caps nesting at 1024
    # (StackError), and _check_depth brings that down to MAX_DEPTH. A map key that is itself a
    # map or an array raises TypeError (unhashable) inside unpackb: a bad payload too.
    try:
        value = msgpack.unpackb(data, raw=False, strict_map_key=False)
    except msgpack.StackError:
        raise DecodeError(f"nested deeper than {MAX_DEPTH} levels") from None
    except (ValueError, msgpack.UnpackException):
        raise
    except Exception as exc:
        raise ValueError(f"{type(exc).__name__}: {exc}") from None
    return _check_depth(value)


def why_undecodable(exc: Exception, data: bytes) -> str:
    """What a parser found wrong with ``data``, never empty (every path that tells why msgpack
    or JSON could not be read says it so): msgpack's ``FormatError`` (its only cause, the
    reserved byte 0xc1) has no text, so it is named with its offset; any other error without
    text by its type."""
    if isinstance(exc, msgpack.FormatError):
        unpacker = msgpack.Unpacker(raw=False, strict_map_key=False)
        unpacker.feed(data)
        with contextlib.suppress(Exception):  # it raises again, where it stopped
            unpacker.unpack()
        at = unpacker.tell()
        found = f"byte 0x{data[at]:02x}" if at < len(data) else "end"
        return f"reserved {found} at offset {at}" if found == "byte 0xc1" \
            else f"FormatError at offset {at} ({found})"
    return str(exc) or type(exc).__name__


def decode_payload(data: bytes, encoding: str) -> Any:
    """The value a sample carries. Raises :class:`DecodeError` when it is neither format, is not
    strict UTF-8, or nests deeper than :data:`MAX_DEPTH`."""
    kind = encoding.partition(";")[0]
    try:
        if kind in (MSGPACK, "application/x-msgpack"):
            return _msgpack(data)
        if kind in (JSON, "text/json", "text/plain"):
            return _json(data)
    except (ValueError, msgpack.UnpackException) as exc:
        raise DecodeError(f"not valid {kind}: {why_undecodable(exc, data)}") from None
    # untagged (zenoh/bytes): JSON text first, as a person typing a value would send it
    try:
        return _json(data)
    except ValueError as exc:  # DecodeError too: it may still be msgpack
        not_json = why_undecodable(exc, data)
    try:
        return _msgpack(data)
    except (ValueError, msgpack.UnpackException) as exc:
        raise DecodeError(f"neither JSON ({not_json}) nor msgpack ({why_undecodable(exc, data)}) "
                          f"({encoding})") from None


def _jsonable(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, bytes):
        return value.hex()
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    return value


def encode_payload(value: Any, encoding: str = "msgpack") -> tuple[bytes, str]:
    """Bytes and Zenoh encoding string for publishing ``value``."""
    if encoding.startswith("image/"):  # a picture, encoded already (bridge.core.images)
        return bytes(value), encoding
    if encoding == "json":
        return json.dumps(_jsonable(value), separators=(",", ":")).encode(), JSON
    return msgpack.packb(value, use_bin_type=True), MSGPACK
