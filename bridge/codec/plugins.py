"""Codec plug-ins: find a ``FieldCodec`` class by the name written in ``codec:``.

Lookup order: the registry (built-ins such as ``ccl.depth``, plus :func:`register_codec`), then
``"package.module:Class"``, then an entry point named so in the ``zab.codecs`` group (so vendor
codecs can ship as separate packages, like python-can's interfaces). Imports happen on use.
"""

from __future__ import annotations

import importlib
from importlib import metadata

from bridge.codec.ccl import CCL_CODECS
from bridge.codec.fields import FieldCodec
from bridge.errors import LayoutError

__all__ = ["ENTRY_POINT_GROUP", "known_codecs", "register_codec", "resolve_codec"]

ENTRY_POINT_GROUP = "zab.codecs"

_REGISTRY: dict[str, type[FieldCodec]] = dict(CCL_CODECS)


def _check_class(obj: object, name: str) -> type[FieldCodec]:
    if not (isinstance(obj, type) and issubclass(obj, FieldCodec)):
        raise LayoutError(f"codec {name!r} is {obj!r}, not a FieldCodec subclass")
    return obj


def register_codec(name: str, cls: type[FieldCodec], *, replace: bool = False) -> None:
    """Make ``cls`` available as ``codec: name``; re-registering needs ``replace=True``."""
    _check_class(cls, name)
    if not name or ":" in name:
        raise ValueError(f"codec name must be non-empty and without ':' (got {name!r})")
    if name in _REGISTRY and _REGISTRY[name] is not cls and not replace:
        raise ValueError(f"codec {name!r} is already registered as {_REGISTRY[name]!r}")
    _REGISTRY[name] = cls


def _entry_points() -> list[metadata.EntryPoint]:
    return list(metadata.entry_points(group=ENTRY_POINT_GROUP))


def known_codecs() -> list[str]:
    """Registered names and installed entry point names, sorted."""
    return sorted(set(_REGISTRY) | {ep.name for ep in _entry_points()})


def _import(target: str, name: str) -> object:
    module_name, _, attr = target.partition(":")
    if not module_name or not attr:
        raise LayoutError(f"codec {name!r}: expected 'package.module:Class'")
    try:
        obj: object = importlib.import_module(module_name)
    except ImportError as exc:
        raise LayoutError(f"codec {name!r}: cannot import {module_name!r}: {exc}") from exc
    for part in attr.split("."):
        try:
            obj = getattr(obj, part)
        except AttributeError:
            raise LayoutError(f"codec {name!r}: {module_name!r} has no {attr!r}") from None
    return obj


def resolve_codec(name: str) -> type[FieldCodec]:
    """The codec class for ``name``; ``LayoutError`` listing the known names if none matches."""
    if name in _REGISTRY:
        return _REGISTRY[name]
    if ":" in name:
        return _check_class(_import(name, name), name)
    matches = [ep for ep in _entry_points() if ep.name == name]
    if matches:
        try:
            obj = matches[0].load()
        except Exception as exc:
            raise LayoutError(
                f"codec {name!r}: entry point {matches[0].value!r} failed to load: {exc}"
            ) from exc
        return _check_class(obj, name)
    known = ", ".join(known_codecs())
    raise LayoutError(
        f"unknown codec {name!r}; known codecs: {known} "
        f"(or 'package.module:Class', or an entry point in group {ENTRY_POINT_GROUP!r})"
    )
