"""Run every node of a mission in one process, over the simulated ocean (``zab sim``): one
water per link of the mission (each modem kind with its own preset), each node a modem in the
water of each of its links."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import tempfile
import time
from collections.abc import Callable, Collection
from typing import Any

from bridge.core.events import Event, FrameReceived
from bridge.core.loaded import LoadedMission
from bridge.modems.setup import node_backends
from bridge.report.age import AgeOfInformation
from bridge.report.model import MissionReport
from bridge.runtime.keys import keys_for_run
from bridge.runtime.state_file import StateFile
from bridge.runtime.surface_wifi import SurfaceWifi
from bridge.runtime.zenoh_node import BridgeNode
from bridge.sim.scenario import Water, surface_script, water_of, water_stats, waters_of
from bridge.sim.service import WaterService
from bridge.wire.seal import KeyRing

log = logging.getLogger("zab.fleet")

WATCH_S = 0.25  # how often a node that failed while running is noticed


def water_for(loaded: LoadedMission, seed: int | None = None) -> WaterService:
    """A water service for the mission (:func:`~bridge.sim.scenario.water_of`; with several
    links, its first link's: :func:`waters_for`)."""
    return _service(water_of(loaded, seed))


def waters_for(loaded: LoadedMission, seed: int | None = None
               ) -> dict[str | None, WaterService]:
    """A water service per link of the mission, by link name (None: its one link)."""
    if not loaded.network.several:
        return {None: water_for(loaded, seed)}
    return {link: _service(water) for link, water in waters_of(loaded, seed).items()}


def _service(water: Water) -> WaterService:
    return WaterService(water.preset, water.seed, water.positions, loss=water.loss,
                        paths=water.paths)


class Fleet:
    """All bridges of a mission plus, for ``backend: sim``, the water they share."""

    def __init__(
        self,
        loaded: LoadedMission,
        *,
        seed: int | None = None,
        on_event: Callable[[str, Event], None] | None = None,
        only: Collection[str] | None = None,
        water: str | None = None,
        state_dir: str | None = None,
        key: bytes | KeyRing | None = None,
    ) -> None:
        """``only`` runs a subset of the nodes; ``water`` joins a water already running
        (``host:port``) instead of starting one; ``state_dir`` keeps the nodes' saved states
        (default: a temporary folder, removed at the end). ``key``: the frame key of an
        authenticated mission (default: the mission key if present, else this process's
        throwaway key, so fleets in one process still hear each other; see
        :attr:`throwaway_key`)."""
        self.state_dir = state_dir
        self.loaded = loaded
        auth = loaded.mission.wire.auth
        self.key, self.throwaway_key = key, False
        if key is None and auth is not None:
            self.key, self.throwaway_key = keys_for_run(auth)
        self.names = [n for n in loaded.mission.nodes if only is None or n in only]
        self.water_address = water
        sim = water is None and all(link.view.modem.backend == "sim"
                                    for link in loaded.network.links)
        self.waters = waters_for(loaded, seed) if sim else {}
        """The water of each link the fleet simulates (None: the mission's one link)."""
        self.water = next(iter(self.waters.values()), None)
        """The first link's water."""
        self.on_event = on_event
        self.nodes: dict[str, BridgeNode] = {}
        self.ages = AgeOfInformation()
        self.started = time.time()
        self.ended: float | None = None  # when the run was told to stop
        self.ready = asyncio.Event()

    def _node_events(self, name: str) -> Callable[[Event], None]:
        """``name``'s events: arrivals for the age of information, then ``on_event``."""
        callback = self.on_event

        def on_event(event: Event) -> None:
            if isinstance(event, FrameReceived):
                for channel in event.channels:
                    self.ages.arrived(channel, name, event.time)
            if callback is not None:
                callback(name, event)

        return on_event

    async def run(self, stop: asyncio.Event) -> None:
        """Start the water and every node; run until ``stop`` is set; close everything."""
        extras: dict[str | None, dict[str, Any]] = {}
        for link, water in self.waters.items():
            port = await water.start("127.0.0.1", 0)
            extras[link] = {"water": f"127.0.0.1:{port}"}
        if not self.waters and self.water_address is not None:
            extras[None] = {"water": self.water_address}
        node_stop = asyncio.Event()
        scratch = tempfile.TemporaryDirectory(prefix="zab-state-") if self.state_dir is None \
            else None
        state_dir = self.state_dir or scratch.name  # type: ignore[union-attr]
        try:
            for name in self.names:
                self.nodes[name] = BridgeNode(
                    self.loaded,
                    name,
                    node_backends(self.loaded.network, name, extras),
                    on_event=self._node_events(name),
                    state_file=StateFile(state_dir, self.loaded.mission.mission, name),
                    key=self.key,
                )
            tasks = [asyncio.create_task(n.run(node_stop)) for n in self.nodes.values()]
            started = asyncio.ensure_future(
                asyncio.gather(*(n.started.wait() for n in self.nodes.values()))
            )
            waiting: list[asyncio.Future[Any]] = [started, *tasks]
            await asyncio.wait(waiting, return_when=asyncio.FIRST_COMPLETED)
            started.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await started
            if any(task.done() for task in tasks):  # a session could not open: stop them all
                node_stop.set()
                ended = await asyncio.gather(*tasks, return_exceptions=True)
                first = next((e for e in ended if isinstance(e, BaseException)), None)
                raise first or RuntimeError("a bridge node stopped while starting")
            self.started = time.time()
            if self.water is not None and self.water.started_at is not None and (
                    script := surface_script(self.loaded, self.water.started_at)) is not None:
                wifi = SurfaceWifi(self.loaded.mission, script, self._surfaced)
                tasks.append(asyncio.create_task(wifi.run(node_stop), name="surface-wifi"))
            self.ready.set()
            while not stop.is_set():
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(WATCH_S):
                        await stop.wait()
                for task in tasks:
                    if task.done() and task.exception() is not None:
                        raise task.exception()  # type: ignore[misc]
            self.ended = time.time()
            node_stop.set()
            await asyncio.gather(*tasks, return_exceptions=True)
        finally:
            node_stop.set()
            for water in self.waters.values():
                await water.stop()
            if scratch is not None:
                scratch.cleanup()

    def water_stats(self) -> dict[str, Any] | None:
        """The counters of the fleet's water (several links: each link's, their ``links``
        named by ``link``)."""
        if not self.waters:
            return None
        return water_stats({link: water.stats() for link, water in self.waters.items()})

    def _surfaced(self, a: str, b: str, up: bool) -> None:
        """The scripted surfacing joined ``a`` and ``b`` over IP (``up``) or parted them (the
        bridges then see it themselves: :class:`~bridge.core.events.Surfaced`)."""
        log.info("surface WiFi: %s and %s %s", a, b, "joined" if up else "parted")

    def report(self) -> MissionReport:
        """The run's report (:mod:`bridge.report.model`), up to its stop (or now)."""
        end = self.ended if self.ended is not None else time.time()
        return MissionReport.build(
            self.loaded, {name: node.core for name, node in self.nodes.items()}, self.ages,
            self.started, end, self.water_stats())
