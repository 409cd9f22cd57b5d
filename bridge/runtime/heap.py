"""Give freed C heap back to the system after a burst of huge buffers (glibc's ``malloc_trim``).

A 100 MB put on an input key is dropped as over its cap, but Zenoh (Rust) has reassembled it
by then in buffers of its own, freed once the sample is gone. glibc keeps freed memory in its
arenas for reuse: a bridge that took puts of 20, 50 and 100 MB went from 70 to 154 MB of RSS
and stayed there; ``malloc_trim(0)`` hands the free pages back (a subscriber of 26 MB came
back from 57 to 27 MB, in 0.1-4 ms; eclipse-zenoh 1.10.2, glibc, Linux). ``MALLOC_ARENA_MAX``
and ``MALLOC_MMAP_THRESHOLD_`` did not.

:class:`HeapTrim` trims when the resident size has grown :data:`GROWTH_BYTES` over the lowest
seen and stopped growing (a message being reassembled is still in use), at most every
:data:`EVERY_S`, also while trims free little: a trim costs 0.1-4 ms, and memory a message
held in use while a trim ran is freed later with no change in the resident size to tell
(backing off to minutes left a bridge at 101 MB after ``bench/flood.py --huge``). One read of
``/proc/self/statm`` a check, no cost on the data path. One per process (:data:`HEAP`: the heap
is the process's, whatever the number of nodes in it). Elsewhere than Linux with glibc it does
nothing.

What a trim cannot give back is memory still in use: a message a publisher started but never
finished (a ``CongestionControl.DROP`` put dropping fragments when its queue is full) stays in
Zenoh's reassembly buffer, up to the part received, until the next message in fragments on
that link.
"""

from __future__ import annotations

import ctypes
import math
import os
import sys
import threading
from collections.abc import Callable
from typing import Any

GROWTH_BYTES = 16 << 20
"""Growth of the resident size over its lowest that makes a trim worth it."""
EVERY_S = 5.0
"""Least time between two trims."""
STEADY_BYTES = 1 << 20
"""Growth since the last check under which the resident size counts as no longer growing."""


def resident_bytes() -> int | None:
    """This process's resident size (Linux), else None."""
    try:
        with open("/proc/self/statm", "rb") as statm:
            return int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return None


def _malloc_trim() -> Callable[[], Any] | None:
    """glibc's ``malloc_trim(0)``, or None (not Linux, or a libc without it, e.g. musl)."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        trim = ctypes.CDLL(None).malloc_trim
    except (OSError, AttributeError):
        return None
    trim.argtypes, trim.restype = [ctypes.c_size_t], ctypes.c_int
    return lambda: trim(0)


MALLOC_TRIM = _malloc_trim()
"""``malloc_trim(0)`` if this process has it, else None."""


class HeapTrim:
    """Trims the C heap when the resident size grew (:meth:`check`, at a low rate)."""

    def __init__(self, rss: Callable[[], int | None] = resident_bytes,
                 trim: Callable[[], Any] | None = MALLOC_TRIM, *,
                 growth: int = GROWTH_BYTES, every_s: float = EVERY_S) -> None:
        self._rss, self._trim = rss, trim
        self.growth, self.every_s = growth, every_s
        self.lowest: int | None = None
        """The lowest resident size seen (bytes)."""
        self.trims = 0
        self.freed = 0
        """Bytes of resident size the trims gave back, in all."""
        self._last = -math.inf  # when the last trim was
        self._previous: int | None = None  # the resident size at the last check
        self._lock = threading.Lock()  # (nodes of one process may check from several loops)

    def check(self, now: float) -> int | None:
        """Trim if the resident size is :attr:`growth` over its lowest, grew no more since the
        last check, and the last trim was long enough ago (``now``: a monotonic clock); the
        bytes it gave back, or None."""
        if self._trim is None:
            return None
        with self._lock:
            rss = self._rss()
            if rss is None:
                return None
            if self.lowest is None or rss < self.lowest:
                self.lowest = rss
            growing = self._previous is not None and rss - self._previous > STEADY_BYTES
            self._previous = rss
            if rss - self.lowest < self.growth or growing:
                return None
            if now - self._last < self.every_s:
                return None
            self._trim()
            after = self._rss()
            after = rss if after is None else after
            freed = max(0, rss - after)
            self.lowest = min(self.lowest, after)
            self.trims += 1
            self.freed += freed
            self._last, self._previous = now, after
            return freed

    def snapshot(self) -> dict[str, Any]:
        """Counters for a node's stats."""
        return {"trims": self.trims, "freed_mb": round(self.freed / (1 << 20), 1),
                "enabled": self._trim is not None}


HEAP = HeapTrim()
"""The process's."""
