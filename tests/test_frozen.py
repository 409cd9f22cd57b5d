"""``direct_init``: the same instances as a frozen dataclass's generated ``__init__``."""

from __future__ import annotations

import dataclasses
import inspect
from dataclasses import dataclass, field
from typing import Any

import pytest

from bridge.frozen import direct_init


def pair(slots: bool) -> tuple[type, type]:
    """One frozen dataclass (a base with a field, defaults, a factory) as generated, and
    again with ``direct_init``."""

    def make() -> type:
        @dataclass(frozen=True, slots=slots)
        class Base:
            time: float

        @dataclass(frozen=True, slots=slots)
        class Record(Base):
            src: str
            size: int = 0
            meta: dict[str, Any] = field(default_factory=dict)
            extra: Any = None

        return Record

    return make(), direct_init(make())


@pytest.mark.parametrize("slots", [True, False])
@pytest.mark.parametrize("args, kwargs", [
    ((1.0, "a"), {}),
    ((1.0, "a", 3), {"extra": [1]}),
    ((), {"time": 2.0, "src": "b", "meta": {"k": 1}, "size": 5}),
])
def test_same_instance_as_the_generated_init(slots: bool, args: tuple, kwargs: dict) -> None:
    generated, direct = pair(slots)
    a, b = generated(*args, **kwargs), direct(*args, **kwargs)
    assert repr(a) == repr(b)
    assert dataclasses.astuple(a) == dataclasses.astuple(b)
    assert b == direct(*args, **kwargs)
    assert direct(1.0, "x").meta is not direct(1.0, "x").meta  # a fresh default each time
    with pytest.raises(dataclasses.FrozenInstanceError):
        b.src = "c"  # type: ignore[misc]


@pytest.mark.parametrize("slots", [True, False])
def test_same_signature(slots: bool) -> None:
    generated, direct = pair(slots)
    want = [(p.name, p.kind, p.default) for p in inspect.signature(generated).parameters.values()]
    got = [(p.name, p.kind, p.default) for p in inspect.signature(direct).parameters.values()]
    assert [w[:2] for w in want] == [g[:2] for g in got]
    assert repr([w[2] for w in want]) == repr([g[2] for g in got])
    with pytest.raises(TypeError):
        direct()
    with pytest.raises(TypeError):
        direct(1.0, "a", 1, {}, None, "too many")


def test_refuses_what_it_does_not_handle() -> None:
    @dataclass(frozen=True)
    class Later:
        a: int

        def __post_init__(self) -> None:
            pass

    @dataclass(frozen=True)
    class Hidden:
        a: int
        b: int = field(init=False, default=0)

    for cls in (Later, Hidden):
        with pytest.raises(TypeError):
            direct_init(cls)
