"""``zab demo``: a simulated fleet, end to end, with nothing to set up.

Runs ``zab sim`` on the MORPH mission, plus what a lab would run around it: on every vehicle,
an application that publishes realistic data on the vehicle's own Zenoh endpoint, and an
application that prints what the bridge delivers there. The applications are plain Zenoh
clients (they use only ``zenoh`` and ``msgpack``), exactly as a program in any language would.
"""

from __future__ import annotations

import asyncio
import json
import math
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgpack
import zenoh
from rich.console import Console
from rich.table import Table

from bridge.cli.demo_queries import QueryApps, member_keys
from bridge.cli.sim import EventLog, print_report, run_fleet_for
from bridge.codec import FieldSpec
from bridge.gui.server import GuiServer
from bridge.mission.loader import LoadedMission
from bridge.resources import data_dir
from bridge.runtime.fleet import Fleet
from bridge.runtime.session import close_quietly

PUBLISH_PERIOD_S = 1.0
OPERATOR_HOLD_S = 60.0  # a key an operator commanded (from the GUI) is left alone this long


def default_demo_mission() -> Path:
    """The MORPH example mission (``deploy/missions/morph.yaml``; shipped in the wheel too)."""
    return data_dir("missions") / "morph.yaml"


def _set(target: dict[str, Any], path: str, value: Any) -> None:
    *parents, last = path.split(".")
    for part in parents:
        target = target.setdefault(part, {})
    target[last] = value


def synthetic_value(spec: FieldSpec, t: float, phase: float) -> Any:
    """A plausible, slowly varying value inside a field's declared range."""
    wave = 0.5 + 0.45 * math.sin(0.05 * t + phase)
    if spec.values:
        return spec.values[int(t / 20 + phase) % len(spec.values)]
    if spec.type == "bool":
        return False
    if spec.type in ("string", "bytes"):
        text = f"t={t:.0f}"
        return text if spec.type == "string" else text.encode()
    if spec.codec in ("ccl.latitude", "ccl.longitude"):
        base = 41.81 if spec.codec == "ccl.latitude" else 3.03  # Sant Feliu de Guíxols
        return base + 0.0005 * math.sin(0.02 * t + phase)
    low = spec.min if spec.min is not None else 0.0
    high = spec.max if spec.max is not None else 1.0
    value = low + (high - low) * wave
    return round(value) if spec.type == "int" else value


TRANSIT_MPS = 0.8  # the formation moves north at this speed, weaving a little east-west


def formation_value(name: str, position: tuple[float, float, float], t: float) -> float | None:
    """Navigation of a vehicle that started at ``position``, transiting with the formation."""
    x0, y0, depth = position
    weave = 3.0 * math.sin(t / 15)
    east_speed = 3.0 / 15 * math.cos(t / 15)
    values = {
        "x": x0 + weave,
        "y": y0 + TRANSIT_MPS * t,
        "depth": depth,
        "heading": math.degrees(math.atan2(east_speed, TRANSIT_MPS)) % 360,
        "speed": math.hypot(east_speed, TRANSIT_MPS),
    }
    return values.get(name)


class VehicleApps:
    """Per node: a publisher of its input keys and a printer of what arrives there."""

    def __init__(self, loaded: LoadedMission, show: Callable[[str], None]) -> None:
        self.loaded = loaded
        self.show = show
        self.sessions: dict[str, zenoh.Session] = {}
        self.published = 0
        self.arrived = 0
        self.ranges: dict[tuple[str, str], float] = {}
        self.operator: dict[tuple[str, str], float] = {}  # (node, key) -> last GUI command
        self._stop = threading.Event()
        self._lock = threading.Lock()

    def _open(self, node: str) -> zenoh.Session | None:
        endpoints = self.loaded.mission.nodes[node].zenoh.listen
        if not endpoints:
            return None
        config = zenoh.Config()
        config.insert_json5("mode", '"client"')
        config.insert_json5("connect/endpoints", json.dumps(endpoints))
        config.insert_json5("scouting/multicast/enabled", "false")
        return zenoh.open(config)

    def start(self) -> None:
        for node in self.loaded.mission.nodes:
            session = self._open(node)
            if session is None:
                continue
            self.sessions[node] = session
            session.declare_subscriber("**", lambda s, n=node: self._arrived(n, s))
            prefix = f"@zab/{self.loaded.mission.mission}/{node}"
            session.declare_subscriber(f"{prefix}/range/*", lambda s, n=node: self._ranged(n, s))
            session.declare_subscriber(f"{prefix}/position", lambda s, n=node: self._fixed(n, s))

    def _ranged(self, node: str, sample: zenoh.Sample) -> None:
        """Keep the latest range each node measured to each peer, for the summary."""
        value = msgpack.unpackb(sample.payload.to_bytes())
        with self._lock:
            self.ranges[(node, value["peer"])] = value["range_m"]

    def _fixed(self, node: str, sample: zenoh.Sample) -> None:
        fix = msgpack.unpackb(sample.payload.to_bytes())
        if not fix.get("fix", True):
            return  # a "no fix" report (too few anchors yet): the demo shows fixes only
        self.show(f"[cyan]{node:>4}[/] position from {' + '.join(fix['anchors'])}: "
                  f"x {fix['x']:.1f} m, y {fix['y']:.1f} m, ±{fix['sigma_m']:.2f} m")

    def _arrived(self, node: str, sample: zenoh.Sample) -> None:
        if sample.attachment is None:  # our own publications; show only what the bridge brought
            return
        try:
            value = msgpack.unpackb(sample.payload.to_bytes())
        except ValueError:
            return
        if sample.attachment.to_bytes().startswith(b"ref:"):  # a command sent from the GUI
            with self._lock:
                self.operator[(node, str(sample.key_expr))] = time.time()
            self.show(f"[magenta]{node:>4}[/] ← operator: [bold]{sample.key_expr}[/] "
                      f"{_short(value)}")
            return
        with self._lock:
            self.arrived += 1
        self.show(f"[green]{node:>4}[/] ← [bold]{sample.key_expr}[/] {_short(value)}")

    def publish_once(self, t: float) -> None:
        """Each node publishes one value on every input key it sends."""
        for node, session in self.sessions.items():
            for channel in self.loaded.mission.channels:
                compiled = self.loaded.table.by_name(channel.name)
                if not compiled.sent_by(node):
                    continue
                for e_index, element in enumerate(channel.elements):
                    value: dict[str, Any] = {}
                    position = self.loaded.mission.nodes[node].position
                    for f_index, spec in enumerate(element.fields):
                        if not spec.field:
                            continue
                        moving = None if position is None else formation_value(
                            spec.field, (position.x, position.y, position.depth), t)
                        phase = hash((node, channel.name, e_index, f_index)) % 628 / 100
                        _set(value, spec.field,
                             moving if moving is not None else synthetic_value(spec, t, phase))
                    for key in member_keys(compiled, e_index, node):
                        if time.time() - self.operator.get((node, key), -OPERATOR_HOLD_S) \
                                < OPERATOR_HOLD_S:
                            continue  # the operator's command stands
                        session.put(key, msgpack.packb(value),
                                    encoding=zenoh.Encoding("application/msgpack"))
                        self.published += 1

    async def run(self) -> None:
        t0 = time.time()
        while True:
            self.publish_once(time.time() - t0)
            await asyncio.sleep(PUBLISH_PERIOD_S)

    def close(self) -> None:
        for session in self.sessions.values():
            close_quietly(session)


async def _start_gui(loaded: LoadedMission, port: int, console: Console) -> GuiServer | None:
    """``zab gui`` inside the demo, joined to the surface node; None if it cannot start."""
    try:
        server = GuiServer(loaded)
        url = await server.start("127.0.0.1", port, any_port=True)
    except (ValueError, OSError) as exc:
        console.print(f"[yellow]no GUI: {exc}[/]")
        return None
    console.print(f"[bold]GUI:[/] open {url} in a browser to watch the fleet move and send "
                  f"commands from {server.node}", highlight=False)
    return server


def _short(value: Any) -> str:
    def fmt(v: Any) -> Any:
        if isinstance(v, float):
            return round(v, 3)
        if isinstance(v, dict):
            return {k: fmt(x) for k, x in v.items()}
        return v

    text = json.dumps(fmt(value), separators=(", ", ": "))
    return text if len(text) < 90 else text[:87] + "..."


async def run_demo(
    loaded: LoadedMission, *, duration: float, console: Console, live: bool,
    gui: bool = True, gui_port: int = 8080,
) -> dict[str, Any]:
    """The demo: fleet + apps for ``duration`` seconds, then a summary."""
    console.print(
        f"[bold]zab demo[/]: the {loaded.mission.mission} fleet over a simulated ocean for "
        f"{duration:.0f} s (Ctrl-C ends it sooner). Each vehicle's Zenoh endpoint:"
    )
    for name, node in loaded.mission.nodes.items():
        console.print(f"  {name:>4} ({node.role}) {' '.join(node.zenoh.listen)}")
    events = EventLog()
    fleet = Fleet(loaded, on_event=events)
    apps = VehicleApps(loaded, lambda line: console.print(line, highlight=False))
    runner = asyncio.create_task(
        run_fleet_for(fleet, duration, live=live, console=console, events=events)
    )
    await asyncio.wait([runner, asyncio.create_task(fleet.ready.wait())],
                       return_when=asyncio.FIRST_COMPLETED)
    publisher: asyncio.Task[None] | None = None
    asker: asyncio.Task[None] | None = None
    page: GuiServer | None = None
    try:
        if not runner.done():
            apps.start()
            publisher = asyncio.create_task(apps.run())
            if loaded.table.queries:  # issue 15: gets across the water
                queries = QueryApps(loaded, apps.sessions,
                                    lambda line: console.print(line, highlight=False))
                asker = asyncio.create_task(queries.run())
            if gui:
                page = await _start_gui(loaded, gui_port, console)
        await runner
    finally:
        if page is not None:
            await page.stop()
        for task in (publisher, asker):
            if task is not None:
                task.cancel()
                await asyncio.gather(task, return_exceptions=True)
        apps.close()
    report = fleet.report()
    print_report(console, report)
    if apps.ranges:
        table = Table("node", "peer", "range", title="DLBL ranges, last measured (from the "
                      "frames the fleet sent anyway)")
        for (node, peer), metres in sorted(apps.ranges.items()):
            table.add_row(node, peer, f"{metres:.2f} m")
        console.print(table)
    console.print(
        f"published {apps.published} values on the vehicles, {apps.arrived} delivered values "
        "arrived at other vehicles' endpoints."
    )
    return report
