"""start_eagerly: a coroutine runs on the caller's stack until it really suspends."""

from __future__ import annotations

import asyncio
import functools
from collections.abc import Callable, Coroutine
from typing import Any

import pytest

from bridge.runtime.eager import start_eagerly


def on_a_loop(test: Callable[[], Coroutine[Any, Any, None]]) -> Callable[[], None]:
    """Run the async test on a fresh event loop."""
    @functools.wraps(test)
    def run() -> None:
        asyncio.run(test())
    return run


@on_a_loop
async def test_a_coroutine_that_never_suspends_finishes_before_the_call_returns() -> None:
    ran: list[str] = []

    async def send() -> None:
        ran.append("sent")

    assert start_eagerly(send()) is None
    assert ran == ["sent"]


@on_a_loop
async def test_the_rest_of_a_suspended_coroutine_runs_as_a_task() -> None:
    ran: list[object] = []
    reply = asyncio.get_running_loop().create_future()

    async def exchange() -> int:
        ran.append("asked")
        value = await reply
        ran.append(value)
        await asyncio.sleep(0)  # a bare yield too
        return value * 2

    task = start_eagerly(exchange())
    assert ran == ["asked"] and task is not None
    reply.set_result(21)
    assert await task == 42
    assert ran == ["asked", 21]


@on_a_loop
async def test_cancelling_the_task_cancels_what_the_coroutine_waits_on() -> None:
    reply = asyncio.get_running_loop().create_future()
    cleaned: list[bool] = []

    async def exchange() -> None:
        try:
            await reply
        finally:
            cleaned.append(True)

    task = start_eagerly(exchange())
    assert task is not None
    await asyncio.sleep(0)
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task
    assert reply.cancelled() and cleaned == [True]


@on_a_loop
async def test_an_error_after_the_suspension_is_the_tasks() -> None:
    reply = asyncio.get_running_loop().create_future()

    async def exchange() -> None:
        await reply
        raise ValueError("modem said no")

    task = start_eagerly(exchange())
    assert task is not None
    reply.set_result(None)
    with pytest.raises(ValueError, match="modem said no"):
        await task
