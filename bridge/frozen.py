"""A faster ``__init__`` for frozen dataclasses built at every frame (pure: no I/O).

A frozen dataclass's generated ``__init__`` stores each field through ``object.__setattr__``
(its own ``__setattr__`` refuses), ~85 ns a field on CPython 3.11: a reception in the
virtual-clock simulator builds several such records (the ocean's delivery, the modem's
reception, the core's publication, status and event, the fleet's timed output). ``direct_init``
stores the fields through their slots, or the instance ``__dict__``, instead: the same
parameters, defaults and instance, for 0.61 of the cost (``bench/record_init_bench.py``, one
run on the 2-core VM of issue #28, a record of five fields: generated 860 ns, direct 528 ns;
a slotted dataclass that is not frozen, 253 ns, would lose the records' immutability and hash).
The ``__init__`` is built from source with ``exec``, as :mod:`dataclasses` builds its own:
the only way to get one call with the class's exact signature and defaults.
"""

from __future__ import annotations

import dataclasses
from types import MemberDescriptorType
from typing import Any, TypeVar

__all__ = ["direct_init"]

T = TypeVar("T", bound=type)

class _Factory:
    """Stands for a missing argument of a field with a ``default_factory``."""

    def __repr__(self) -> str:
        return "<factory>"  # as in the generated signature


_FACTORY = _Factory()


def direct_init(cls: T) -> T:
    """Replace the frozen dataclass ``cls``'s ``__init__`` by one storing every field directly
    (see the module docstring). Classes with ``__post_init__``, ``init=False`` or keyword-only
    fields, or slots for some fields only, are refused (TypeError)."""
    fields = dataclasses.fields(cls)
    if hasattr(cls, "__post_init__") or any(not f.init or f.kw_only for f in fields):
        raise TypeError(f"direct_init: {cls.__name__} needs the generated __init__")
    slots = [_slot(cls, f.name) for f in fields]
    if any(s is None for s in slots) and not all(s is None for s in slots):
        raise TypeError(f"direct_init: {cls.__name__} has slots for some fields only")
    ns: dict[str, Any] = {"_FACTORY": _FACTORY}
    params, body = [], []
    if slots and slots[0] is None:
        body.append("__dict_of_self__ = __self__.__dict__")
    for i, (f, slot) in enumerate(zip(fields, slots, strict=True)):
        name = f.name
        if f.default_factory is not dataclasses.MISSING:
            ns[f"_factory{i}"] = f.default_factory
            params.append(f"{name}=_FACTORY")
            body.append(f"if {name} is _FACTORY: {name} = _factory{i}()")
        elif f.default is not dataclasses.MISSING:
            ns[f"_default{i}"] = f.default
            params.append(f"{name}=_default{i}")
        else:
            params.append(name)
        if slot is not None:
            ns[f"_set{i}"] = slot.__set__
            body.append(f"_set{i}(__self__, {name})")
        else:
            body.append(f"__dict_of_self__[{name!r}] = {name}")
    source = (f"def __init__(__self__, {', '.join(params)}):\n"
              + "".join(f"    {line}\n" for line in body or ["pass"]))
    exec(compile(source, f"<direct_init {cls.__qualname__}>", "exec"), ns)
    init = ns["__init__"]
    init.__qualname__ = f"{cls.__qualname__}.__init__"
    init.__module__ = cls.__module__
    init.__doc__ = vars(cls)["__init__"].__doc__
    cls.__init__ = init  # type: ignore[misc]
    return cls


def _slot(cls: type, name: str) -> MemberDescriptorType | None:
    """The slot that stores field ``name`` of ``cls``, None if it has none (a ``__dict__``)."""
    for klass in cls.__mro__:
        found = vars(klass).get(name)
        if isinstance(found, MemberDescriptorType):
            return found
    return None
