"""``zab demo``: a guided tour of a simulated fleet, with nothing to set up.

Runs ``zab sim`` on the MORPH mission, plus what a lab would run around it: on every vehicle,
an application that publishes plausible data on the vehicle's own Zenoh endpoint (navigation
from the formation's motion, a slowly draining battery), and an application that watches what
the bridge delivers there. The applications are plain Zenoh clients (they use only ``zenoh``
and ``msgpack``), exactly as a program in any language would. :mod:`bridge.cli.tour` holds the
words; this module runs the fleet and says them at the right moments.
"""

from __future__ import annotations

import asyncio
import copy
import functools
import json
import logging
import math
import queue
import random
import re
import threading
import time
import zlib
from collections import Counter, deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgpack
import yaml
import zenoh
from rich.console import Console
from rich.table import Table
from rich.text import Text

from bridge.cli.demo_images import PictureWatch, camera_pair, images_for_tour
from bridge.cli.demo_queries import QUERY_PERIOD_S, QueryApps, member_keys, query_for_tour
from bridge.cli.demo_relay import RelayWatch, relay_plan, shown_values
from bridge.cli.demo_surfacing import (
    SentAtSwitches,
    SurfacingWatch,
    surfaced_vehicle,
    surfacing_for_tour,
    turns_to_wait,
)
from bridge.cli.poke import value_of
from bridge.cli.sim import (
    EventLog,
    attach_truth,
    link_modems,
    run_fleet_for,
    simulate_real_modems,
)
from bridge.cli.text import said
from bridge.cli.tour import Tour, short, turn_waits
from bridge.core.bounds import UNBOUNDED_TURN_S
from bridge.core.events import Event
from bridge.core.loaded import LoadedMission, parse_mission
from bridge.core.mac import frame_time_s
from bridge.core.queries import deadline_s
from bridge.errors import MissionError
from bridge.gui.commands import named_as_command
from bridge.gui.server import GuiServer
from bridge.mission.fields import FieldSpec
from bridge.report import MissionRecorder, write_report
from bridge.report.check import check_mission
from bridge.report.model import MissionReport
from bridge.resources import data_dir
from bridge.runtime.fleet import Fleet
from bridge.runtime.keys import throwaway_note
from bridge.runtime.session import close_quietly
from bridge.wire.channels import ChannelCodec, ElementCodec
from bridge.wire.queries import QuerySpec

PUBLISH_PERIOD_S = 1.0
OPERATOR_HOLD_S = 60.0  # a key an operator commanded (from the GUI) is left alone this long
TOUR_LOSS = 0.1  # share of frames the tour's water loses, so reliability has work to do
TOUR_S = 70.0  # how long the tour lasts unless `zab demo --duration` says otherwise
EXAMPLES = 3  # arrivals shown with their quantisation, of different channels
EXAMPLES_WAIT_S = 20.0
EXAMPLE_TRIES = 4  # arrivals of a channel passed over while they show no rounding
COMMAND_WAIT_S = 25.0  # the tour moves on if a delivery report is still missing by then
GET_MARGIN_S = 2.0  # past its deadline, the bridge's reply error reaches the get by then
END_MARGIN_S = 1.0  # the story's waits end this long before the fleet does
SWITCH_WAIT_S = 10.0  # the tour waits this long past a scripted surfacing or dive for it
FIXES_WAIT_S = 15.0  # the fixes part waits this long for a vehicle's first fix
TOUR_REF = "tour-1"  # correlation of the tour's command (the put's attachment ``ref:...``)
POLL_S = 0.2
PICTURE_LINES = 8  # refinements of the tour's picture shown at most


def default_demo_mission() -> Path:
    """The MORPH example mission (``deploy/missions/morph.yaml``; shipped in the wheel too)."""
    return data_dir("missions") / "morph.yaml"


def tour_mission(path: Path, loss: float = TOUR_LOSS, duration: float = TOUR_S
                 ) -> tuple[LoadedMission, list[str]]:
    """The mission at ``path`` as the tour of ``duration`` seconds runs it, and the changes
    made, in words: real modems (EvoLogics, Micro-Modem) become simulated ones, the water
    loses ``loss`` of the frames, a mission without queries gets one (the surface node asks
    the vehicles' health), one without surfacing gets a vehicle surfacing on a scripted path,
    one without image channels a camera, and the first channel named as a command becomes
    acknowledged (reliable, so not latching)."""
    data = yaml.safe_load(path.read_text(encoding="utf-8"))
    changes = []
    real = simulate_real_modems(data)
    if real:
        changes.append(f"the {' and '.join(real)} modems are simulated ones with the same "
                       "timings, in the simulated water")
    if loss > 0:
        for modem in link_modems(data):
            modem.setdefault("options", {})["loss"] = loss  # (each link's water)
        changes.append(f"the water loses {loss:.0%} of frames")
    loaded = parse_mission(yaml.safe_dump(data, sort_keys=False), path)
    known = set(check_mission(loaded).errors)
    for extra in (query_for_tour, functools.partial(surfacing_for_tour, mission=loaded.mission,
                                                    duration=duration), images_for_tour):
        trial = copy.deepcopy(data)
        said = extra(trial)
        if said is None:
            continue
        try:  # this mission may not take it: goby's wire format has no image channels, a
            # query's repeatable entries lengthen hippocampus's count field past its sensors
            tried = parse_mission(yaml.safe_dump(trial, sort_keys=False), path)
        except MissionError:
            continue
        if set(check_mission(tried).errors) - known:
            continue
        data, loaded = trial, tried
        changes.append(said)
    for channel in data.get("channels") or []:
        keys = [str(e.get("in", "")) for e in channel.get("elements") or []]
        if named_as_command(str(channel.get("name", "")), *keys):
            if not channel.get("reliable"):
                channel.update(reliable=True, latching=False)
                try:
                    loaded = parse_mission(yaml.safe_dump(data, sort_keys=False), path)
                except MissionError:
                    break  # this channel cannot be acknowledged as it is: leave it be
                return loaded, [*changes, f"{channel['name']} is acknowledged (reliable: true)"]
            break
    return loaded, changes


def _set(target: dict[str, Any], path: str, value: Any) -> None:
    *parents, last = path.split(".")
    for part in parents:
        target = target.setdefault(part, {})
    target[last] = value


def _phase(*parts: object) -> float:
    """A fixed phase in [0, 2π) per field, the same in every run."""
    return zlib.crc32(repr(parts).encode()) % 628 / 100


PREFERRED_MODES = ("transit", "survey", "hold")


def synthetic_value(spec: FieldSpec, t: float, phase: float) -> Any:
    """A plausible value inside a field's declared range that changes slowly: a battery
    drains by about 1 % a minute, a mode stays put, other numbers drift over ten minutes;
    an array field (``count``) gets a list of such values, each of its own phase."""
    if spec.count:
        one = spec.model_copy(update={"count": None})
        return [synthetic_value(one, t, phase + i) for i in range(spec.count)]
    if spec.values:
        return next((m for m in PREFERRED_MODES if m in spec.values), spec.values[0])
    if spec.type == "bool":
        return False
    if spec.type in ("string", "bytes"):
        text = f"t={t:.0f}"
        return text if spec.type == "string" else text.encode()
    if spec.codec in ("ccl.latitude", "ccl.longitude"):
        base = 41.81 if spec.codec == "ccl.latitude" else 3.03  # Sant Feliu de Guíxols
        return round(base + 0.0005 * math.sin(0.02 * t + phase), 6)
    low = spec.min if spec.min is not None else 0.0
    high = spec.max if spec.max is not None else 1.0
    if "battery" in spec.field:
        value = high - (high - low) * (0.05 + 0.1 * phase / 6.28 + t / 6000)
    else:
        value = low + (high - low) * (0.5 + 0.3 * math.sin(2 * math.pi * t / 600 + phase))
    value = min(high, max(low, value))
    return round(value) if spec.type == "int" else round(value, 4)


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
    value = values.get(name)
    return None if value is None else round(value, 3)


def _numbers(value: Any, prefix: str = "") -> dict[str, float]:
    out: dict[str, float] = {}
    if isinstance(value, dict):
        for k, v in value.items():
            out.update(_numbers(v, f"{prefix}{k}."))
    elif isinstance(value, int | float) and not isinstance(value, bool):
        out[prefix.rstrip(".")] = float(value)
    return out


def closest(history: list[tuple[float, Any]], got: Any) -> Any:
    """The published value the delivered ``got`` most likely came from: the one nearest to it
    in every numeric field (values change slowly, so any near one tells the same story)."""
    numbers = _numbers(got)

    def distance(item: tuple[float, Any]) -> float:
        sent = _numbers(item[1])
        return sum(abs(sent[k] - v) for k, v in numbers.items() if k in sent) + (
            0.0 if sent.keys() & numbers.keys() else math.inf)  # (a ROS 2 message has more)

    return min(history, key=distance)[1] if history else None


class VehicleApps:
    """Per node: a publisher of its input keys and a watcher of what arrives there."""

    def __init__(self, loaded: LoadedMission, show: Callable[[str | Text], None],
                 tour: Tour | None = None,
                 truth: Callable[[str, float], tuple[float, float, float] | None] | None = None
                 ) -> None:
        """``truth(node, time)``: where the simulator has ``node`` at wall ``time`` (to print
        each published position's error beside it)."""
        self.loaded = loaded
        self.show = show
        self.tour = tour
        self.truth = truth
        self.errors: dict[str, list[float]] = {}
        self.fix_state: dict[str, str] = {}
        self.sessions: dict[str, zenoh.Session] = {}
        self.published: Counter[str] = Counter()  # per channel
        self.arrived = 0
        self.operator: dict[tuple[str, str], float] = {}  # (node, key) -> last GUI command
        self.history: dict[tuple[str, str], deque[tuple[float, Any]]] = {}
        self.routes = self._routes()
        self.families = [(zenoh.KeyExpr(element.output_key(src, dst)), channel.name)
                         for channel in loaded.table.channels if channel.family is not None
                         for src in channel.senders for dst in channel.destinations(src)
                         for element in channel.elements]
        self.members: dict[str, set[str]] = {}  # per key family: member keys arrived
        self.examples: list[str] = []  # channels shown with their quantisation
        self.passed: Counter[str] = Counter()  # arrivals per channel considered for it
        self.examples_done = threading.Event()  # part 1 over (or its wait)
        self.fixes_seen: dict[str, tuple[dict[str, Any], tuple[float, float] | None]] = {}
        self.deliveries: queue.Queue[dict[str, Any]] = queue.Queue()
        self.latest: dict[tuple[str, str], Any] = {}  # (node, field name) -> last published
        self._lock = threading.Lock()

    def _routes(self) -> dict[tuple[str, str], tuple[str, ChannelCodec, int]]:
        """(receiver, output key) -> (sender, channel, element index)."""
        routes = {}
        for channel in self.loaded.table.channels:
            for src in channel.senders:
                for dst in channel.destinations(src):
                    for index, element in enumerate(channel.elements):
                        routes[(dst, element.output_key(src, dst))] = (src, channel, index)
        return routes

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
        mission = self.loaded.mission.mission
        for node in self.loaded.mission.nodes:
            session = self._open(node)
            if session is None:
                continue
            self.sessions[node] = session
            session.declare_subscriber("**", functools.partial(self._arrived, node))
            prefix = f"@zab/{mission}/{node}"
            session.declare_subscriber(f"{prefix}/position",
                                       functools.partial(self._fix_arrived, node))
            session.declare_subscriber(f"{prefix}/delivery/*", self._delivered)

    # -- what arrives ------------------------------------------------------------------------

    def _delivered(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.deliveries.put(msgpack.unpackb(sample.payload.to_bytes()))

    def _fix_arrived(self, node: str, sample: zenoh.Sample) -> None:
        """Every published position's error is kept (:attr:`errors`), the latest of each
        vehicle for the tour's part (:meth:`show_fixes`)."""
        try:
            fix = msgpack.unpackb(sample.payload.to_bytes())
        except ValueError:
            return
        if not isinstance(fix, dict):
            return
        where = self._truth(node, fix)
        with self._lock:
            self.fixes_seen[node] = (fix, where)

    async def show_fixes(self, vehicles: list[str], until: float) -> None:
        """Print the latest fix of each of ``vehicles``, waiting for those without one until
        wall time ``until``; later fixes are kept (:attr:`errors`), not printed, so the next
        parts read undisturbed."""
        shown: set[str] = set()
        while True:
            with self._lock:
                latest = {n: f for n, f in self.fixes_seen.items() if n not in shown}
            for node, (fix, where) in sorted(latest.items()):
                self._fixed(node, fix, where)
                shown.add(node)
            if set(vehicles) <= shown or time.time() >= until:
                break
            await asyncio.sleep(POLL_S)
        for node in sorted(set(vehicles) - shown):
            self.show(said((f"{node:>4}", "cyan"), " position: none yet"))

    def _fixed(self, node: str, fix: dict[str, Any], where: tuple[float, float] | None) -> bool:
        """Print a published position (a lost one only when its state changed)."""
        state = str(fix.get("state", "tracking" if fix.get("fix", True) else "lost"))
        told = f"{state} {fix.get('reason', '')}"
        with self._lock:
            changed, self.fix_state[node] = self.fix_state.get(node) != told, told
        if not fix.get("fix", True):
            if changed:  # say it once, not at every range
                reason = str(fix.get("reason", "")).replace("_", " ")
                self.show(said((f"{node:>4}", "cyan"), " position: ", (state, "yellow"),
                               f" ({reason})"))
            return changed
        self.show(said((f"{node:>4}", "cyan"), " ") + describe_fix(fix, where))
        return True

    def _truth(self, node: str, fix: dict[str, Any]) -> tuple[float, float] | None:
        """Where the simulator had ``node`` at the time of a published position; the error of
        every position (not only the printed ones) is kept in :attr:`errors`."""
        if self.truth is None or not fix.get("fix", True):
            return None
        try:
            where = self.truth(node, float(fix["time"]))
            error = math.dist((float(fix["x"]), float(fix["y"])), where[:2]) \
                if where is not None else None
        except (KeyError, TypeError, ValueError):
            return None
        if where is None or error is None:
            return None
        with self._lock:
            self.errors.setdefault(node, []).append(error)
        return where[0], where[1]

    def _arrived(self, node: str, sample: zenoh.Sample) -> None:
        if sample.attachment is None:  # our own publications; show only what the bridge brought
            return
        if str(sample.encoding).startswith("image/"):
            return  # a picture: the tour's pictures part tells it
        value = value_of(str(sample.key_expr), sample.payload.to_bytes(), str(sample.encoding))
        attachment = sample.attachment.to_bytes()
        if attachment.startswith(b"ref:"):  # a command put on this node's key
            if attachment == f"ref:{TOUR_REF}".encode():
                return  # the tour's own, told in its part
            with self._lock:  # its value is what reaches the receivers now
                self.operator[(node, str(sample.key_expr))] = time.time()
                self.history.setdefault((node, str(sample.key_expr)), deque(maxlen=8)).append(
                    (time.time(), value))
            self.show(said((f"{node:>4}", "magenta"), " ← operator: ",
                           (str(sample.key_expr), "bold"), f" {short(value)}"))
            return
        with self._lock:
            self.arrived += 1
        route = self.routes.get((node, str(sample.key_expr)))
        if route is not None and self.tour is not None:
            self._example(node, route, value)
        elif route is None:
            family = next((name for pattern, name in self.families
                           if pattern.intersects(sample.key_expr)), None)
            if family is not None:
                with self._lock:
                    self.members.setdefault(family, set()).add(str(sample.key_expr))

    def members_arrived(self) -> dict[str, list[str]]:
        """Per key family, the member keys that arrived so far."""
        with self._lock:
            return {name: sorted(keys) for name, keys in self.members.items()}

    def _example(self, dst: str, route: tuple[str, ChannelCodec, int], got: Any) -> None:
        """The first arrivals of a few channels, beside what was published."""
        src, channel, element = route
        with self._lock:
            if self.examples_done.is_set() or len(self.examples) >= EXAMPLES \
                    or channel.name in self.examples:
                return  # (part 1 over: a later part's words are not interrupted)
            history = list(self.history.get((src, channel.elements[element].input_key(src)),
                                            ()))
            if not history:
                return
            sent = closest(history, got)
            self.passed[channel.name] += 1
            if _numbers(sent) == _numbers(got) and self.passed[channel.name] <= EXAMPLE_TRIES:
                return  # nothing rounded this time: a later arrival shows quantisation better
            self.examples.append(channel.name)
        assert self.tour is not None
        self.tour.quantised(src, dst, channel, element, sent, got)
        if len(self.examples) >= EXAMPLES:
            self.examples_done.set()

    # -- what the vehicles publish -----------------------------------------------------------

    def is_operators(self, channel: ChannelCodec) -> bool:
        """Commands and acknowledged channels are the operator's to send, not the apps'."""
        return channel.reliable or named_as_command(
            channel.name, *(e.in_key for e in channel.elements))

    def publish_once(self, t: float) -> None:
        """Each node publishes one value on every input key it sends."""
        for node, session in self.sessions.items():
            position = self.loaded.mission.nodes[node].position
            for channel in self.loaded.mission.channels:
                compiled = self.loaded.table.by_name(channel.name)
                if not compiled.sent_by(node) or self.is_operators(compiled):
                    continue
                for e_index, element in enumerate(channel.elements):
                    sailed = self._sailed(node)
                    if sailed is None and self.loaded.mission.nodes[node].path is not None:
                        continue  # not in the water yet: nothing to navigate by
                    keys = member_keys(compiled, e_index, node)
                    for key in keys:
                        if time.time() - self.operator.get((node, key), -OPERATOR_HOLD_S) \
                                < OPERATOR_HOLD_S:
                            continue  # the operator's command stands
                        value: dict[str, Any] = {}
                        if element.dccl:  # a DCCL message: a valid value of its own
                            layout = compiled.elements[e_index].layout
                            value = layout.synthetic_value(  # type: ignore[attr-defined]
                                random.Random(hash((node, key, t))))
                        # (a layout file's fields as the compiled layout expands them)
                        specs = element.fields if element.dccl else [
                            codec.spec for codec in compiled.elements[e_index].layout.fields]
                        for f_index, spec in enumerate(specs):
                            if not spec.field:
                                continue
                            moving = None if spec.count else sailed.get(spec.field) \
                                if sailed is not None else \
                                None if position is None else formation_value(
                                    spec.field, (position.x, position.y, position.depth), t)
                            # (a key family's members: each its own phase, so its own value)
                            phase = _phase(node, channel.name, e_index, f_index,
                                           *([key] if len(keys) > 1 else []))
                            chosen = moving if moving is not None else \
                                synthetic_value(spec, t, phase)
                            _set(value, spec.field, chosen)
                            self.latest[(node, spec.field.rsplit(".", 1)[-1])] = chosen
                        _put(session, compiled.elements[e_index], node, key, value)
                        with self._lock:
                            self.published[channel.name] += 1
                            self.history.setdefault((node, key), deque(maxlen=8)).append(
                                (time.time(), value))

    def _sailed(self, node: str) -> dict[str, float] | None:
        """The navigation of a node moved by a scripted path: where the simulator has it, its
        heading and speed over the last second (None: not on a path, or not in the water)."""
        if self.loaded.mission.nodes[node].path is None or self.truth is None:
            return None
        now = time.time()
        try:
            here, before = self.truth(node, now), self.truth(node, now - 1.0)
        except KeyError:  # its modem is not in the water yet
            return None
        if here is None or before is None:
            return None
        east, north = here[0] - before[0], here[1] - before[1]
        return {"x": round(here[0], 3), "y": round(here[1], 3), "depth": round(here[2], 3),
                "heading": round(math.degrees(math.atan2(east, north)) % 360, 3),
                "speed": round(math.hypot(east, north), 3)}

    def own(self, node: str, name: str) -> Any:
        """``node``'s own datum called ``name`` (or ``name`` less a unit suffix: depth_m is
        its depth): the last value its programs published, else, for a depth, where the
        simulator has it; None if it has none."""
        for candidate in (name, name.rsplit("_", 1)[0]):
            found = self.latest.get((node, candidate))
            if found is not None:
                return found
        if "depth" in name and self.truth is not None:
            try:
                where = self.truth(node, time.time())
            except KeyError:
                return None
            return None if where is None else round(where[2], 1)
        return None

    async def run(self) -> None:
        t0 = time.time()
        while True:
            self.publish_once(time.time() - t0)
            await asyncio.sleep(PUBLISH_PERIOD_S)

    # -- the operator's acknowledged command -------------------------------------------------

    def command_channel(self) -> tuple[str, ChannelCodec] | None:
        """(sender, channel): an acknowledged channel the surface node sends (not a
        camera's control: the pictures part shows those)."""
        surfaces = [n for n, node in self.loaded.mission.nodes.items() if node.role == "surface"]
        for channel in self.loaded.table.channels:
            for node in surfaces:
                if channel.reliable and channel.image is None and channel.sent_by(node) \
                        and self.loaded.mission.nodes[node].zenoh.listen:
                    return node, channel
        return None

    async def send_command(self, loss: float) -> None:
        """Put one command on the surface node and report its delivery to each receiver."""
        assert self.tour is not None
        found = self.command_channel()
        if found is None:
            self.tour.no_command()
            return
        node, channel = found
        destinations = channel.destinations(node)
        report_key = f"@zab/{self.loaded.mission.mission}/{node}/delivery/{channel.name}"
        values = [_command_value(element.layout.fields) for element in channel.elements]
        self.tour.command_sent(node, channel.elements[0].put_key(node),
                               json.dumps(values[0]), destinations, loss, report_key)
        t0 = time.time()
        with self._lock:
            self.published[channel.name] += 1
        for element, value in zip(channel.elements, values, strict=True):
            _put(self.sessions[node], element, node, element.input_key(node), value,
                 attachment=f"ref:{TOUR_REF}".encode())
        states: dict[str, str] = {}
        while len(states) < len(destinations) and time.time() - t0 < COMMAND_WAIT_S:
            await asyncio.sleep(POLL_S)
            while not self.deliveries.empty():
                report = self.deliveries.get_nowait()
                if report.get("ref") != TOUR_REF or report.get("state") not in (
                        "delivered", "failed"):
                    continue
                states[str(report.get("dst"))] = str(report["state"])
                self.tour.delivery(report, time.time() - t0)
        self.tour.command_done(states, [d for d in destinations if d not in states])

    def close(self) -> None:
        for session in self.sessions.values():
            close_quietly(session)


def _put(session: zenoh.Session, element: ElementCodec, node: str, key: str, value: Any,
         attachment: bytes | None = None) -> None:
    """A program's put of ``value`` on input ``key`` (a family member's) of ``element`` at
    ``node``, as :meth:`~bridge.wire.channels.ElementCodec.sample` makes it."""
    key, payload, encoding = element.sample(node, value, time.time(), key)
    session.put(key, payload, encoding=zenoh.Encoding(encoding) if encoding else None,
                attachment=attachment)


def _command_value(fields: Any) -> dict[str, Any]:
    """A sensible command for the tour: hold (or the second action), leg 7, mid-range."""
    value: dict[str, Any] = {}
    for field in fields:
        spec = field.spec
        if spec.values:
            chosen = "hold" if "hold" in spec.values else spec.values[min(1, len(spec.values) - 1)]
        elif spec.type == "bool":
            chosen = True
        elif spec.type == "int" and spec.min is not None and spec.max is not None:
            chosen = int(min(spec.max, max(spec.min, 7)))
        elif spec.min is not None and spec.max is not None:
            chosen = round((spec.min + spec.max) / 2, 3)
        else:
            continue
        if field.path:
            _set(value, field.path, chosen)
    return value


async def _start_gui(loaded: LoadedMission, port: int, console: Console) -> GuiServer | None:
    """``zab gui`` inside the demo, joined to the surface node; None if it cannot start."""
    try:
        server = GuiServer(loaded)
        await server.start("127.0.0.1", port, any_port=True)
    except (ValueError, OSError) as exc:
        console.print(said((f"no GUI: {exc}", "yellow")), markup=False, emoji=False)
        return None
    return server


def describe_fix(fix: dict[str, Any], truth: tuple[float, float] | None = None) -> Text:
    """One published position for a newcomer: state, anchors, where, how sure, and (from the
    simulator) the truth and the error, in sensible units."""
    anchors = " + ".join(fix.get("anchors", [])) or "no anchors"
    state = str(fix.get("state", "fix"))
    if state == "coasting":
        state = f"coasting {float(fix.get('age_s', 0.0)):.0f} s"
    text = said(f"position ({state}, {anchors}): x {fix['x']:.1f} m, y {fix['y']:.1f} m, "
                f"±{fix['sigma_m']:.2f} m")
    if truth is not None:
        error = math.dist((fix["x"], fix["y"]), truth)
        text.append(f" · truth x {truth[0]:.1f}, y {truth[1]:.1f} · ")
        text.append(f"error {error:.2f} m", style="bold")
    return text


def _query_pair(loaded: LoadedMission) -> tuple[QuerySpec, str, str] | None:
    """(query, asker, server) of the tour's get: two nodes with Zenoh endpoints."""
    running = {n for n, node in loaded.mission.nodes.items() if node.zenoh.listen}
    return next(((spec, asker, server) for spec in loaded.table.queries for asker in spec.askers
                 for server in spec.servers if server != asker
                 and {asker, server} <= running), None)


async def _query_part(tour: Tour, loaded: LoadedMission, fleet: Fleet,
                      queries: QueryApps | None, tasks: list[asyncio.Task[None]],
                      end: float) -> None:
    """A plain get at the surface answered on a submerged vehicle, alone; then an operator
    asks now and then, quietly (the summary says what came of it)."""
    found = _query_pair(loaded)
    if queries is None or found is None or not tour.part("queries"):
        return
    spec, asker, server = found
    selector = queries.selector(spec, server)
    deadline = deadline_s(loaded.mission, spec, asker, server)
    tour.query_intro(asker, selector, server, deadline,
                     "the query's timeout_s" if spec.timeout_s else "the MAC's bound")
    core = fleet.nodes[asker].core.queries
    repeated = core.repeated if core is not None else 0
    # the bridge ends the query itself at its deadline (a reply error); the get waits for
    # that, but not past the tour's end
    values, errors, took = await queries.ask(
        asker, selector, max(1.0, min(deadline + GET_MARGIN_S, end - time.time())))
    tour.query_answered(asker, selector, values, errors, took,
                        None if core is None else 1 + core.repeated - repeated)
    tasks.append(asyncio.create_task(queries.run(until=end + END_MARGIN_S)))


async def _surfacing_part(tour: Tour, loaded: LoadedMission, fleet: Fleet,
                          watch: SurfacingWatch | None, sent: SentAtSwitches | None,
                          end: float) -> None:
    """The scripted surfacing as the running system saw it: the token over IP, what crossed
    over IP and acoustically meanwhile (the vehicle's own counters at its switches), and the
    first acoustic value after the dive. Everything is recorded as it happens, so the part
    tells it right even when it starts late; no wait outlasts the tour (``end``)."""
    plan = surfaced_vehicle(loaded)
    if not tour.part("surfacing"):
        return  # (the plan left it out: no vehicle of this mission surfaces)
    if watch is None or sent is None or plan is None or fleet.water is None:
        tour.say("No vehicle of this mission surfaces: nothing to show.")
        return
    surface, vehicle, up_s, down_s = plan
    tour.surfacing_intro(vehicle, surface, up_s, down_s)
    origin = fleet.water.started_at or fleet.started
    up = await _switch(watch, True, min(end, origin + up_s + SWITCH_WAIT_S))
    if up is None:
        tour.not_seen(f"{vehicle} joining over IP")
        return
    tour.switched(vehicle, surface, True, up - origin)
    down = await _switch(watch, False, min(end, origin + down_s + SWITCH_WAIT_S), after=up)
    if down is None:
        tour.not_seen(f"{vehicle}'s dive")
        return
    over_ip = watch.between(up, math.inf, "ip")
    if over_ip:
        tour.over_ip(over_ip[-1][1], short(over_ip[-1][2]), len(over_ip))
    else:
        tour.not_seen(f"a value of {vehicle} over IP")
    while (counts := sent.while_up()) is None and time.time() < min(end, down + SWITCH_WAIT_S):
        await asyncio.sleep(POLL_S)  # the vehicle's bridge sees the dive about when ssv does
    channels = [c for c in loaded.table.channels if c.sent_by(vehicle)]
    if counts is None:
        tour.not_seen(f"{vehicle}'s bridge noticing the dive")
    else:
        dropped = fleet.nodes[surface].core.surfacing
        tour.acoustic_while_up(
            vehicle, {c.name: counts.get(c.name, 0) for c in channels
                      if surface in c.destinations(vehicle)},
            {c.name: tuple(d for d in c.destinations(vehicle) if d != surface or c.stream)
             for c in channels},  # (a stream, a picture's say, goes on over the water)
            len(watch.between(sent.surface_saw_up(up - SWITCH_WAIT_S) or up, down,
                              "acoustic")),
            dropped.duplicates if dropped is not None else 0, surface)
    tour.switched(vehicle, surface, False, down - origin)
    loss = float(loaded.mission.modem.options.get("loss", 0.0) or 0.0)
    turns = turns_to_wait(loss)
    turn = turn_waits(loaded).get(vehicle) or UNBOUNDED_TURN_S
    frame = frame_time_s(loaded.mission, vehicle) or 0.0
    wait = down + turns * turn + frame  # its next turns, a frame each
    while not watch.between(down, math.inf, "acoustic") and time.time() < min(wait, end):
        await asyncio.sleep(POLL_S)
    again = watch.between(down, math.inf, "acoustic")
    if again:
        tour.acoustic_again(again[0][1], short(again[0][2]), again[0][0] - down)
    else:
        tour.not_seen(f"{vehicle}'s next acoustic value ({turns} of its turns, "
                      f"{min(wait, end) - down:.0f} s after the dive)")


async def _switch(watch: SurfacingWatch, up: bool, until: float,
                  after: float = 0.0) -> float | None:
    """When the watched token came (``up``) or went, waiting until wall time ``until``."""
    while (at := watch.switch(up, after)) is None and time.time() < until:
        watch.changed.clear()
        await asyncio.to_thread(watch.changed.wait, POLL_S * 5)
    return at


def tour_parts(loaded: LoadedMission, apps: VehicleApps) -> list[str]:
    """The parts of the tour this mission has something to show for."""
    parts = ["values", "latest"]
    if apps.command_channel() is not None:
        parts.append("command")
    if loaded.mission.wire.dlbl and loaded.mission.ranging.anchors:
        parts.append("fixes")
    if loaded.table.queries and _query_pair(loaded) is not None:
        parts.append("queries")
    if surfaced_vehicle(loaded) is not None:
        parts.append("surfacing")
    if camera_pair(loaded) is not None:
        parts.append("pictures")
    if relay_plan(loaded) is not None:
        parts.append("relay")
    return parts


async def _picture_part(tour: Tour, loaded: LoadedMission, pictures: PictureWatch | None,
                        end: float) -> None:
    """The picture put as the tour began, refinement by refinement (until the last one or
    the tour's end)."""
    found = camera_pair(loaded)
    if pictures is None or found is None or not tour.part("pictures"):
        return
    camera, key, receiver, _, _ = found
    tour.picture_intro(camera, key, receiver)
    while not any(r.final for r in pictures.seen()) and time.time() < end:
        pictures.changed.clear()
        await asyncio.to_thread(pictures.changed.wait, POLL_S * 5)
    seen = pictures.seen()
    if not seen:
        tour.not_seen("a refinement of the picture")
        return
    step = max(1, -(-len(seen) // PICTURE_LINES))  # (a long list thinned, the last kept)
    for index, r in enumerate(seen):
        if index % step == 0 or index == len(seen) - 1:
            tour.picture_refined(r.after_s, r.bytes, r.budget, r.psnr_estimate, r.final,
                                 r.width, r.height)
    if not seen[-1].final:
        tour.not_seen("the picture's last fragment")


def latest_channel(loaded: LoadedMission, apps: VehicleApps) -> ChannelCodec:
    """The channel part 2 tells of: one the vehicles' programs publish every
    ``PUBLISH_PERIOD_S`` (not a command, not a camera's picture, put once), the most often
    sent (first of those on news: interval 0)."""
    published = [c for c in loaded.table.channels if c.image is None
                 and not apps.is_operators(c)] or list(loaded.table.channels)
    return min(published, key=lambda c: c.interval_s)


async def cut_short(stop: asyncio.Event, story: asyncio.Task[None], tour: Tour,
                    end: float) -> None:
    """Ctrl-C (or SIGTERM) before the tour's end stops the story where it is, and says so:
    the stopping fleet is not told as news (a surfaced vehicle's token going with its bridge
    read as its dive)."""
    await stop.wait()
    if not story.done() and time.time() < end:
        story.cancel()
        tour.say(said(("Stopped early: the rest of the tour is skipped.", "dim")))


async def _story(apps: VehicleApps, tour: Tour, loaded: LoadedMission, loss: float,
                 fleet: Fleet, queries: QueryApps | None, watch: SurfacingWatch | None,
                 sent: SentAtSwitches | None, relays: RelayWatch | None,
                 tasks: list[asyncio.Task[None]], end: float,
                 pictures: PictureWatch | None = None) -> None:
    """The parts of the tour before the summary, each when the fleet has something to show
    for it (those the plan left out say nothing)."""
    found = camera_pair(loaded)
    if pictures is not None and found is not None:
        pictures.put()  # (it crosses while the other parts are told)
        apps.published[found[4]] += 1
    tour.part("values")
    tour.values_intro()
    await asyncio.to_thread(apps.examples_done.wait, EXAMPLES_WAIT_S)
    apps.examples_done.set()  # part 1 ends: arrivals after it are not shown as examples
    tour.families(apps.members_arrived())
    tour.part("latest")
    channel = latest_channel(loaded, apps)
    sender = channel.senders[0]
    tour.latest(channel, PUBLISH_PERIOD_S, sender, turn_waits(loaded).get(sender))
    if tour.part("command"):
        await apps.send_command(loss)
    if tour.part("fixes"):
        anchors = list(loaded.mission.ranging.anchors or ())
        tour.fixes_intro(anchors)
        await apps.show_fixes([n for n in loaded.mission.nodes if n not in anchors],
                              min(end, time.time() + FIXES_WAIT_S))
    await _query_part(tour, loaded, fleet, queries, tasks, end)
    await _surfacing_part(tour, loaded, fleet, watch, sent, end)
    await _picture_part(tour, loaded, pictures, end)
    await _relay_part(tour, fleet, relays, end)


async def _relay_part(tour: Tour, fleet: Fleet, relays: RelayWatch | None,
                      end: float) -> None:
    """A vehicle out of the surface's reach, its values carried by another: the first frame
    of it the surface took through a relay (waiting for one, but not past the tour)."""
    if relays is None or not tour.part("relay"):
        return
    plan = relays.plan
    tour.relay_intro(plan.vehicle, plan.surface, plan.path, plan.links)
    while relays.first() is None and time.time() < end:
        await asyncio.sleep(POLL_S)
    found = relays.first()
    if found is None:
        tour.not_seen(f"a frame of {plan.vehicle} through {plan.path[1]}")
        return
    _, event = found
    channel, value = shown_values(event)
    network = fleet.nodes[str(event.meta["via"])].core.network
    tour.relayed(plan.vehicle, plan.surface, channel, short(value), str(event.meta["via"]),
                 int(event.meta["hops"]), int(event.meta["age_s"]),
                 network.routing.relayed if network is not None else 0)


class LateFrames(logging.Filter):
    """Keeps off the screen, and counts per node, the simulated modem's refusals of frames
    the bridge asked it to start after their moment (a busy computer): the summary says
    what they are, once. A frame due as the tour ends, refused by a modem already closed,
    is no news either."""

    def __init__(self) -> None:
        super().__init__()
        self.by_node: Counter[str] = Counter()

    def filter(self, record: logging.LogRecord) -> bool:
        text = record.getMessage()
        if "failed: " in text and "expired: asked to start" in text:
            self.by_node[text.split(":", 1)[0]] += 1
            return False
        return not re.search(r"failed: sim modem '\w+' is closed$", text)


async def run_demo(
    loaded: LoadedMission, *, duration: float, console: Console, live: bool = False,
    gui: bool = True, gui_port: int = 8080, report: Path | None = None,
    changes: list[str] | None = None, loss: float = 0.0,
) -> MissionReport:
    """The tour: fleet + apps for ``duration`` seconds, its parts told as they happen, then a
    summary; ``report`` (an HTML file) gets the mission report."""
    tour = Tour(loaded, console, duration)
    events = EventLog()
    recorder = MissionRecorder()
    plan = surfaced_vehicle(loaded)
    sent = None if plan is None else SentAtSwitches(plan[1], plan[0])
    relayed = relay_plan(loaded)
    relays = None if relayed is None else RelayWatch(relayed)

    def on_event(node: str, event: Event) -> None:
        events(node, event)
        recorder(node, event)
        if sent is not None:  # the vehicle's frames and switches, as its bridge saw them
            sent(node, event)
        if relays is not None:  # frames the surface took through a relay
            relays(node, event)

    fleet = Fleet(loaded, on_event=on_event)
    attach_truth(recorder, fleet)
    water = fleet.water

    def truth(node: str, wall: float) -> tuple[float, float, float] | None:
        if water is None:
            return None
        return water.position(loaded.mission.address_of(node), wall)

    apps = VehicleApps(loaded, lambda line: console.print(line, highlight=False, markup=False,
                                                               emoji=False), tour, truth)
    tour.plan(tour_parts(loaded, apps))
    tour.intro(changes or [])
    if fleet.throwaway_key:
        console.print(f"  {throwaway_note(loaded.mission)}", highlight=False)
    late = LateFrames()
    handlers = logging.getLogger().handlers
    for handler in handlers:
        handler.addFilter(late)
    end = time.time() + duration - END_MARGIN_S  # the story's last moment
    stop = asyncio.Event()
    runner = asyncio.create_task(
        run_fleet_for(fleet, duration, live=live, console=console, events=events, stop=stop)
    )
    await asyncio.wait([runner, asyncio.create_task(fleet.ready.wait())],
                       return_when=asyncio.FIRST_COMPLETED)
    tasks: list[asyncio.Task[None]] = []
    page: GuiServer | None = None
    queries: QueryApps | None = None
    pictures: PictureWatch | None = None
    try:
        if not runner.done():
            apps.start()
            tasks.append(asyncio.create_task(apps.run()))
            if loaded.table.queries:  # issue 15: gets across the water (a part of the tour)
                queries = QueryApps(loaded, apps.sessions, apps.own)
            watch = None if plan is None or plan[0] not in apps.sessions else SurfacingWatch(
                loaded, apps.sessions[plan[0]], plan[0], plan[1])
            if gui:
                page = await _start_gui(loaded, gui_port, console)
                tour.gui(None if page is None else page.url, page.node if page else "")
            camera = camera_pair(loaded)
            if camera is not None and camera[0] in apps.sessions and camera[2] in apps.sessions:
                pictures = PictureWatch(apps.sessions[camera[0]], camera[1],
                                        apps.sessions[camera[2]], camera[3])
            story = asyncio.create_task(
                _story(apps, tour, loaded, loss, fleet, queries, watch, sent, relays, tasks,
                       end, pictures))
            tasks += [story, asyncio.create_task(cut_short(stop, story, tour, end))]
        await runner
    finally:
        if page is not None:
            await page.stop()
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        apps.examples_done.set()  # a story thread still waiting ends now
        if pictures is not None:
            pictures.changed.set()
            pictures.close()
        apps.close()
        for handler in handlers:
            handler.removeFilter(late)
    result = fleet.report()
    tour.part("summary")
    still = {n for n, node in loaded.mission.nodes.items()
             if node.nav_key is None and node.path is None}
    waits = [w for w in turn_waits(loaded).values() if w]
    tour.summary(result.to_dict(), apps.published,
                 [(observer, peer, abs(m - t)) for _, observer, peer, m, t
                  in recorder.recording.ranges if t is not None],
                 still, max(waits) if waits else None)
    found = _query_pair(loaded)
    if queries is not None and found is not None:
        tour.operators(found[1], queries.answered, queries.failed, QUERY_PERIOD_S)
    tour.late_frames(late.by_node)
    if apps.errors:
        table = Table("node", "positions", "p50 error", "p95 error", "max error",
                      title="Published positions against the simulator's truth")
        for node, errors in sorted(apps.errors.items()):
            ordered = sorted(errors)
            table.add_row(node, str(len(errors)), f"{ordered[len(errors) // 2]:.2f} m",
                          f"{ordered[min(len(errors) - 1, int(0.95 * len(errors)))]:.2f} m",
                          f"{ordered[-1]:.2f} m")
        console.print(table)
    if report is not None:
        try:
            write_report(report, result, recorder.recording, loaded)
        except OSError as exc:
            console.print(said(("cannot write the mission report:", "red"), f" {exc}"),
                          highlight=False)
        else:
            console.print(f"mission report (plots, opens offline): {report.resolve()}",
                          highlight=False, soft_wrap=True)  # a path one can copy whole
    return result
