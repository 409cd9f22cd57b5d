"""The GUI's picture of the fleet, built from the samples one node sees (pure, clock-free).

:class:`GuiModel` takes every sample the GUI's Zenoh session receives (``ingest``), the
commands typed on the page (``command``) and the passing time (``tick``), and accumulates
*items*: small JSON-ready dicts that the page applies in order (``take``). ``snapshot`` gives
the items that rebuild the whole picture for a page that has just connected. Times are the
GUI host's clock at arrival (``now``); a bridge's own clock is used only for differences, so
ages stay right even if that vehicle's clock is off.

Item kinds: ``position`` (node, x, y, depth, source nav|fix, sigma_m; a tracker's fix also
state tracking|coasting, age_s and its 1-σ ellipse), ``lost`` (node, reason: the tracker has no
position), ``track`` (node, source,
points), ``channel`` (node, channel, element, key, value, interval_s), ``link`` (observer,
node, state), ``heard`` (node, last_heard), ``range`` (observer, peer, range_m), ``stats``,
``event`` (level, category, text), ``command`` and ``transfer``; with several links or routes
``hop`` (observer, link, peer, state) and ``route`` (observer, peer, link, via, reason):
:mod:`bridge.gui.network_view`.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from bridge.core.loaded import LoadedMission
from bridge.errors import DecodeError
from bridge.gui.commands import Command, CommandBook, CommandError, Put, command_channels
from bridge.gui.eventlog import (
    CounterWatch,
    LogLine,
    delivery_line,
    describe_event,
    link_line,
    transfer_line,
)
from bridge.gui.images import ImageBoard
from bridge.gui.keys import ChannelSource, StatusKey, SurfaceKeys
from bridge.gui.network_view import NetworkView, network_description, relay_view
from bridge.wire.payloads import decode_payload

#: Points of track kept per vehicle and source (about 10 min of 1 Hz navigation).
TRACK_POINTS = 600
#: Lines kept in the event log.
MAX_EVENTS = 300
#: Longest text, list or byte string shown in a value; longer ones are cut.
MAX_SHOWN = 64
#: "Last heard" moves only by more than this: the stats' once-a-second echo of the same
#: frame differs by transit jitter, which is not news.
HEARD_SLACK_S = 0.25


Item = dict[str, Any]


def shown(value: Any, depth: int = 0) -> Any:
    """``value`` made JSON-safe and small: bytes as hex, long text and lists cut."""
    if isinstance(value, bytes | bytearray):
        text = bytes(value[:MAX_SHOWN]).hex()
        return text if len(value) <= MAX_SHOWN else f"{text}… ({len(value)} B)"
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, str):
        return value if len(value) <= MAX_SHOWN * 4 else value[:MAX_SHOWN * 4] + "…"
    if depth > 8:
        return "…"
    if isinstance(value, Mapping):
        return {str(k): shown(v, depth + 1) for k, v in list(value.items())[:MAX_SHOWN]}
    if isinstance(value, list | tuple):
        items = [shown(v, depth + 1) for v in value[:MAX_SHOWN]]
        return items if len(value) <= MAX_SHOWN else [*items, f"… ({len(value)} items)"]
    if value is None or isinstance(value, bool | int):
        return value
    return str(value)


def _finite(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    number = float(value)
    return number if math.isfinite(number) else None


def _tracked(value: Mapping[str, Any]) -> dict[str, Any]:
    """A tracker fix's state, age and 1-σ ellipse, where the payload has them (all finite)."""
    out: dict[str, Any] = {}
    if value.get("state") in ("tracking", "coasting"):
        out["state"] = value["state"]
    age = _finite(value.get("age_s"))
    if age is not None:
        out["age_s"] = age
    ellipse = value.get("ellipse")
    if isinstance(ellipse, Mapping):
        axes = [_finite(ellipse.get(k)) for k in ("major_m", "minor_m", "angle_deg")]
        if all(a is not None for a in axes):
            out["ellipse"] = dict(zip(("major_m", "minor_m", "angle_deg"), axes, strict=True))
    return out


def _xyz(value: Any) -> tuple[float, float, float] | None:
    """(x, y, depth) from a navigation payload; depth defaults to 0."""
    if not isinstance(value, Mapping):
        return None
    x, y = _finite(value.get("x")), _finite(value.get("y"))
    depth = _finite(value.get("depth", 0.0))
    if x is None or y is None or depth is None:
        return None
    return x, y, depth


def zspace_view(stats: Mapping[str, Any]) -> dict[str, Any]:
    """Issue 15's state in a node's stats, for the page: the channels its applications want
    (demand missions), its open acoustic queries, the peers it reaches over IP, and the keys
    its applications put that no channel reads."""
    out: dict[str, Any] = {}
    interest, queries, surfacing = (stats.get(k) for k in ("interest", "queries", "surfacing"))
    if isinstance(interest, Mapping) and isinstance(interest.get("here"), list):
        out["wanted"] = [str(c) for c in interest["here"]]
    if isinstance(queries, Mapping) and isinstance(queries.get("open"), list):
        out["open_queries"] = [f"{q.get('query')} → {q.get('server')}"
                               for q in queries["open"] if isinstance(q, Mapping)]
    if isinstance(surfacing, Mapping) and isinstance(surfacing.get("ip_reachable"), list):
        out["ip_reachable"] = [str(p) for p in surfacing["ip_reachable"]]
    unmapped = stats.get("unmapped_keys")
    if isinstance(unmapped, Mapping):  # issue 32: puts no channel reads (a typo, often)
        out["unmapped"] = [f"{k} ×{n}" for k, n in sorted(unmapped.items())]
    return out


@dataclass
class VehicleView:
    """What the GUI knows of one node."""

    name: str
    position: dict[str, Item] = field(default_factory=dict)  # by source: nav, fix
    tracks: dict[str, deque[list[float]]] = field(default_factory=dict)
    channels: dict[tuple[str, int], Item] = field(default_factory=dict)
    heard: float | None = None
    lost: Item | None = None  # the tracker said it has no position (newer than the fix)


class GuiModel:
    """Everything the page shows, updated from samples; items accumulate until ``take``."""

    def __init__(self, loaded: LoadedMission, node: str, *, track_points: int = TRACK_POINTS,
                 max_events: int = MAX_EVENTS) -> None:
        self.loaded = loaded
        self.node = node
        self.keys = SurfaceKeys(loaded, node)
        self.track_points = track_points
        self.commands = {c.channel: c for c in command_channels(loaded, node)}
        self.images = ImageBoard(loaded, node)
        self.book = CommandBook()
        self.vehicles = {name: VehicleView(name) for name in loaded.mission.nodes}
        self.links: dict[tuple[str, str], Item] = {}
        self.ranges: dict[tuple[str, str], Item] = {}
        self.stats: dict[str, Item] = {}
        self.transfers: dict[tuple[str, str, Any], Item] = {}
        self.network = NetworkView(set(loaded.mission.nodes))
        self.events: deque[Item] = deque(maxlen=max_events)
        self.dropped: Counter[str] = Counter()
        self._watches: dict[str, CounterWatch] = {}
        self._event_streams: set[str] = set()
        self._out: list[Item] = []

    # -- description -------------------------------------------------------------------------

    def description(self) -> dict[str, Any]:
        """The static part of the page: mission, nodes, channels and command forms."""
        mission = self.loaded.mission
        nodes = []
        for name, node in mission.nodes.items():
            static = node.position
            nodes.append({
                "name": name, "role": node.role, "address": node.address,
                "position": None if static is None else
                {"x": static.x, "y": static.y, "depth": static.depth},
            })
        channels = [{"name": c.name, "senders": list(c.senders), "receivers": list(c.receivers),
                     "interval_s": c.interval_s, "latching": c.latching}
                    for c in self.loaded.table.channels]
        return {"mission": mission.mission, "node": self.node, "nodes": nodes,
                "channels": channels,
                "commands": [c.describe() for c in self.commands.values()],
                "images": self.images.describe(),
                "track_points": self.track_points, "sent_after_s": self.book.sent_after_s,
                **network_description(self.loaded, self.node)}

    # -- output ------------------------------------------------------------------------------

    def take(self) -> list[Item]:
        """The items produced since the last call."""
        out, self._out = self._out, []
        return out

    def snapshot(self) -> list[Item]:
        """Items that rebuild the whole picture, oldest facts first."""
        items: list[Item] = []
        for view in self.vehicles.values():
            for source, track in view.tracks.items():
                items.append({"kind": "track", "node": view.name, "source": source,
                              "points": [list(p) for p in track]})
            items.extend(view.position.values())
            items.extend(view.channels.values())
            if view.heard is not None:
                items.append({"kind": "heard", "node": view.name, "last_heard": view.heard})
            if view.lost is not None:
                items.append(view.lost)
        items.extend(self.links.values())
        items.extend(self.ranges.values())
        items.extend(self.network.items())
        items.extend(self.stats.values())
        items.extend(self.transfers.values())
        items.extend(self.events)
        items.extend(self.book.items())
        items.extend(self.images.items())
        return items

    def emit(self, item: Item) -> None:
        """An item from outside the model (the GUI's own connection state) for the pages."""
        self._out.append(item)

    def note(self, level: str, category: str, text: str, now: float) -> None:
        """A line of the GUI's own (connection, errors) in the event log."""
        self._log(LogLine(level, category, text), now)

    def _log(self, line: LogLine, now: float, node: str | None = None) -> None:
        item = {"kind": "event", "time": now, "node": node, "level": line.level,
                "category": line.category, "text": line.text}
        self.events.append(item)
        self._out.append(item)

    # -- input -------------------------------------------------------------------------------

    def ingest(self, key: str, data: bytes, encoding: str, now: float,
               publisher: str | None = None) -> None:
        """One sample the GUI's session received; ``publisher``: the node whose bridge
        published it (from its origin tag; None: an application)."""
        picture = self.images.ingest(key, data, encoding, now)
        if picture is not None:
            self._out.append(picture)
            return
        status = self.keys.status(key)
        sources = self.keys.lookup(key)
        if status is None and sources is None:
            return
        ros2 = next((s.ros2 for s in sources or () if s.ros2 is not None), None)
        try:
            value = decode_payload(data, encoding) if ros2 is None else ros2.decode(data, key)
        except DecodeError as exc:
            self._drop(key, str(exc), now)
            return
        if status is not None:
            self._status(status, value, now)
        for source in sources or ():
            if publisher is None or publisher in (self.node, source.src):
                self._value(source, value, now)
            # else a third vehicle's bridge published what it heard acoustically, seen here
            # because it surfaced and its Zenoh joined this node's: this node's bridge brings
            # the same value (the sender's own bridge, over IP, may too), so it is no arrival

    def _drop(self, key: str, reason: str, now: float) -> None:
        self.dropped[key] += 1
        if self.dropped[key] == 1:  # logged once per key, counted always
            self._log(LogLine("warn", "payload", f"GUI cannot read {key}: {reason}"), now)

    def _value(self, source: ChannelSource, value: Any, now: float) -> None:
        view = self.vehicles[source.src]
        slot = (source.channel, source.element)
        previous = view.channels.get(slot)
        item = {"kind": "channel", "node": source.src, "channel": source.channel,
                "element": source.element, "key": source.key, "value": shown(value),
                "time": now, "interval_s": None if previous is None else now - previous["time"],
                "count": 1 if previous is None else previous["count"] + 1}
        view.channels[slot] = item
        self._out.append(item)
        if source.nav:
            xyz = _xyz(value)
            if xyz is None:
                self._drop(source.key, "navigation needs numbers x, y (and depth)", now)
            else:
                self._position(source.src, "nav", xyz, now)

    def _position(self, node: str, source: str, xyz: tuple[float, float, float], now: float,
                  sigma_m: float | None = None, extra: Mapping[str, Any] | None = None) -> None:
        view = self.vehicles[node]
        x, y, depth = xyz
        item = {"kind": "position", "node": node, "source": source, "x": x, "y": y,
                "depth": depth, "time": now, "sigma_m": sigma_m, **(extra or {})}
        view.position[source] = item
        track = view.tracks.setdefault(source, deque(maxlen=self.track_points))
        track.append([x, y, now])
        self._out.append(item)

    def _status(self, status: StatusKey, value: Any, now: float) -> None:
        node, topic, name = status.node, status.topic, status.name
        if node not in self.vehicles or not isinstance(value, Mapping):
            return
        if topic == "stats" and name is None:
            self._stats(node, value, now)
        elif topic == "link" and name in self.vehicles:
            silent = _finite(value.get("silent_s"))
            self._link(node, name, str(value.get("state")), now,
                       None if silent is None else now - silent)
        elif topic == "peers" and name in self.vehicles:
            self._heard(name, now)
        elif topic == "range" and name in self.vehicles:
            metres = _finite(value.get("range_m"))
            if metres is not None:
                item = {"kind": "range", "observer": node, "peer": name, "range_m": metres,
                        "time": now, "method": shown(value.get("method"))}
                self.ranges[(node, name)] = item
                self._out.append(item)
        elif topic == "position" and name is None and value.get("fix") is False:
            if value.get("state") == "lost":  # the tracker's word: it has no position
                item = {"kind": "lost", "node": node, "reason": shown(value.get("reason")),
                        "time": now}
                self.vehicles[node].lost = item
                self._out.append(item)
        elif topic == "position" and name is None:
            xyz = _xyz(value)
            if xyz is not None:
                self.vehicles[node].lost = None
                self._position(node, "fix", xyz, now, _finite(value.get("sigma_m")),
                               _tracked(value))
        elif topic in ("links", "route") and name is not None:
            news = self.network.status(node, topic, name, value, now)
            if news is not None:
                self._out.append(news)
        elif topic == "delivery":
            self._delivery(node, value, now)
        elif topic == "transfer":
            self._transfer(node, value, now)
        elif topic == "events" and name is None:
            self._event_streams.add(node)
            line = describe_event(node, value)
            if line is not None:
                self._log(line, now, node)

    def _stats(self, node: str, stats: Mapping[str, Any], now: float) -> None:
        def total(name: str) -> int:
            table = stats.get(name)
            return sum(v for v in table.values() if isinstance(v, int)) \
                if isinstance(table, Mapping) else 0

        item = {"kind": "stats", "node": node, "time": now,
                "frames_sent": shown(stats.get("frames_sent")),
                "frames_received": shown(stats.get("frames_received")),
                "frames_dropped": total("frames_dropped"),
                "payloads_dropped": total("payloads_dropped"),
                "send_errors": shown(stats.get("send_errors")),
                "values_published": shown(stats.get("values_published"))}
        item.update(zspace_view(stats))
        item.update(relay_view(stats))
        self.stats[node] = item
        self._out.append(item)
        self._out.extend(self.network.stats(node, stats, now))
        watch = self._watches.setdefault(node, CounterWatch(node))
        lines = watch.update(stats)
        if node not in self._event_streams:  # its events say the same, one by one
            for line in lines:
                self._log(line, now, node)
        bridge_time = _finite(stats.get("time"))
        heard = stats.get("last_heard")
        links = stats.get("links")
        for peer in self.vehicles:
            last = _finite(heard.get(peer)) if isinstance(heard, Mapping) else None
            at = None if last is None or bridge_time is None else now - (bridge_time - last)
            if at is not None:
                self._heard(peer, at)
            if isinstance(links, Mapping) and isinstance(links.get(peer), str):
                self._link(node, peer, links[peer], now, at)

    def _heard(self, node: str, at: float) -> None:
        view = self.vehicles[node]
        if view.heard is not None and at <= view.heard + HEARD_SLACK_S:
            return
        view.heard = at
        self._out.append({"kind": "heard", "node": node, "last_heard": at})

    def _link(self, observer: str, peer: str, state: str, now: float,
              heard: float | None) -> None:
        if state not in ("up", "degraded", "down"):
            return
        if heard is not None:
            self._heard(peer, heard)
        previous = self.links.get((observer, peer))
        if previous is not None and previous["state"] == state:
            return
        item = {"kind": "link", "observer": observer, "node": peer, "state": state,
                "since": now}
        self.links[(observer, peer)] = item
        self._out.append(item)
        silent = None if heard is None else max(0.0, now - heard)
        never = self.vehicles[peer].heard is None
        self._log(link_line(observer, peer, state, silent, never), now, observer)

    def liveliness(self, key: str, alive: bool, now: float) -> None:
        """A link token appeared or vanished. A vanished token means the link is down, or
        the bridge holding it is gone (then no link message says so); a new one is news only
        with its state, which the link key and the stats bring."""
        status = self.keys.status(key)
        if status is None or status.topic != "link" or status.name not in self.vehicles:
            return
        if not alive:
            self._link(status.node, status.name, "down", now, None)

    def _delivery(self, node: str, report: Mapping[str, Any], now: float) -> None:
        item = self.book.report(dict(report), now)
        if item is not None:
            self._out.append(shown(item))
        if report.get("state") == "failed":
            self._log(delivery_line(node, report), now, node)

    def _transfer(self, node: str, report: Mapping[str, Any], now: float) -> None:
        item = {"kind": "transfer", "node": node, "time": now,
                **{k: shown(v) for k, v in report.items() if k != "time"}}
        slot = (node, str(report.get("channel")), report.get("id"))
        self.transfers[slot] = item
        while len(self.transfers) > MAX_EVENTS:
            self.transfers.pop(next(iter(self.transfers)))
        self._out.append(item)
        line = transfer_line(node, report)
        if line is not None:
            self._log(line, now, node)

    # -- commands and time ---------------------------------------------------------------------

    def command(self, request: Mapping[str, Any], ref: str, now: float) -> list[Put]:
        """Check a command from the page; the puts to make, each with attachment
        ``ref:<ref>``. Raises :class:`CommandError` with a message for the page."""
        name = request.get("channel")
        channel = self.commands.get(name) if isinstance(name, str) else None
        if channel is None:
            raise CommandError(f"{self.node} sends no channel {name!r}")
        vehicle = request.get("vehicle")
        if vehicle not in channel.destinations:
            raise CommandError(f"channel {channel.channel!r} does not reach {vehicle!r} "
                               f"(it reaches {', '.join(channel.destinations)})")
        payloads = channel.puts(request.get("values"), now, str(vehicle))
        self._out.append(self.book.add(Command(ref, str(vehicle), channel.channel,
                                               shown(request.get("values")), channel.reliable,
                                               now)))
        return payloads

    def command_failed(self, ref: str, reason: str, now: float) -> None:
        """The put itself failed (no session): the command failed at once."""
        command = self.book.commands.get(ref)
        if command is not None:
            command.state, command.reason, command.updated = "failed", reason, now
            self._out.append(command.item())

    def tick(self, now: float) -> None:
        """Let time pass: best-effort commands become "sent"."""
        self._out.extend(self.book.tick(now))
