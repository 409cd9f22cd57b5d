"""``Layout``: an ordered list of field codecs packed into one fixed-width int.

The first field sits in the most significant bits. ``pack``/``unpack``/``encode``/``decode`` are
generated per layout (see :mod:`bridge.codec.compile`); the ``*_reference`` methods are the
plain loop over field codecs that the generated code falls back to and is tested against.
"""

from __future__ import annotations

import numbers
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, ValidationError

from bridge.codec.bits import bytes_to_int, nbytes_for
from bridge.codec.compile import compile_layout
from bridge.codec.fields import ArrayCodec, FieldCodec, checked_decode, checked_encode
from bridge.codec.fields import codec_for_type as _codec_for_type
from bridge.codec.plugins import resolve_codec
from bridge.errors import DecodeError, EncodeError, LayoutError
from bridge.mission.fields import FieldSpec, OutOfRange
from bridge.resources import data_dir

__all__ = ["Layout", "LayoutFile", "find_layout_file", "validation_message"]

#: Layout files may include other layouts; this deep is surely a cycle.
MAX_LAYOUT_DEPTH = 8

_MISSING = object()


class LayoutFile(BaseModel):
    """A reusable layout file under ``codecs/``: ``{description, fields}``."""

    model_config = ConfigDict(extra="forbid")

    description: str = ""
    fields: list[dict[str, Any]]


def validation_message(exc: ValidationError) -> tuple[str, tuple[str | int, ...]]:
    """A one-paragraph message and the ``loc`` of the first error of a pydantic error."""
    errors = exc.errors(include_url=False)
    parts = []
    for err in errors:
        where = ".".join(str(p) for p in err["loc"])
        parts.append(f"{where}: {err['msg']}" if where else err["msg"])
    return "; ".join(parts), tuple(errors[0]["loc"]) if errors else ()


def find_layout_file(name: str, dirs: Sequence[Path] = ()) -> Path:
    """The YAML file of layout ``name`` in ``dirs`` then ``codecs/``; LayoutError if absent."""
    looked: list[Path] = []
    for base in [*dirs, data_dir("codecs")]:
        for candidate in (base / f"{name}.yaml", base / f"{name}.yml"):
            looked.append(candidate)
            if candidate.is_file():
                return candidate
    raise LayoutError(f"layout {name!r} not found; looked at: {', '.join(str(p) for p in looked)}")


def _join(prefix: str, path: str) -> str:
    return f"{prefix}.{path}" if prefix and path else prefix or path


def _build_codec(spec: FieldSpec, index: int) -> FieldCodec:
    """The codec of one (already path-resolved) spec; errors as LayoutError with loc."""
    if spec.codec is not None:
        try:
            cls = resolve_codec(spec.codec)
        except LayoutError as exc:
            raise LayoutError(str(exc), (index, "codec")) from exc
        element_spec = spec.model_copy(update={"count": None})
        try:
            codec = cls(element_spec)
        except (LayoutError, ValueError, TypeError, KeyError) as exc:
            raise LayoutError(f"codec {spec.codec!r}: {exc}", (index, "params")) from exc
        bits = getattr(codec, "bits", None)
        if isinstance(bits, bool) or not isinstance(bits, int) or not 0 <= bits <= 8 * 1024:
            raise LayoutError(f"codec {spec.codec!r} has invalid bits {bits!r}", (index, "codec"))
    else:
        assert spec.type is not None
        codec = _codec_for_type(spec.type)(spec.model_copy(update={"count": None}))
    if spec.count is not None:
        codec = ArrayCodec(spec, codec, spec.count)
    return codec


def _expand(
    items: Iterable[Any],
    default: OutOfRange,
    dirs: Sequence[Path],
    prefix: str = "",
    depth: int = 0,
) -> list[tuple[FieldCodec, int]]:
    """Codecs (with full paths) and the top-level index each came from."""
    out: list[tuple[FieldCodec, int]] = []
    for index, item in enumerate(items):
        if isinstance(item, FieldSpec):
            spec = item
        elif isinstance(item, Mapping):
            try:
                spec = FieldSpec.model_validate(dict(item))
            except ValidationError as exc:
                message, loc = validation_message(exc)
                raise LayoutError(message, (index, *loc)) from None
        else:
            raise LayoutError(f"expected a field mapping, got {type(item).__name__}", (index,))
        path = _join(prefix, spec.field)
        policy: OutOfRange = spec.on_out_of_range or default
        if spec.layout is not None:
            if depth >= MAX_LAYOUT_DEPTH:
                raise LayoutError(f"layouts nest deeper than {MAX_LAYOUT_DEPTH}", (index, "layout"))
            try:
                file = find_layout_file(spec.layout, dirs)
                inner = load_layout_file(file)
                nested = _expand(inner.fields, policy, dirs, path, depth + 1)
            except LayoutError as exc:
                inner_loc = ".".join(str(p) for p in exc.loc)
                where = f" (fields.{inner_loc})" if inner_loc else ""
                raise LayoutError(
                    f"layout {spec.layout!r}{where}: {exc}", (index, "layout")
                ) from exc
            out.extend((codec, index) for codec, _ in nested)
            continue
        resolved = spec.model_copy(update={"field": path, "on_out_of_range": policy})
        out.append((_build_codec(resolved, index), index))
    return out


def load_layout_file(file: Path) -> LayoutFile:
    """Parse and check a layout YAML file (fields are checked when expanded)."""
    try:
        data = yaml.safe_load(file.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError) as exc:
        raise LayoutError(f"cannot read {file}: {exc}") from exc
    try:
        return LayoutFile.model_validate(data)
    except ValidationError as exc:
        message, _ = validation_message(exc)
        raise LayoutError(f"{file}: {message}") from None


def _check_paths(entries: list[tuple[FieldCodec, int]]) -> None:
    seen: dict[str, int] = {}
    for codec, index in entries:
        path = codec.path
        for other in seen:
            clash = path == other or not path or not other
            clash = clash or path.startswith(other + ".") or other.startswith(path + ".")
            if clash:
                shown = other or "(whole payload)"
                raise LayoutError(
                    f"field {path or '(whole payload)'!r} overlaps field {shown!r}",
                    (index, "field"),
                )
        seen[path] = index


class Layout:
    """A fixed-width bit layout: ``bits`` long, fields packed first-field-most-significant."""

    def __init__(self, fields: Sequence[FieldCodec], description: str = "") -> None:
        self.fields: tuple[FieldCodec, ...] = tuple(fields)
        self.description = description
        self.bits: int = sum(f.bits for f in self.fields)
        self.nbytes: int = nbytes_for(self.bits)
        self._parts = [tuple(f.path.split(".")) if f.path else () for f in self.fields]
        self._enc = [checked_encode(f) for f in self.fields]
        self._dec = [checked_decode(f) for f in self.fields]
        compiled = compile_layout(
            self.fields,
            {
                "pack": self.pack_reference,
                "unpack": self.unpack_reference,
                "encode": self.encode_reference,
                "decode": self.decode_reference,
            },
        )
        self.source = compiled.source
        # Plain functions stored on the instance: no bound-method overhead on the hot path.
        self.pack = compiled.pack
        self.unpack = compiled.unpack
        self.encode = compiled.encode
        self.decode = compiled.decode

    @classmethod
    def from_fields(
        cls,
        fields: Iterable[Mapping[str, Any] | FieldSpec],
        *,
        on_out_of_range: Literal["clamp", "reject"] = "clamp",
        layout_dirs: Sequence[Path] = (),
        description: str = "",
    ) -> Layout:
        """Compile a field list (dicts or ``FieldSpec``) into a layout; LayoutError(loc) if bad."""
        if on_out_of_range not in ("clamp", "reject"):
            raise ValueError(
                f"on_out_of_range must be 'clamp' or 'reject', not {on_out_of_range!r}"
            )
        entries = _expand(fields, on_out_of_range, tuple(layout_dirs))
        _check_paths(entries)
        return cls([codec for codec, _ in entries], description)

    @classmethod
    def load(cls, name: str, *, on_out_of_range: Literal["clamp", "reject"] = "clamp") -> Layout:
        """A layout file from ``codecs/`` by name, e.g. ``Layout.load("ccl/bathymetry")``."""
        file = find_layout_file(name)
        return cls.from_fields(
            [{"layout": name}],
            on_out_of_range=on_out_of_range,
            description=load_layout_file(file).description,
        )

    # -- introspection -------------------------------------------------------------------------
    @property
    def clamped(self) -> dict[str, int]:
        """How many values each field path has clamped so far."""
        return {f.path: f.clamped for f in self.fields}

    def json_schema(self) -> dict[str, Any]:
        """JSON Schema (2020-12) of the whole payload; extra keys in objects are allowed."""
        root: dict[str, Any] = {"type": "object", "properties": {}, "required": []}
        for f in self.fields:
            if not f.path:
                root = dict(f.json_schema())
                break
            node = root
            parts = f.path.split(".")
            for part in parts[:-1]:
                props = node["properties"]
                if part not in props:
                    props[part] = {"type": "object", "properties": {}, "required": []}
                    node["required"].append(part)
                node = props[part]
            node["properties"][parts[-1]] = f.json_schema()
            node["required"].append(parts[-1])
        schema = {"$schema": "https://json-schema.org/draft/2020-12/schema", **root}
        if self.description:
            schema.setdefault("description", self.description)
        return schema

    def describe(self) -> str:
        """One line per field: path, bits, what it holds."""
        width = max((len(f.path) for f in self.fields), default=0)
        lines = [f"{f.path or '(payload)':<{width}}  {f.describe()}" for f in self.fields]
        lines.append(f"{'total':<{width}}  {self.bits} bit ({self.nbytes} byte)")
        return "\n".join(lines)

    def __repr__(self) -> str:
        return f"<Layout {len(self.fields)} fields, {self.bits} bits>"

    # -- reference path ------------------------------------------------------------------------
    def pack_reference(self, value: Any) -> int:
        """Pack field by field (the readable twin of the generated ``pack``)."""
        n = 0
        for codec, parts, enc in zip(self.fields, self._parts, self._enc, strict=True):
            item = value
            for depth, part in enumerate(parts):
                try:
                    item = item[part]
                except (KeyError, TypeError, IndexError):
                    where = ".".join(parts[: depth + 1])
                    if where == codec.path:
                        raise EncodeError(f"{codec.path}: missing") from None
                    raise EncodeError(f"{codec.path}: missing ({where!r} not found)") from None
            n = (n << codec.bits) | enc(item)
        return n

    def unpack_reference(self, n: int) -> Any:
        """Unpack field by field; ``DecodeError`` for anything invalid."""
        if isinstance(n, bool) or not isinstance(n, numbers.Integral):
            raise DecodeError(f"expected an int, got {type(n).__name__}")
        n = int(n)
        if n < 0 or n >> self.bits:
            raise DecodeError(f"{n} does not fit in {self.bits} bits")
        out: dict[str, Any] = {}
        shift = self.bits
        for codec, parts, dec in zip(self.fields, self._parts, self._dec, strict=True):
            shift -= codec.bits
            value = dec((n >> shift) & ((1 << codec.bits) - 1))
            if not parts:
                return value
            node = out
            for part in parts[:-1]:
                node = node.setdefault(part, {})
            node[parts[-1]] = value
        return out

    def encode_reference(self, value: Any) -> bytes:
        """``pack_reference`` as bytes (big-endian, zero pad bits at the end)."""
        pad = -self.bits % 8
        return (self.pack_reference(value) << pad).to_bytes(self.nbytes, "big")

    def decode_reference(self, data: bytes) -> Any:
        """Inverse of ``encode_reference``; ``DecodeError`` on wrong length or pad bits."""
        if not isinstance(data, bytes | bytearray | memoryview):
            raise DecodeError(f"expected bytes, got {type(data).__name__}")
        return self.unpack_reference(bytes_to_int(bytes(data), self.bits))
