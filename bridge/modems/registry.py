"""Backend lookup by name: built-ins imported lazily, plus the ``zab.backends`` entry points.

A third-party package registers a backend in its own ``pyproject.toml``::

    [project.entry-points."zab.backends"]
    mymodem = "mypkg.modem:MyModemBackend"
"""

from __future__ import annotations

import importlib
from importlib.metadata import entry_points

from bridge.errors import BackendError
from bridge.mission.backends import ENTRY_POINT_GROUP
from bridge.modems.base import ModemBackend

__all__ = ["BUILTIN_BACKENDS", "ENTRY_POINT_GROUP", "available_backends", "load_backend"]

BUILTIN_BACKENDS: dict[str, str] = {
    "sim": "bridge.modems.sim:SimBackend",
    "udp": "bridge.modems.udp:UdpBackend",
    "evologics": "bridge.modems.evologics.driver:EvologicsBackend",
    "micromodem": "bridge.modems.micromodem.driver:MicromodemBackend",
}
"""Name -> ``"module:Class"``; modules are imported only when their backend is loaded."""


def available_backends() -> dict[str, str]:
    """Every known backend name and its ``"module:Class"`` target (built-ins win)."""
    found: dict[str, str] = {}
    try:
        for ep in entry_points(group=ENTRY_POINT_GROUP):
            found[ep.name] = ep.value
    except Exception:  # a broken installed distribution must not hide the built-ins
        pass
    found.update(BUILTIN_BACKENDS)
    return dict(sorted(found.items()))


def load_backend(name: str) -> type[ModemBackend]:
    """Import and return the backend class called ``name``; :class:`BackendError` if unknown."""
    known = available_backends()
    target = known.get(name)
    if target is None:
        raise BackendError(
            f"unknown modem backend {name!r}; known backends: {', '.join(known) or 'none'}"
        )
    module_name, _, attr = target.partition(":")
    try:
        module = importlib.import_module(module_name)
        cls = getattr(module, attr) if attr else module
    except ImportError as exc:
        raise BackendError(f"backend {name!r} cannot be imported ({target}): {exc}") from exc
    except AttributeError as exc:
        raise BackendError(f"backend {name!r}: {target} does not exist") from exc
    if not (isinstance(cls, type) and issubclass(cls, ModemBackend)):
        raise BackendError(f"backend {name!r}: {target} is not a ModemBackend subclass")
    return cls
