"""ROS 2 message types from ``rosbags``: type hashes, CDR in and out, plain-data views (sans I/O).

``rosbags`` ships the message definitions of each ROS 2 distribution and a pure-Python CDR
codec; nothing here writes CDR by hand. A message travels through the bridge as *plain data*:
nested dicts of Python scalars, numeric arrays as lists, ``uint8``/``byte`` arrays as ``bytes``,
so the channel layouts pick fields by dotted path exactly as in msgpack payloads.
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass
from functools import cache
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.base import Nodetype  # type: ignore[attr-defined]  # (not in __all__)

from bridge.errors import DecodeError, EncodeError
from bridge.ros2.names import parse_topic_key

Distro = Literal["jazzy", "kilted"]
DISTROS: dict[str, Stores] = {"jazzy": Stores.ROS2_JAZZY, "kilted": Stores.ROS2_KILTED}

_INTS = {"int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64", "byte",
         "char"}
_FLOATS = {"float32", "float64"}
_BYTES = {"uint8", "byte", "char"}  # arrays of these are ``bytes`` in plain data
# Defaults written in the message definitions (``float64 w 1``), which rosbags does not carry.
DEFINITION_DEFAULTS: dict[tuple[str, str], Any] = {("geometry_msgs/msg/Quaternion", "w"): 1.0}
_DTYPES = {"bool": np.bool_, "byte": np.uint8, "char": np.uint8, "int8": np.int8,
           "uint8": np.uint8, "int16": np.int16, "uint16": np.uint16, "int32": np.int32,
           "uint32": np.uint32, "int64": np.int64, "uint64": np.uint64, "float32": np.float32,
           "float64": np.float64}


class UnknownType(ValueError):
    """A message type the chosen distribution does not define."""


@cache
def typestore(distro: str) -> Any:
    """The ``rosbags`` type store of ``distro`` (loaded once)."""
    if distro not in DISTROS:
        raise UnknownType(f"unknown ROS 2 distribution {distro!r}; known: {', '.join(DISTROS)}")
    return get_typestore(DISTROS[distro])


def check_type(distro: str, msgtype: str) -> None:
    """Raise :class:`UnknownType` (with close names) unless ``msgtype`` exists in ``distro``."""
    store = typestore(distro)
    if msgtype not in store.fielddefs:
        close = difflib.get_close_matches(msgtype, list(store.fielddefs), n=3)
        hint = f"; did you mean {', '.join(close)}?" if close else ""
        raise UnknownType(f"{msgtype!r} is not a message type of ROS 2 {distro}{hint}")


@cache
def type_hash(distro: str, msgtype: str) -> str:
    """The REP-2011 type hash ``RIHS01_<sha256>`` of ``msgtype``, as rmw_zenoh puts in keys."""
    check_type(distro, msgtype)
    return str(typestore(distro).hash_rihs01(msgtype))


@dataclass(frozen=True)
class Leaf:
    """What a dotted path names in a message: a base type, maybe an array of ``count`` (None:
    unbounded sequence), or a nested message (``message`` set)."""

    base: str | None
    array: bool = False
    count: int | None = None
    message: str | None = None

    @property
    def plain(self) -> str:
        """The plain-data kind: number, bool, string, bytes, list, message."""
        if self.message is not None:
            return "list" if self.array else "message"
        if self.array:
            return "bytes" if self.base in _BYTES else "list"
        if self.base == "bool":
            return "bool"
        if self.base == "string" or self.base == "wstring":
            return "string"
        return "number"


def _leaf(desc: tuple[Any, Any]) -> Leaf:
    kind, rest = desc
    if kind == Nodetype.NAME:
        return Leaf(None, message=rest)
    if kind == Nodetype.BASE:
        return Leaf(rest[0])
    (inner_kind, inner), count = rest
    size = count if kind == Nodetype.ARRAY else None
    if inner_kind == Nodetype.NAME:
        return Leaf(None, array=True, count=size, message=inner)
    return Leaf(inner[0], array=True, count=size)


def resolve(distro: str, msgtype: str, path: str) -> Leaf:
    """The :class:`Leaf` at ``path`` of ``msgtype``; ``KeyError`` naming the first bad part."""
    store = typestore(distro)
    current, leaf = msgtype, Leaf(None, message=msgtype)
    parts = path.split(".")
    for depth, part in enumerate(parts):
        if leaf.message is None or leaf.array:
            where = ".".join(parts[:depth])
            raise KeyError(f"{where!r} is not a message, it has no field {part!r}")
        current = leaf.message
        fields = dict(store.fielddefs[current][1])
        if part not in fields:
            raise KeyError(f"{current} has no field {part!r} (fields: {', '.join(fields)})")
        leaf = _leaf(fields[part])
    return leaf


def to_plain(msg: Any) -> Any:
    """A deserialised message as plain data (see the module docstring)."""
    if isinstance(msg, np.ndarray):
        if msg.dtype == np.uint8:
            return msg.tobytes()
        return msg.tolist()
    if isinstance(msg, list):
        return [to_plain(m) for m in msg]
    fields = getattr(msg, "__dataclass_fields__", None)
    if fields is None:
        return msg
    return {name: to_plain(getattr(msg, name)) for name in fields if name != "__msgtype__"}


def decode_cdr(distro: str, msgtype: str, data: bytes) -> dict[str, Any]:
    """Plain data of a CDR message (4-byte encapsulation header first, as rmw_zenoh sends).

    ``DecodeError`` for anything that is not a whole, valid ``msgtype``."""
    if len(data) < 4 or data[0] != 0 or data[1] not in (0, 1):
        raise DecodeError(f"not a CDR {msgtype}: bad encapsulation header {data[:4].hex()}")
    try:
        msg = typestore(distro).deserialize_cdr(bytes(data), msgtype)
    except Exception as exc:  # rosbags raises struct/index/unicode/assertion errors alike
        raise DecodeError(f"malformed CDR for {msgtype}: {type(exc).__name__}: {exc}") from None
    plain: dict[str, Any] = to_plain(msg)
    return plain


def _build(store: Any, msgtype: str, tree: Any, path: str, strict: bool) -> Any:
    values = tree if isinstance(tree, dict) else {}
    if tree is not None and not isinstance(tree, dict):
        raise EncodeError(f"{path or msgtype}: expected a mapping for {msgtype}, "
                          f"got {type(tree).__name__}")
    fields = store.fielddefs[msgtype][1]
    if strict and (unknown := [n for n in values if n not in {f for f, _ in fields}]):
        raise EncodeError(f"{path + ': ' if path else ''}no field {unknown[0]!r} in {msgtype} "
                          f"(its fields: {', '.join(f for f, _ in fields)})")
    kwargs = {}
    for name, desc in fields:
        where = f"{path}.{name}" if path else name
        value = values.get(name, DEFINITION_DEFAULTS.get((msgtype, name)))
        kwargs[name] = _value(store, _leaf(desc), value, where, strict)
    return store.types[msgtype](**kwargs)


def _scalar(base: str, value: Any, where: str) -> Any:
    if base in ("string", "wstring"):
        if value is None:
            return ""
        if not isinstance(value, str):
            raise EncodeError(f"{where}: expected a string, got {type(value).__name__}")
        return value
    if value is None:
        return False if base == "bool" else 0 if base in _INTS else 0.0
    if base == "bool":
        return bool(value)
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise EncodeError(f"{where}: expected a number, got {type(value).__name__}")
    if base in _INTS:
        info = np.iinfo(_DTYPES[base])
        if not math.isfinite(value):
            raise EncodeError(f"{where}: {value} does not fit a {base}")
        n = round(value)
        if not info.min <= n <= info.max:
            raise EncodeError(f"{where}: {value} does not fit a {base}")
        return n
    return float(value)


def _value(store: Any, leaf: Leaf, value: Any, where: str, strict: bool) -> Any:
    if not leaf.array:
        if leaf.message is not None:
            return _build(store, leaf.message, value, where, strict)
        assert leaf.base is not None
        return _scalar(leaf.base, value, where)
    items: list[Any] | bytes
    if value is None:
        items = []
    elif isinstance(value, bytes | bytearray):
        items = bytes(value)  # (a picture's megabytes: never a list of ints)
    elif isinstance(value, list | tuple):
        items = list(value)
    else:
        raise EncodeError(f"{where}: expected a list, got {type(value).__name__}")
    if leaf.count is not None:
        if value is not None and len(items) != leaf.count:
            raise EncodeError(f"{where}: needs {leaf.count} values, got {len(items)}")
        if value is None:
            items = [None] * leaf.count
    if leaf.message is not None:
        return [_build(store, leaf.message, v, f"{where}.{i}", strict)
                for i, v in enumerate(items)]
    assert leaf.base is not None
    if leaf.base in _BYTES and isinstance(items, bytes):
        return np.frombuffer(items, dtype=np.uint8)
    numbers = _numbers(leaf.base, items)
    if numbers is not None:
        return numbers
    scalars = [_scalar(leaf.base, v, f"{where}.{i}") for i, v in enumerate(items)]
    if leaf.base in _DTYPES:
        with np.errstate(over="ignore"):
            return np.array(scalars, dtype=_DTYPES[leaf.base])
    return scalars  # strings


def _numbers(base: str, items: list[Any] | bytes) -> NDArray[Any] | None:
    """``items`` as a numeric array field, all at once, as :func:`_scalar` takes each (ints
    rounded, each within its type); None where one of them is no number for it (bools are
    not) or out of range: the element-wise path then says which."""
    dtype = _DTYPES.get(base)
    if dtype is None or base == "bool" or not len(items):
        return None
    if isinstance(items, list) and any(type(v) is bool for v in items):
        return None
    try:
        array = np.asarray(items)
    except (TypeError, ValueError):
        return None
    if array.ndim != 1 or array.dtype.kind not in "iuf":
        return None
    if base in _FLOATS:
        with np.errstate(over="ignore"):  # (beyond a float32: inf, as one value at a time)
            return array.astype(dtype)
    if array.dtype.kind == "f":
        if not np.isfinite(array).all():
            return None
        array = np.rint(array)
    info = np.iinfo(dtype)
    if array.min() < info.min or array.max() > info.max:
        return None
    return array.astype(dtype)


def encode_cdr(distro: str, msgtype: str, tree: dict[str, Any], *,
               strict: bool = False) -> bytes:
    """A complete CDR ``msgtype`` from plain data; every field not in ``tree`` is zero/empty.

    ``EncodeError`` when a value does not fit its field, and, ``strict``, when ``tree`` names
    a field the type has not (else such names are ignored)."""
    store = typestore(distro)
    msg = _build(store, msgtype, tree, "", strict)
    try:
        return bytes(store.serialize_cdr(msg, msgtype))
    except Exception as exc:
        raise EncodeError(f"cannot serialise {msgtype}: {type(exc).__name__}: {exc}") from None


def set_path(tree: dict[str, Any], path: str, value: Any) -> None:
    """Put ``value`` at dotted ``path`` in nested dicts (creating them)."""
    *parents, last = path.split(".")
    node = tree
    for part in parents:
        node = node.setdefault(part, {})
    node[last] = value


def merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """``base`` with ``over`` laid on top, nested dicts merged (neither is changed)."""
    out = dict(base)
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merge(out[key], value)
        else:
            out[key] = value
    return out


def decode_sample(key: str, data: bytes) -> dict[str, Any] | None:
    """A sample on an rmw_zenoh data key as plain data, its type read from the key
    (:func:`_keyed_type`); None if the key names no type this bridge knows. ``DecodeError``
    if it does and ``data`` is not a whole message of it."""
    found = _keyed_type(key)
    return None if found is None else decode_cdr(*found, data)


def encode_sample(key: str, tree: Any, *, strict: bool = False) -> bytes | None:
    """``tree`` as the CDR message an rmw_zenoh data ``key`` names (:func:`_keyed_type`);
    None if the key names no type this bridge knows. ``EncodeError`` when a value does not
    fit its field (or, ``strict``, names no field: :func:`encode_cdr`)."""
    found = _keyed_type(key)
    if found is None:
        return None
    if not isinstance(tree, dict):
        raise EncodeError(f"{found[1]}: expected the message's fields as an object")
    return encode_cdr(*found, tree, strict=strict)


def _keyed_type(key: str) -> tuple[str, str] | None:
    """(distribution, message type) an rmw_zenoh data ``key`` names: the first known
    distribution whose type hash the key carries; None for any other key."""
    try:
        got = parse_topic_key(key)
    except ValueError:
        return None
    if not got.msgtype:
        return None
    distro = _distro_of(got.msgtype, got.type_hash)
    return None if distro is None else (distro, got.msgtype)


@cache
def _distro_of(msgtype: str, hash_: str) -> str | None:
    """The first known distribution whose ``msgtype`` has the type hash ``hash_``."""
    for distro in DISTROS:
        try:
            if type_hash(distro, msgtype) == hash_:
                return distro
        except (UnknownType, KeyError):
            continue
    return None
