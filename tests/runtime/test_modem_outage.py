"""A node whose modem comes back says so: one ``modem_down`` when it went, however many
retries, and one ``modem_up`` with how long it was down (a restarted ``zab emulate`` gave
``modem_down`` at every retry and nothing once the modem was ready)."""

from __future__ import annotations

import asyncio

from bridge.core.events import Event, ModemDown, ModemUp
from bridge.errors import BackendError
from bridge.modems.base import ModemBackend
from bridge.modems.setup import backend_factory
from bridge.runtime.zenoh_node import BridgeNode
from tests.conftest import on_free_ports, udp_ports

MISSION = """\
mission: outage
modem: {backend: udp, frame_bytes: 16}
mac: {type: none}
nodes:
  a: {address: 1, modem: {options: {port: PORT_A}}}
  b: {address: 2, modem: {options: {port: PORT_B}}}
channels:
  - {name: n, from: a, to: b, elements: [{in: n, out: a/n, fields: [{field: v, type: int,
      min: 0, max: 9}]}]}
"""

GONE = 3
"""Opens that fail before the modem is back (retried after 0.5, 1 and 2 s)."""


def test_a_modem_back_after_retries_is_one_down_and_one_up() -> None:
    loaded = on_free_ports(udp_ports(MISSION), "outage.yaml")
    make = backend_factory(loaded.mission, "a")
    opens = 0

    def flaky() -> ModemBackend:
        nonlocal opens
        opens += 1
        backend = make()
        if opens <= GONE:
            async def refused() -> None:
                raise BackendError(f"the modem's port is gone (open {opens})")

            backend.open = refused  # type: ignore[method-assign]
        return backend

    events: list[Event] = []

    async def scenario() -> None:
        stop = asyncio.Event()
        bridge = BridgeNode(loaded, "a", flaky, on_event=events.append)
        run = asyncio.create_task(bridge.run(stop))
        for _ in range(200):
            if any(isinstance(e, ModemUp) for e in events):
                break
            await asyncio.sleep(0.05)
        stop.set()
        await asyncio.wait_for(run, 30)

    asyncio.run(asyncio.wait_for(scenario(), 60))
    modem = [e for e in events if isinstance(e, ModemDown | ModemUp)]
    assert [type(e) for e in modem] == [ModemDown, ModemUp], modem
    down, up = modem
    assert isinstance(down, ModemDown) and down.error == "the modem's port is gone (open 1)"
    assert isinstance(up, ModemUp) and up.retries == GONE - 1
    assert 3.0 <= up.down_s < 10.0 and up.down_s == up.time - down.time
