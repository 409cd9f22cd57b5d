"""The REMUS mission on emulated Micro-Modems delivers the same values as over ``sim``."""

from __future__ import annotations

import asyncio
import contextlib
import queue
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import yaml

from bridge.core.loaded import LoadedMission
from bridge.mission.presets import get_preset
from bridge.modems.micromodem.emulator import run_emulator
from bridge.sim.service import WaterService
from tests.conftest import MISSIONS, on_free_ports
from tests.harness import Inbox, outside_session, put, running_fleet

# rate-0 Micro-Modem sped up 40x (real sound speed, so travel times stay realistic)
FAST = get_preset("micromodem-rate0").replace(name="micromodem-fast", bitrate_bps=3200.0,
                                               overhead_s=0.05)
SLOT = {"slot_s": 1.2, "guard_s": 0.1}

STATE = {"lat": 41.52, "lon": -70.67, "depth": 31.0, "heading": 270.0, "speed": 1.5,
         "battery": 87, "goal": 3, "fault": False}
BATHY = {"depth": [30.0, 31.5, 33.0], "altitude": [5.0, 4.2, 3.9],
         "latitude": [41.52, 41.5201, 41.5202], "longitude": [-70.67, -70.6701, -70.6702]}
COMMAND = {"action": "abort_to_end"}


def mission(path: Path, links: dict[str, Path] | None, **modem: Any) -> LoadedMission:
    """``path`` with short slots; with ``links`` each node's device, else ``modem`` options."""
    data = yaml.safe_load(path.read_text())
    data["mac"].update(SLOT)
    data["modem"].update(modem)
    for name, node in data["nodes"].items():
        node.pop("modem", None)
        if links is not None:
            node["modem"] = {"options": {"device": str(links[name])}}
    return on_free_ports(yaml.safe_dump(data, sort_keys=False), path)


@contextlib.contextmanager
def emulated_modems(loaded: LoadedMission, links: dict[str, Path]) -> Iterator[None]:
    """A fast water and one emulator per node, on their own event loop in a thread."""
    loop = asyncio.new_event_loop()
    started = threading.Event()
    stop: list[asyncio.Future[None]] = []

    async def main() -> None:
        water = WaterService(FAST, 3, {n.address: (n.position.x, n.position.y, n.position.depth)
                                       for n in loaded.mission.nodes.values() if n.position})
        port = await water.start()
        ready: list[dict[str, Any]] = []
        tasks = [asyncio.create_task(run_emulator(loaded, name, water=f"127.0.0.1:{port}",
                                                  link=links[name], ready=ready.append,
                                                  dto_s=1.0, rev_period_s=0.7))
                 for name in loaded.mission.nodes]
        try:
            while len(ready) < len(tasks):
                await asyncio.sleep(0.01)
            stop.append(loop.create_future())
            started.set()
            await stop[0]
        finally:
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            await water.stop()

    thread = threading.Thread(target=lambda: loop.run_until_complete(main()), daemon=True)
    thread.start()
    try:
        assert started.wait(10), "emulators did not start"
        yield
    finally:
        if stop:
            loop.call_soon_threadsafe(stop[0].set_result, None)
        thread.join(10)
        loop.close()


def exchange(loaded: LoadedMission) -> dict[str, Any]:
    """Put one value on each channel; return what arrives at the other end."""
    got: dict[str, Any] = {}
    with running_fleet(loaded):
        top, r1, r2 = (outside_session(loaded, n) for n in ("topside", "remus1", "remus2"))
        try:
            inboxes = {key: Inbox() for key in ("remus1/state", "remus2/bathymetry",
                                                "topside/command")}
            for key, inbox in inboxes.items():
                (r1 if key == "topside/command" else top).declare_subscriber(key, inbox)
            time.sleep(0.3)
            puts = {"remus1/state": lambda: put(r1, "state", STATE),
                    "remus2/bathymetry": lambda: put(r2, "bathymetry", BATHY),
                    "topside/command": lambda: put(top, "command", COMMAND)}
            for again in puts.values():
                again()
            for key, inbox in inboxes.items():
                try:
                    got[key] = inbox.get(timeout=4 * SLOT["slot_s"] * 2)[1]
                except queue.Empty:  # (a loaded machine: a subscriber not yet routed when
                    puts[key]()      # the value came; the value is the same, put once more)
                    got[key] = inbox.get(timeout=4 * SLOT["slot_s"] * 2)[1]
        finally:
            for session in (top, r1, r2):
                session.close()
    return got


def test_remus_over_micromodem_emulators_matches_sim(tmp_path: Path) -> None:
    links = {name: tmp_path / f"mm-{name}" for name in ("topside", "remus1", "remus2")}
    emulated = mission(MISSIONS / "remus_micromodem.yaml", links)
    assert emulated.mission.node_modem("remus1").backend == "micromodem"
    with emulated_modems(emulated, links):
        over_modems = exchange(emulated)
    simulated = mission(MISSIONS / "remus_ccl.yaml", None,
                        options={"preset": "evologics-s2c-im", "seed": 3})
    over_sim = exchange(simulated)
    assert over_modems == over_sim
    assert over_modems["topside/command"] == COMMAND
    assert over_modems["remus1/state"]["battery"] == 87
