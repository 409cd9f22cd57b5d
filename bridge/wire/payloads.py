"""Payloads on Zenoh keys: msgpack by default, JSON accepted, chosen by the sample's encoding."""

from __future__ import annotations

import json
import math
from typing import Any

import msgpack

from bridge.errors import DecodeError

MSGPACK = "application/msgpack"
JSON = "application/json"


def decode_payload(data: bytes, encoding: str) -> Any:
    """The value a sample carries. Raises :class:`DecodeError` when it is neither format."""
    kind = encoding.split(";", 1)[0]
    try:
        if kind in (MSGPACK, "application/x-msgpack"):
            return msgpack.unpackb(data, raw=False, strict_map_key=False)
        if kind in (JSON, "text/json", "text/plain"):
            return json.loads(data)
    except (ValueError, msgpack.UnpackException) as exc:
        raise DecodeError(f"not valid {kind}: {exc}") from None
    # untagged (zenoh/bytes): JSON text first, as a person typing a value would send it
    try:
        return json.loads(data)
    except ValueError:
        pass
    try:
        return msgpack.unpackb(data, raw=False, strict_map_key=False)
    except (ValueError, msgpack.UnpackException) as exc:
        raise DecodeError(f"neither JSON nor msgpack ({encoding}): {exc}") from None


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
    if encoding == "json":
        return json.dumps(_jsonable(value), separators=(",", ":")).encode(), JSON
    return msgpack.packb(value, use_bin_type=True), MSGPACK
