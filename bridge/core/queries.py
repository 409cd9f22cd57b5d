"""Queries across the water in the node core (pure): asking, serving, deadlines, limits.

Asking side: the runtime hands a Zenoh ``get`` to :meth:`Queries.ask`. It is refused at once
(a reason the runtime sends back as a reply error) when the serving node's link is down, when
``max_open_queries`` are already open here, or when its parameters do not fit the request
fields (counted). Otherwise it joins an open query with the same request (one acoustic request
serves every concurrent ``get``) or opens one: a query id, and a request entry in the next frame
the MAC allows. Replies become :class:`QueryAnswer` outputs and the end a :class:`QueryEnd`
(with an error when the deadline passes first: the query's ``timeout_s`` or the MAC's bound
for a request and its reply, see :func:`deadline_s`).

Serving side: a request becomes a :class:`LocalGet` for the runtime, which runs the local Zenoh
``get`` and calls :meth:`Queries.served` with the replies (at most ``max_replies``); they go
back in reply entries, the last one marked, in the next frames the MAC allows.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from bridge.core.builder import Candidate
from bridge.core.families import Extra
from bridge.core.link import LinkState
from bridge.core.mac import frame_time_s, mac_report
from bridge.errors import EncodeError
from bridge.mission.model import Mission
from bridge.wire.channels import ChannelTable
from bridge.wire.queries import QID_BITS, QueryCodec, QuerySpec, ReplyStatus

LOCAL_GET_S = 1.0  # time the serving bridge allows its local get, within the deadline
UNBOUNDED_TURN_S = 30.0  # a node's wait for a turn when the MAC gives no bound

Ticket = tuple[int, str, int]  # (query index, serving node, query id) at the asking node
Served = tuple[int, str, int]  # (query index, asking node, query id) at the serving node


@dataclass(frozen=True)
class LocalGet:
    """Serving side: run ``get(key, parameters)`` on this node's session, then call
    :meth:`NodeCore.query_served` with the replies."""

    ticket: Served
    key: str
    parameters: dict[str, Any]
    timeout_s: float


@dataclass(frozen=True)
class QueryAnswer:
    """Asking side: one reply ``value`` for the gets waiting on ``ticket``, on ``key``."""

    ticket: Ticket
    key: str
    value: Any
    encoding: str


@dataclass(frozen=True)
class QueryEnd:
    """Asking side: the query is over (``error`` None: every reply arrived)."""

    ticket: Ticket
    error: str | None = None


def deadline_s(mission: Mission, spec: QuerySpec, asker: str, server: str) -> float:
    """How long a query may take: the query's ``timeout_s``, else the MAC's bound: the asker's
    longest wait for a turn and its frame, the same for the server, and its local get."""
    if spec.timeout_s is not None:
        return spec.timeout_s
    total = LOCAL_GET_S
    for node in (asker, server):
        worst = mac_report(mission, node, None).worst_interval_s
        total += (worst if worst is not None else UNBOUNDED_TURN_S) + (
            frame_time_s(mission, node) or 0.0)
    return round(total, 3)


@dataclass
class Open:
    """A query open at the asking node."""

    ticket: Ticket
    key: str
    packed: int
    deadline: float
    sent: bool = False


@dataclass
class Queries:
    """The queries of one node, asking and serving."""

    mission: Mission
    table: ChannelTable
    node: str
    open: dict[Ticket, Open] = field(default_factory=dict)
    replies: list[tuple[QueryCodec, int, Served]] = field(default_factory=list)
    outputs: list[LocalGet | QueryAnswer | QueryEnd] = field(default_factory=list)
    dropped: Counter[str] = field(default_factory=Counter)
    asked: int = 0
    answered: int = 0
    failed: int = 0
    cached: int = 0
    cache: dict[str, tuple[Any, str, float]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        codecs = self.table.query_codecs
        self.requests = {c.spec.index: c for c in codecs if not c.reply}
        self.reply_codecs = {c.spec.index: c for c in codecs if c.reply}
        self._qid = 0

    def spec_for(self, key: str) -> tuple[QuerySpec, str] | None:
        """The query asked by a get on concrete ``key`` here, and its server."""
        for spec in self.table.queries:
            if self.node in spec.askers:
                for server in spec.servers:
                    if server != self.node and spec.asked_key(server) == key:
                        return spec, server
        return None

    def asked_keys(self) -> dict[str, tuple[QuerySpec, str]]:
        """Keys this node's bridge answers gets on (declares queryables for)."""
        return {spec.asked_key(server): (spec, server) for spec in self.table.queries
                if self.node in spec.askers for server in spec.servers if server != self.node}

    # -- asking ------------------------------------------------------------------------------

    def ask(self, spec: QuerySpec, server: str, parameters: Any, now: float,
            link: LinkState | None) -> Ticket | str:
        """Open (or join) a query; returns its ticket, or why it ends at once. A fresh enough
        latched value (``cached_s``) answers at once, even with the link down."""
        hit = self.cache.get(spec.asked_key(server))
        if spec.cached_s is not None and hit is not None and now - hit[2] <= spec.cached_s:
            self.cached += 1
            ticket = (spec.index, server, -self.cached)  # never an acoustic query id
            self.outputs += [QueryAnswer(ticket, spec.asked_key(server), hit[0], hit[1]),
                             QueryEnd(ticket)]
            return ticket
        if link is not LinkState.UP and link is not LinkState.DEGRADED:
            self.failed += 1
            return f"{server}: acoustic link down, query {spec.name!r} not sent"
        try:
            packed = spec.request.pack(parameters if spec.request.fields else {})
        except (EncodeError, TypeError, ValueError, KeyError) as exc:
            self.dropped[spec.name] += 1
            self.failed += 1
            return f"query {spec.name!r}: malformed parameters: {exc}"
        for item in self.open.values():
            if item.ticket[:2] == (spec.index, server) and item.packed == packed:
                return item.ticket  # a concurrent get with the same request: share it
        if len(self.open) >= self.mission.max_open_queries:
            self.failed += 1
            return (f"{self.node}: {self.mission.max_open_queries} acoustic queries already "
                    "open (max_open_queries)")
        used = {t[2] for t in self.open}
        qid = next(q for q in range(1 << QID_BITS) if q not in used)
        ticket = (spec.index, server, qid)
        self.open[ticket] = Open(ticket, spec.asked_key(server), packed,
                                 now + deadline_s(self.mission, spec, self.node, server))
        self.asked += 1
        return ticket

    def candidates(self, now: float) -> list[Candidate]:
        """Requests not sent yet and replies owed."""
        out: list[Candidate] = []
        for item in self.open.values():
            if not item.sent:
                codec = self.requests[item.ticket[0]]
                server = self.table.nodes.index(item.ticket[1])
                bits = codec.pack(item.ticket[2], server, item.packed)
                out.append(Candidate(codec, None, Extra(codec, bits, self._marker(item)),
                                     item.ticket[2]))
        for n, (codec, bits, served) in enumerate(self.replies):
            out.append(Candidate(codec, None, Extra(codec, bits, self._unqueue(served, bits)),
                                 n))
        return out

    def _marker(self, item: Open) -> Callable[[float], None]:
        def sent(built: float) -> None:
            item.sent = True
        return sent

    def _unqueue(self, served: Served, bits: int) -> Callable[[float], None]:
        def sent(built: float) -> None:
            self.replies = [r for r in self.replies if not (r[2] == served and r[1] == bits)]
        return sent

    def next_due(self) -> float | None:
        if self.replies or any(not item.sent for item in self.open.values()):
            return float("-inf")
        return None

    def on_reply(self, src: str, codec: QueryCodec, header: tuple[int, ...],
                 values: list[dict] | None) -> None:
        qid, asker, status = header
        if self.table.nodes[asker] != self.node:
            return  # a reply to somebody else
        ticket = (codec.spec.index, src, qid)
        item = self.open.get(ticket)
        if item is None:
            self.dropped["late_reply"] += 1
            return
        if values is not None:
            self.outputs.append(QueryAnswer(ticket, item.key, values[0], codec.spec.encoding))
        if status == ReplyStatus.FAILED:
            self._end(ticket, f"{src}: the serving node's get failed or gave no usable reply")
        elif status in (ReplyStatus.LAST, ReplyStatus.DONE):
            self.answered += 1
            self._end(ticket, None)

    def _end(self, ticket: Ticket, error: str | None) -> None:
        self.open.pop(ticket, None)
        if error is not None:
            self.failed += 1
        self.outputs.append(QueryEnd(ticket, error))

    def expire(self, now: float) -> None:
        """End the queries whose deadline passed."""
        for ticket, item in list(self.open.items()):
            if now >= item.deadline:
                spec = self.table.queries[ticket[0]]
                self._end(ticket, f"{ticket[1]}: no reply to query {spec.name!r} within "
                          f"{deadline_s(self.mission, spec, self.node, ticket[1]):g} s "
                          + ("(its timeout_s)" if spec.timeout_s else "(the MAC's bound)"))

    def next_deadline(self) -> float | None:
        return min((item.deadline for item in self.open.values()), default=None)

    # -- serving -----------------------------------------------------------------------------

    def on_request(self, src: str, codec: QueryCodec, header: tuple[int, ...],
                   values: list[dict] | None) -> None:
        qid, server, _ = header
        spec = codec.spec
        if self.table.nodes[server] != self.node or src not in spec.askers:
            return
        self.outputs.append(LocalGet((spec.index, src, qid), spec.served_key(self.node),
                                     values[0] if values else {}, LOCAL_GET_S))

    def served(self, ticket: Served, values: list[Any], error: str | None) -> None:
        """The local get of ``ticket`` ended with ``values`` (or failed with ``error``)."""
        spec = self.table.queries[ticket[0]]
        codec = self.reply_codecs[spec.index]
        asker = self.table.nodes.index(ticket[1])
        packed: list[int] = []
        for value in values[:spec.max_replies]:
            try:
                packed.append(spec.reply.pack(value))
            except (EncodeError, TypeError, ValueError, KeyError):
                self.dropped[f"{spec.name}:reply"] += 1
        if error is not None or (values and not packed):
            self.replies.append((codec, codec.pack(ticket[2], asker, 0, ReplyStatus.FAILED),
                                 ticket))
            return
        if not packed:
            self.replies.append((codec, codec.pack(ticket[2], asker, 0, ReplyStatus.DONE),
                                 ticket))
            return
        for i, bits in enumerate(packed):
            status = ReplyStatus.LAST if i == len(packed) - 1 else ReplyStatus.VALUE
            self.replies.append((codec, codec.pack(ticket[2], asker, bits, status), ticket))

    def remember(self, key: str, value: Any, encoding: str, now: float) -> None:
        """A latched channel's value this node published on ``key``."""
        self.cache[key] = (value, encoding, now)

    def take(self) -> list[LocalGet | QueryAnswer | QueryEnd]:
        out, self.outputs = self.outputs, []
        return out

    def snapshot(self) -> dict[str, Any]:
        return {"open": [{"query": self.table.queries[t[0]].name, "server": t[1],
                          "deadline": item.deadline} for t, item in self.open.items()],
                "asked": self.asked, "answered": self.answered, "failed": self.failed,
                "cached": self.cached,
                "dropped": dict(self.dropped), "replies_owed": len(self.replies)}
