"""``zab sim``: the fleet with a live terminal view and a final report."""

from __future__ import annotations

import asyncio
import contextlib
import signal
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import yaml
from rich.console import Console, Group
from rich.live import Live
from rich.table import Table
from rich.text import Text

from bridge.cli.text import said
from bridge.core.events import (
    Event,
    FrameDropped,
    FrameReceived,
    FrameSent,
    ModemDown,
    ModemUp,
    PayloadDrops,
    SendFailed,
)
from bridge.core.loaded import LoadedMission, parse_mission
from bridge.mission.backends import SimOptions
from bridge.report.model import MissionReport, channel_figures, print_report
from bridge.report.recorder import MissionRecorder, truth_from
from bridge.runtime.fleet import Fleet
from bridge.runtime.keys import throwaway_note

REFRESH_S = 0.5
SIMULATED = ("sim", "udp")
"""Backends a fleet in one process runs as they are; any other (a real modem's) is simulated."""


def link_modems(data: dict[str, Any]) -> list[dict[str, Any]]:
    """The modem settings of each link of mission ``data`` (its YAML; made empty where a link
    has none, so a caller may fill them in): the links' own, or the mission's one modem."""
    return ([link.setdefault("modem", {}) for link in data["links"].values()]
            if data.get("links") else [data.setdefault("modem", {})])


def simulate_real_modems(data: dict[str, Any]) -> list[str]:
    """Make every real modem (EvoLogics, Micro-Modem) of mission ``data`` (its YAML, changed in
    place) a simulated one with the same timings: the simulated modem keeps the options a sim
    modem has (its preset and water) and leaves the others. Returns the real backends found,
    sorted."""
    real: set[str] = set()

    def simulate(modem: Any, inherited: str) -> str:
        """Make ``modem`` (a modem section, whose backend is ``inherited`` unless it names
        one) simulated; its own backend, as it was."""
        if not isinstance(modem, dict):
            return inherited
        backend = str(modem.get("backend", inherited))
        if backend not in SIMULATED:
            real.add(backend)
            modem["backend"] = "sim"
            if isinstance(modem.get("options"), dict):
                modem["options"] = {k: v for k, v in modem["options"].items()
                                    if k in SimOptions.model_fields}
        return backend

    links = data.get("links") or {}
    for link in links.values() if isinstance(links, dict) else ():
        shared = simulate(link.setdefault("modem", {}), "sim")
        for member in (link.get("nodes") or {}).values() if isinstance(link.get("nodes"),
                                                                        dict) else ():
            simulate(member.get("modem") if isinstance(member, dict) else None, shared)
    if not links:
        shared = simulate(data.setdefault("modem", {}), "sim")
        for node in (data.get("nodes") or {}).values():
            simulate(node.get("modem") if isinstance(node, dict) else None, shared)
    return sorted(real)


def simulated(loaded: LoadedMission) -> tuple[LoadedMission, str | None]:
    """``loaded`` as ``zab sim`` runs it with no water of its own (``--water``): its real
    modems simulated, and a line saying so (None if it has none)."""
    data = yaml.safe_load(loaded.path.read_text(encoding="utf-8"))
    real = simulate_real_modems(data)
    if not real:
        return loaded, None
    return parse_mission(yaml.safe_dump(data, sort_keys=False), loaded.path), (
        f"the {' and '.join(real)} modems are simulated ones with the same timings (to drive "
        "the real drivers: zab water, zab emulate for each node, then zab sim --water)")


class EventLog:
    """The last few frame events, for the live view (kept as they come, worded when shown)."""

    KINDS = (FrameSent, FrameReceived, FrameDropped, PayloadDrops, SendFailed, ModemDown,
             ModemUp)

    def __init__(self, size: int = 10) -> None:
        self._last: deque[tuple[float, str, Event]] = deque(maxlen=size)
        self.t0 = time.time()

    def __call__(self, node: str, event: Event) -> None:
        if isinstance(event, self.KINDS):
            self._last.append((time.time() - self.t0, node, event))

    @property
    def lines(self) -> list[str]:
        return [f"{t:7.1f} s  {_wording(node, event)}" for t, node, event in self._last]


def _wording(node: str, event: Event) -> str:
    match event:
        case FrameSent(size=size, channels=channels):
            return f"{node} sent {size} B [{', '.join(channels) or 'empty'}]"
        case FrameReceived(src=src, size=size):
            return f"{node} heard {src} ({size} B)"
        case PayloadDrops(drops=drops):
            return f"{node} dropped {event.total} payloads: " + "; ".join(
                f"{count} on {key} ({cause})" for key, cause, count, _ in drops)
        case FrameDropped(reason=why) | SendFailed(error=why) \
                | ModemDown(error=why):
            return f"{node} {event.kind.replace('_', ' ')}: {why}"
        case ModemUp(down_s=down_s):
            return f"{node} modem up after {down_s:.1f} s"
    return f"{node} {event.kind}"


def fleet_view(fleet: Fleet, events: EventLog) -> Group:
    """Nodes' counters, channel ages at receivers, and recent events."""
    nodes = Table("node", "sent", "received", "dropped", "left out", "published",
                  title="nodes", expand=False)
    ages = Table("channel", "bits", "sent", "delivered", "age at receivers", title="channels")
    with contextlib.ExitStack() as held:  # a direct backend's threads change the cores
        for node in fleet.nodes.values():
            held.enter_context(node.lock)
        return _fleet_view(fleet, events, nodes, ages)


def _fleet_view(fleet: Fleet, events: EventLog, nodes: Table, ages: Table) -> Group:
    now = time.time()
    for name, node in fleet.nodes.items():
        s = node.stats
        nodes.add_row(name, str(s.frames_sent), str(s.frames_received),
                      str(sum(s.frames_dropped.values())), str(s.left_out),
                      str(s.values_published))
    cores = {name: node.core for name, node in fleet.nodes.items()}
    for c in channel_figures(fleet.loaded, cores).values():
        heard = [now - n.received_at[c.name] for n in fleet.nodes.values()
                 if c.name in n.received_at]
        age = f"{min(heard):.1f}–{max(heard):.1f} s" if heard else "—"
        ages.add_row(c.name, str(c.bits), str(c.sent), str(c.delivered), age)
    return Group(nodes, ages, Text("\n".join(events.lines), style="dim"))


async def run_fleet_for(
    fleet: Fleet, duration: float | None, *, live: bool, console: Console, events: EventLog,
    stop: asyncio.Event | None = None,
) -> None:
    """Run ``fleet`` for ``duration`` seconds once started, or until SIGINT/SIGTERM (which
    set ``stop``, the caller's to watch if it gives one), with an optional live view."""
    stop = stop or asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.add_signal_handler(sig, stop.set)
    runner = asyncio.create_task(fleet.run(stop))
    timer = None if duration is None else asyncio.create_task(_stop_after(fleet, duration, stop))
    try:
        if live and console.is_terminal:
            with Live(fleet_view(fleet, events), console=console, refresh_per_second=4) as view:
                while not runner.done():
                    await asyncio.wait([runner], timeout=REFRESH_S)
                    view.update(fleet_view(fleet, events))
        await runner
    finally:
        stop.set()
        if timer is not None:
            timer.cancel()
        await asyncio.gather(runner, *([timer] if timer else []), return_exceptions=True)


async def _stop_after(fleet: Fleet, duration: float, stop: asyncio.Event) -> None:
    """Set ``stop`` once the fleet has run ``duration`` seconds (start-up not counted)."""
    await fleet.ready.wait()
    await asyncio.sleep(duration)
    stop.set()


def attach_truth(recorder: MissionRecorder, fleet: Fleet) -> None:
    """Let ``recorder`` ask the fleet's simulated water where each node is (wall time)."""
    if fleet.water is not None:
        water = fleet.water
        names = {n: node.address for n, node in fleet.loaded.mission.nodes.items()}
        recorder.truth = truth_from(names, lambda address, t: water.position(address, t))


async def run_sim(
    loaded: LoadedMission,
    *,
    duration: float | None,
    seed: int | None,
    live: bool,
    console: Console,
    record: Callable[[str, Event], None] | None = None,
    recorder: MissionRecorder | None = None,
    water: str | None = None,
) -> MissionReport:
    """``zab sim``: run, show, and return the report. ``record`` also gets every event;
    ``recorder`` too, and learns where the water has each node (for the HTML report);
    ``water``: join a water already running there (``zab water``) instead of starting one."""
    events = EventLog()

    def both(node: str, event: Event) -> None:
        events(node, event)
        if record is not None:
            record(node, event)
        if recorder is not None:
            recorder(node, event)

    fleet = Fleet(loaded, seed=seed, on_event=both, water=water)
    if recorder is not None:
        attach_truth(recorder, fleet)
    console.print(said("simulating ", (loaded.mission.mission, "bold"), ": " + ", ".join(
        f"{n} on {' '.join(node.zenoh.listen) or '(no endpoint)'}"
        for n, node in loaded.mission.nodes.items())))
    if fleet.throwaway_key:
        console.print(throwaway_note(loaded.mission), highlight=False)
    await run_fleet_for(fleet, duration, live=live, console=console, events=events)
    report = fleet.report()
    print_report(console, report)
    return report
