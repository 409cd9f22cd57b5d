"""What ``bridge.frozen.direct_init`` saves: building a frozen record (as every frame builds
several) with the dataclass's generated ``__init__`` against ``direct_init``'s, side by side
in one run; a plain (not frozen) slotted dataclass is the floor.

Run: ``uv run python bench/record_init_bench.py``.
"""

from __future__ import annotations

import timeit
from dataclasses import dataclass
from typing import Any

from bridge.frozen import direct_init


@dataclass(frozen=True, slots=True)
class Generated:
    time: float
    src: str
    size: int
    channels: list[str]
    data: bytes


@direct_init
@dataclass(frozen=True, slots=True)
class Direct:
    time: float
    src: str
    size: int
    channels: list[str]
    data: bytes


@dataclass(slots=True)
class NotFrozen:
    time: float
    src: str
    size: int
    channels: list[str]
    data: bytes


def per_record_ns(cls: Any, number: int = 200_000) -> float:
    """The best of seven runs, ns per record of five fields."""
    return min(timeit.repeat(lambda: cls(1.0, "a", 3, [], b""), number=number, repeat=7)) \
        / number * 1e9


def main() -> None:
    times = {cls.__name__: per_record_ns(cls) for cls in (Generated, Direct, NotFrozen)}
    for name, ns in times.items():
        print(f"{name:10} {ns:6.0f} ns  ({ns / times['Generated']:.2f} of generated)")


if __name__ == "__main__":
    main()
