"""The surface WiFi of ``zab sim``: the scripted surfacings of the mission (decided by
:func:`bridge.sim.scenario.surface_script`) join the Zenoh of a surfaced vehicle and the
surface's, over loopback, while the vehicle is at the surface.

Each IP pair gets a Zenoh router session (the access point) connecting both nodes' listen
endpoints, gossip off, closed at the dive. As with the deploy kit, the nodes must run Zenoh
routers: Zenoh 1.x does not route between two peers through a router.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import time
from collections.abc import Callable

import zenoh

from bridge.mission.model import Mission
from bridge.sim.scenario import SurfaceScript

log = logging.getLogger(__name__)

Pair = tuple[str, str]


def access_point(endpoints: list[str]) -> zenoh.Session:
    """A router session joining ``endpoints`` (no listening, no gossip, no multicast)."""
    config = zenoh.Config()
    config.insert_json5("mode", '"router"')
    config.insert_json5("listen/endpoints", "[]")
    config.insert_json5("connect/endpoints", json.dumps(endpoints))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("scouting/gossip/enabled", "false")
    config.insert_json5("scouting/delay", "0")
    return zenoh.open(config)


def _close(session: zenoh.Session) -> None:
    with contextlib.suppress(zenoh.ZError):
        session.close()


class SurfaceWifi:
    """Opens and closes the access points as the script says, on wall-clock time."""

    def __init__(self, mission: Mission, script: SurfaceScript,
                 on_change: Callable[[str, str, bool], None] | None = None) -> None:
        self.mission = mission
        self.script = script
        self.on_change = on_change
        self.links: dict[Pair, zenoh.Session] = {}
        for name in {*script.surface_nodes, *script.windows}:
            node = mission.nodes[name]
            if node.zenoh.mode != "router" or not node.zenoh.listen:
                log.warning("%s: scripted surfacing in zab sim joins Zenoh routers over IP; "
                            "this node runs a %s%s, so data may not cross the WiFi (give it "
                            "zenoh: {mode: router, listen: [...]})", name, node.zenoh.mode,
                            "" if node.zenoh.listen else " without a listen endpoint")

    async def _set(self, pairs: set[Pair]) -> None:
        for pair in sorted(set(self.links) - pairs):
            await asyncio.to_thread(_close, self.links.pop(pair))
            self._report(pair, False)
        for pair in sorted(pairs - set(self.links)):
            a, b = (self.mission.nodes[n].zenoh.listen for n in pair)
            try:
                self.links[pair] = await asyncio.to_thread(access_point, [*a, *b])
            except zenoh.ZError as exc:
                log.warning("surface WiFi %s-%s: %s", *pair, exc)
                continue
            self._report(pair, True)

    def _report(self, pair: Pair, up: bool) -> None:
        log.info("%s %s the surface WiFi with %s", pair[1], "joins" if up else "leaves",
                 pair[0])
        if self.on_change is not None:
            self.on_change(*pair, up)

    async def run(self, stop: asyncio.Event) -> None:
        """Follow the script until ``stop``; every access point is closed at the end."""
        try:
            while not stop.is_set():
                now = time.time()
                await self._set(self.script.ip_pairs(now))
                at = self.script.next_any(now)
                with contextlib.suppress(TimeoutError):
                    wait_s = None if at is None else max(0.0, at - time.time()) + 0.01
                    async with asyncio.timeout(wait_s):
                        await stop.wait()
        finally:
            for session in self.links.values():
                _close(session)
            self.links.clear()
