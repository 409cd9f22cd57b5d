"""The parts of ``zab demo`` for issue 15's features: key-family inputs and queries.

Plain Zenoh applications again (only ``zenoh`` and ``msgpack``): a queryable on each serving
vehicle answering its query's key with plausible reply fields, and an operator at each asking
node that gets every asked key now and then, counting the answers for the tour's summary.
"""

from __future__ import annotations

import asyncio
import functools
import math
import threading
import time
import zlib
from collections import Counter
from collections.abc import Callable
from typing import Any

import msgpack
import zenoh

from bridge.core.loaded import LoadedMission
from bridge.errors import DecodeError
from bridge.wire.channels import ChannelCodec
from bridge.wire.queries import QuerySpec

QUERY_PERIOD_S = 20.0
TOUR_QUERY_TIMEOUT_S = 30.0  # the tour's query: several TDMA cycles, for repeats under loss
LEARNED_DEMO_KEYS = 3  # members a demo application publishes on a learned family


def query_for_tour(data: dict[str, Any]) -> str | None:
    """Give a mission without queries (raw YAML data, changed in place) one for the tour: the
    surface node gets ``<vehicle>/health`` from any submerged vehicle. Returns the change in
    words (None: it has queries, or no surface node and vehicle)."""
    nodes = data.get("nodes") or {}
    surface = next((n for n, v in nodes.items() if v.get("role") == "surface"), None)
    vehicles = [n for n, v in nodes.items() if v.get("role", "submerged") != "surface"]
    if data.get("queries") or surface is None or not vehicles:
        return None
    data["queries"] = [{
        "name": "health", "key": "{node}/health", "serve": "|".join(vehicles), "ask": surface,
        "reply": [{"field": "battery", "type": "int", "min": 0, "max": 100},
                  {"field": "depth_m", "min": 0, "max": 200, "resolution": 0.5}],
        "timeout_s": TOUR_QUERY_TIMEOUT_S}]
    return (f"{surface} may get <vehicle>/health from a queryable on any vehicle (a query "
            f"across the water, {TOUR_QUERY_TIMEOUT_S:g} s to answer)")


def member_keys(channel: ChannelCodec, element: int, node: str) -> list[str]:
    """The concrete input keys a demo application publishes for one element: the element's
    key, or one per member of a key family (a few names for a learned one)."""
    codec = channel.elements[element]
    family = channel.family
    if family is None:
        return [codec.input_key(node)]
    names = ([f"k{i}" for i in range(min(family.bound, LEARNED_DEMO_KEYS))] if family.learned
             else list(family.members))
    return [codec.input_key(node, name) for name in names]


Own = Callable[[str], Any]
"""A serving vehicle's own data by field name (its battery, its depth ...); None if it has
none of that name."""


def _reply_value(spec: QuerySpec, t: float, params: dict[str, Any], own: Own,
                 phase: float = 0.0) -> dict[str, Any]:
    """Reply fields: a field named like a parameter echoes it, one named like the vehicle's
    own data is that, any other a plausible value of its own (``phase``: the vehicle's)."""
    value: dict[str, Any] = {}
    for field in spec.reply.fields:
        *parents, last = field.path.split(".")
        target = value
        for part in parents:
            target = target.setdefault(part, {})
        mine = own(last)
        target[last] = params[last] if last in params else \
            mine if mine is not None else _plausible(field, t, phase)
    return value


def _plausible(field: Any, t: float, phase: float = 0.0) -> Any:
    """A value the field encodes, moving slowly through its codes."""
    code = int(((1 << field.bits) - 1) * (0.5 + 0.4 * math.sin(t / 30 + phase)))
    while code > 0:  # a code past the field's range (an int field's spare codes): go lower
        try:
            return field.decode(code)
        except DecodeError:
            code //= 2
    return field.decode(0)


def failure(error: str) -> str | None:
    """The reason of a reply error without its vehicle ("gcv: acoustic link down" → "acoustic
    link down"); None for a get its bridge ended as it stopped (Ctrl-C before the tour's
    end), which is no failure of the water's."""
    why = error.split(": ", 1)[-1]
    return None if why == "the bridge is stopping" else why


class QueryApps:
    """Queryables on serving vehicles, each answering with that vehicle's own data
    (``own(vehicle, field)``), and an operator asking from the asking nodes now and then,
    quietly: what the operator's gets came to is counted (:attr:`answered`,
    :attr:`failed` by reason) for the tour's summary."""

    def __init__(self, loaded: LoadedMission, sessions: dict[str, zenoh.Session],
                 own: Callable[[str, str], Any]) -> None:
        self.loaded = loaded
        self.sessions = sessions
        self.answered = 0
        self.failed: Counter[str] = Counter()
        self.own = own
        self.t0 = time.time()
        self.until = math.inf  # the fleet stops then: replies after it are not the fleet's
        self._lock = threading.Lock()
        for spec in loaded.table.queries:
            for server in spec.servers:
                session = sessions.get(server)
                if session is not None:
                    session.declare_queryable(
                        spec.served_key(server),
                        functools.partial(self._answer, spec=spec, server=server))

    def _answer(self, query: zenoh.Query, spec: QuerySpec, server: str) -> None:
        params = {}
        for part in filter(None, str(query.parameters).split(";")):
            name, _, raw = part.partition("=")
            params[name] = int(raw) if raw.lstrip("-").isdigit() else raw
        phase = zlib.crc32(server.encode()) % 628 / 100  # each vehicle its own
        value = _reply_value(spec, time.time() - self.t0, params,
                             lambda name: self.own(server, name), phase)
        query.reply(query.key_expr, msgpack.packb(value),
                    encoding=zenoh.Encoding("application/msgpack"))
        query.drop()

    def selector(self, spec: QuerySpec, server: str) -> str:
        """The selector an operator gets: the asked key, with each request field at zero."""
        params = ";".join(f"{f.path}={f.decode(0)}" for f in spec.request.fields
                          if "." not in f.path)
        return spec.asked_key(server) + (f"?{params}" if params else "")

    async def ask(self, asker: str, selector: str,
                  timeout: float = 60.0) -> tuple[list[Any], list[str], float]:
        """One plain Zenoh get at ``asker``: the reply values, the reply errors, and the
        seconds from the get to its end (its last reply)."""
        session = self.sessions[asker]
        loop = asyncio.get_running_loop()
        done: asyncio.Future[None] = loop.create_future()
        values: list[Any] = []
        errors: list[str] = []
        ended: list[float] = []

        def on_reply(reply: zenoh.Reply) -> None:  # Zenoh thread
            if reply.ok is not None:
                values.append(msgpack.unpackb(reply.ok.payload.to_bytes()))
            elif reply.err is not None:
                errors.append(reply.err.payload.to_string())

        def resolve() -> None:
            if not done.done():
                done.set_result(None)

        def finished() -> None:
            ended.append(time.time())
            loop.call_soon_threadsafe(resolve)

        asked = time.time()
        session.get(selector, zenoh.handlers.Callback(on_reply, finished), timeout=timeout)
        await done
        return values, errors, ended[0] - asked

    def ask_once(self) -> None:
        """Each asking node gets every asked key once."""
        for spec in self.loaded.table.queries:
            for asker in spec.askers:
                session = self.sessions.get(asker)
                if session is None:
                    continue
                for server in spec.servers:
                    if server == asker:
                        continue
                    selector = self.selector(spec, server)
                    session.get(selector, zenoh.handlers.Callback(self._reply),
                                timeout=60.0)

    def _reply(self, reply: zenoh.Reply) -> None:
        if time.time() >= self.until:
            return  # the bridges are stopping: they end what is still open, not the water
        with self._lock:
            if reply.ok is not None:
                self.answered += 1
            else:  # "gcv: acoustic link down", ...: the reason, without the vehicle
                why = failure(reply.err.payload.to_string() if reply.err is not None
                              else "no reply")
                if why is not None:
                    self.failed[why] += 1

    async def run(self, until: float = math.inf) -> None:
        """Ask every QUERY_PERIOD_S until the fleet stops at wall time ``until``."""
        self.until = until
        while True:
            self.ask_once()
            await asyncio.sleep(QUERY_PERIOD_S)
