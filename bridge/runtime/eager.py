"""Start a coroutine on the caller's stack, as Python 3.12's eager tasks do.

``asyncio.create_task`` runs nothing until the event loop's next iteration; a frame built from
a sample that just arrived would wait for that hop. :func:`start_eagerly` runs the coroutine
at once up to its first real suspension (a UDP or simulated send never suspends) and only
then hands what is left to a task.
"""

from __future__ import annotations

import asyncio
from collections.abc import Coroutine
from typing import Any, TypeVar

T = TypeVar("T")

__all__ = ["start_eagerly"]


def start_eagerly(coro: Coroutine[Any, Any, T]) -> asyncio.Task[T] | None:
    """Run ``coro`` now; None if it finished without suspending (its result is dropped, its
    exception raised here), else the task that finishes it."""
    try:
        yielded = coro.send(None)
    except StopIteration:
        return None
    return asyncio.get_running_loop().create_task(_finish(coro, yielded))


async def _finish(coro: Coroutine[Any, Any, T], yielded: Any) -> T:
    """Drive ``coro`` on from a suspension on ``yielded`` (an asyncio future, or None for a
    bare yield), passing a cancellation on to it."""
    while True:
        try:
            if yielded is None:
                await asyncio.sleep(0)
            else:
                yielded._asyncio_future_blocking = False
                await asyncio.wait([yielded])  # settled; ``coro`` reads its outcome itself
        except asyncio.CancelledError as cancel:
            if yielded is not None:
                yielded.cancel()
            try:
                yielded = coro.throw(cancel)
            except StopIteration as stop:
                return stop.value
            continue
        try:
            yielded = coro.send(None)
        except StopIteration as stop:
            return stop.value
