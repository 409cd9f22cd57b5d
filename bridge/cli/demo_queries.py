"""The parts of ``zab demo`` for issue 15's features: key-family inputs and queries.

Plain Zenoh applications again (only ``zenoh`` and ``msgpack``): a queryable on each serving
vehicle answering its query's key with plausible reply fields, and an operator at each asking
node that gets every asked key now and then and prints the answer (or the reply error).
"""

from __future__ import annotations

import asyncio
import functools
import math
import threading
import time
from collections.abc import Callable
from typing import Any

import msgpack
import zenoh

from bridge.core.loaded import LoadedMission
from bridge.errors import DecodeError
from bridge.wire.channels import ChannelCodec
from bridge.wire.queries import QuerySpec

QUERY_PERIOD_S = 20.0
FIRST_QUERY_S = 8.0
TOUR_QUERY_TIMEOUT_S = 30.0  # the tour's query: several TDMA cycles, for repeats under loss
POLL_S = 0.2
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


def _reply_value(spec: QuerySpec, t: float, params: dict[str, Any]) -> dict[str, Any]:
    """Plausible reply fields; a field named like a parameter echoes it."""
    value: dict[str, Any] = {}
    for field in spec.reply.fields:
        *parents, last = field.path.split(".")
        target = value
        for part in parents:
            target = target.setdefault(part, {})
        target[last] = params[last] if last in params else _plausible(field, t)
    return value


def _plausible(field: Any, t: float) -> Any:
    """A value the field encodes, moving slowly through its codes."""
    code = int(((1 << field.bits) - 1) * (0.5 + 0.4 * math.sin(t / 30)))
    while code > 0:  # a code past the field's range (an int field's spare codes): go lower
        try:
            return field.decode(code)
        except DecodeError:
            code //= 2
    return field.decode(0)


class QueryApps:
    """Queryables on serving vehicles and an operator asking from the asking nodes."""

    def __init__(self, loaded: LoadedMission, sessions: dict[str, zenoh.Session],
                 show: Callable[[str], None]) -> None:
        self.loaded = loaded
        self.sessions = sessions
        self.show = show
        self.answered = 0
        self.failed = 0
        self.t0 = time.time()
        self.pending = 0  # the operators' gets not ended yet
        self.alone = False  # the tour's own get runs: the operators wait
        self.until = math.inf  # the fleet stops then: replies after it are not the fleet's
        self._lock = threading.Lock()
        for spec in loaded.table.queries:
            for server in spec.servers:
                session = sessions.get(server)
                if session is not None:
                    session.declare_queryable(spec.served_key(server),
                                              functools.partial(self._answer, spec=spec))

    def _answer(self, query: zenoh.Query, spec: QuerySpec) -> None:
        params = {}
        for part in filter(None, str(query.parameters).split(";")):
            name, _, raw = part.partition("=")
            params[name] = int(raw) if raw.lstrip("-").isdigit() else raw
        value = _reply_value(spec, time.time() - self.t0, params)
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
                    asked = time.time()
                    with self._lock:
                        self.pending += 1
                    session.get(selector, zenoh.handlers.Callback(
                        functools.partial(self._reply, asker, selector, asked),
                        self._ended), timeout=60.0)

    def _ended(self) -> None:  # Zenoh thread: an operator's get is over
        with self._lock:
            self.pending -= 1

    async def ask_alone(self, asker: str, selector: str, timeout: Callable[[], float]
                        ) -> tuple[float | None, tuple[list[Any], list[str], float]]:
        """:meth:`ask`, once the operators' gets have ended, with theirs held meanwhile;
        returns the seconds waited for them too (None: none was open). ``timeout()`` is the
        get's, asked when it starts."""
        self.alone = True
        started = time.time()
        try:
            busy = self.pending > 0
            while self.pending > 0:  # each ends by its deadline at the latest
                await asyncio.sleep(POLL_S)
            waited = time.time() - started if busy else None
            return waited, await self.ask(asker, selector, timeout())
        finally:
            self.alone = False

    def _reply(self, asker: str, selector: str, asked: float, reply: zenoh.Reply) -> None:
        if time.time() >= self.until:
            return  # the bridges are stopping: they end what is still open, not the water
        took = time.time() - asked
        if reply.ok is not None:
            self.answered += 1
            value = msgpack.unpackb(reply.ok.payload.to_bytes())
            self.show(f"[blue]{asker:>4}[/] get {selector} → {value} ({took:.1f} s)")
        else:
            self.failed += 1
            why = reply.err.payload.to_string() if reply.err is not None else "no reply"
            self.show(f"[red]{asker:>4}[/] get {selector} failed after {took:.1f} s: {why}")

    async def run(self, first_s: float = FIRST_QUERY_S, until: float = math.inf) -> None:
        """Ask every QUERY_PERIOD_S from ``first_s`` on, the tour's get aside
        (:meth:`ask_alone`), until the fleet stops at wall time ``until``."""
        self.until = until
        await asyncio.sleep(first_s)  # the links come up first
        while True:
            while self.alone:  # the tour's get goes alone
                await asyncio.sleep(POLL_S)
            self.ask_once()
            await asyncio.sleep(QUERY_PERIOD_S)
