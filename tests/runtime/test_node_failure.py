"""A node that cannot go on stops whole, saying why: a task of the runtime that fails, or a
thread that reports a failure, ends :meth:`BridgeNode.run` with :class:`NodeFailure` (the
process exits non-zero and systemd restarts it), never a node left half alive."""

from __future__ import annotations

import asyncio
import threading

import pytest

from bridge.errors import NodeFailure
from bridge.modems.setup import backend_factory
from bridge.runtime.zenoh_node import BridgeNode
from tests.conftest import on_free_ports, udp_ports

MISSION = """\
mission: fails
modem: {backend: udp, frame_bytes: 16}
mac: {type: none}
nodes:
  a: {address: 1, modem: {options: {port: PORT_A}}}
  b: {address: 2, modem: {options: {port: PORT_B}}}
channels:
  - {name: n, from: a, to: b, elements: [{in: n, out: a/n, fields: [{field: v, type: int,
      min: 0, max: 9}]}]}
"""


def node() -> BridgeNode:
    loaded = on_free_ports(udp_ports(MISSION), "fails.yaml")
    return BridgeNode(loaded, "a", backend_factory(loaded.mission, "a"))


def test_a_task_that_fails_stops_the_node_with_its_reason() -> None:
    bridge = node()

    def broken(now: float) -> None:
        raise RuntimeError("the health check broke")

    bridge.core.tick = broken  # type: ignore[method-assign]
    with pytest.raises(NodeFailure, match=r"the a-health task ended \(RuntimeError: the health "
                       r"check broke\)"):
        asyncio.run(asyncio.wait_for(bridge.run(asyncio.Event()), 30))
    assert bridge.session is not None and bridge.session.is_closed()


def test_a_thread_that_cannot_go_on_stops_the_node() -> None:
    bridge = node()

    async def scenario() -> None:
        run = asyncio.create_task(bridge.run(asyncio.Event()))
        await bridge.started.wait()
        threading.Thread(target=bridge.fail, args=("the reader thread failed: OSError",)).start()
        await asyncio.wait_for(run, 30)

    with pytest.raises(NodeFailure, match="the reader thread failed: OSError"):
        asyncio.run(scenario())
