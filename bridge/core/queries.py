"""Queries across the water in the node core (pure): asking, serving, deadlines, limits.

Asking side: the runtime hands a Zenoh ``get`` to :meth:`Queries.ask`. While the serving node is
reachable over IP (``surfacing``) nothing crosses the water: :class:`OverIp`, the get goes to
the server's applications over IP. Else it is refused at once (a reason the runtime sends back
as a reply error) when the serving node's link is down, when ``max_open_queries`` are already
open here, or when its parameters do not fit the request fields (counted). Otherwise it joins an
open query with the same request (one acoustic request serves every concurrent ``get``) or opens
one: a query id, and a request entry in the next frame the MAC allows. Replies become
:class:`QueryAnswer` outputs and the end a :class:`QueryEnd` (with an error when the deadline
passes first: the query's ``timeout_s`` or the MAC's bound for a request and its reply, see
:func:`deadline_s`).

Serving side: a request becomes a :class:`LocalGet` for the runtime, which runs the local Zenoh
``get`` and calls :meth:`Queries.served` with the replies (at most ``max_replies``); they go
back in reply entries, each with its index and the last one marked, in the next frames the MAC
allows.

Unusable input, both sides, goes the put path's way (``drop``: the node's
:meth:`~bridge.core.outbound.Outbound.drop_payload`, counted per key and cause, logged at a
bounded rate; ``told_left_out``: fields no request field carries, as a put's): a get refused
before it is asked (:meth:`Queries.refuse`: too large, undecodable, a parameter given twice),
a get whose parameters do not fit (``unfit``), and each reply of a local get that cannot be
sent (an error reply, an undecodable one, one that does not fit the reply fields). Counted
also in ``dropped`` (by query; ``<name>:reply`` for replies). When a local get gives nothing
to send back, the failed reply says why in a :class:`~bridge.wire.queries.FailReason`, and
the asker's reply error names it (``app-error``, ``not-usable``, ``timeout``).

Deadlines: a get may say how long its caller waits (``until``); the query then ends at the
earlier of that and its own deadline, and a request is never sent past it. With the query's
``deadline_bits`` each request carries the time left, in whole steps (see
:data:`~bridge.wire.queries.LEFT`): the server drops a request that arrives with none left
(counted ``expired``), gives its local get no more than what is left, and sends no reply after.

Under loss: the asker repeats the request at each later opportunity (once a reply could have
come back, :func:`retry_s`) until it holds every reply or the deadline passes; replies are
handed on once each, in the server's order. The server answers a repeated request from the
replies it kept (:class:`Answered`, at most ``answers_kept``, each for one deadline)
without running its local get again. Query ids rotate and cool for a deadline before reuse, so
a kept answer never meets a newer query.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from bridge.core.bounds import UNBOUNDED_TURN_S, round_trip_s
from bridge.core.builder import Candidate
from bridge.core.families import Extra
from bridge.core.link import LinkState
from bridge.core.mac import frame_time_s, mac_report
from bridge.core.surfacing import Surfacing
from bridge.errors import EncodeError
from bridge.mission.model import Mission
from bridge.mission.network import Network
from bridge.wire.channels import ChannelTable
from bridge.wire.payloads import payload_cap
from bridge.wire.queries import LEFT, QID_BITS, FailReason, QueryCodec, QuerySpec, ReplyStatus
from bridge.wire.unused import left_out, schema_tree

LOCAL_GET_S = 1.0  # time the serving bridge allows its local get, within the deadline
ANSWERS_KEPT = 32  # answers a serving node keeps for repeated requests (oldest go first)

Ticket = tuple[int, str, int]  # (query index, serving node, query id) at the asking node
Served = tuple[int, str, int]  # (query index, asking node, query id) at the serving node

ERROR_REPLY, UNDECODABLE, TOO_LARGE, TIMED_OUT = (
    "error_reply", "undecodable", "too_large", "timeout")
"""What the runtime says of a local get's reply it could not use (:meth:`Queries.served`): the
queryable's reply error, a reply neither msgpack nor JSON, and the get's own timeout."""
_REASONS = {ERROR_REPLY: FailReason.APP_ERROR, UNDECODABLE: FailReason.NOT_USABLE,
            TOO_LARGE: FailReason.NOT_USABLE, TIMED_OUT: FailReason.TIMEOUT}
_FAILED = {
    FailReason.UNSAID: "the serving node's get failed or gave no usable reply",
    FailReason.APP_ERROR: "its queryable replied with an error (its text is in {src}'s log)",
    FailReason.NOT_USABLE: "its replies could not be decoded or did not fit the reply "
                           "fields (counted and logged at {src})",
    FailReason.TIMEOUT: "no queryable at {src} answered within its local get's time"}
"""The asker's reply error for a failed reply, by reason."""


def failed_reply(src: str, name: str, code: int) -> str:
    """The reply error a get is given when ``src`` answers query ``name`` with a failed reply
    saying ``code`` (a :class:`FailReason`; another number is unsaid)."""
    try:
        reason = FailReason(code)
    except ValueError:  # (fields with room for more than a reason: another number)
        reason = FailReason.UNSAID
    if reason is FailReason.UNSAID:
        return f"{src}: {_FAILED[reason]}"
    return f"{src}: query {name!r}: {reason.code}: {_FAILED[reason].format(src=src)}"


@dataclass(frozen=True)
class LocalGet:
    """Serving side: run ``get(key, parameters)`` on this node's session, then call
    :meth:`NodeCore.query_served` with the replies."""

    ticket: Served
    key: str
    parameters: dict[str, Any]
    timeout_s: float
    cap: int
    """The longest reply payload taken (as a put's on a key of the reply's bits); a longer
    one is an unusable reply, ``too_large``."""


@dataclass(frozen=True)
class QueryAnswer:
    """Asking side: one reply ``value`` for the gets waiting on ``ticket``, on ``key``."""

    ticket: Ticket
    key: str
    value: Any
    encoding: str


@dataclass(frozen=True)
class OverIp:
    """Asking side: the server is reachable over IP, so nothing crosses the water. ``key``: the
    key its bridge would get there (``local_key``). Where that is the asked key, Zenoh routes
    the get to the server's applications itself and this bridge answers nothing (at once);
    elsewhere the runtime gets ``key`` over IP and hands the replies on, as they came."""

    key: str


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
    if mission.links is not None or any(n.routes for n in mission.nodes.values()):
        return round(LOCAL_GET_S + round_trip_s(Network(mission), asker, server), 3)
    total = LOCAL_GET_S
    for node in (asker, server):
        worst = mac_report(mission, node, None).worst_interval_s
        total += (worst if worst is not None else UNBOUNDED_TURN_S) + (
            frame_time_s(mission, node) or 0.0)
    return round(total, 3)


def left_step_s(mission: Mission, spec: QuerySpec) -> float:
    """One step of the remaining time a request carries: the query's longest deadline over
    its askers and servers, in ``2**deadline_bits - 1`` steps (both ends compute the same)."""
    longest = max((deadline_s(mission, spec, a, s) for a in spec.askers for s in spec.servers
                   if s != a), default=0.0)
    return longest / ((1 << spec.deadline_bits) - 1) if spec.deadline_bits else 0.0


def retry_s(mission: Mission, asker: str, server: str) -> float:
    """How long after sending a request the asker waits before repeating it: the earliest a
    reply could be back (its frame and the server's; with several links or routes, half the
    longest round trip)."""
    if mission.links is not None or any(n.routes for n in mission.nodes.values()):
        return round(round_trip_s(Network(mission), asker, server) / 2, 3)
    return round(sum(frame_time_s(mission, n) or 0.0 for n in (asker, server)), 3)


@dataclass
class Open:
    """A query open at the asking node: its request, when it last went out, the replies."""

    ticket: Ticket
    key: str
    packed: int
    deadline: float
    retry_s: float
    sent_at: float | None = None
    released: int = 0  # replies handed on, in index order
    held: dict[int, Any] = field(default_factory=dict)  # arrived ahead of a missing one
    count: int | None = None  # known once the last reply (or "done") arrived
    cut: bool = False  # the deadline is the caller's, before the query's own

    def due_at(self) -> float | None:
        """When the request is next due: now if never sent, else once a reply is late."""
        if self.sent_at is None:
            return float("-inf")
        return self.sent_at + self.retry_s


@dataclass
class Answered:
    """A request served here, kept for its repeats: the reply entries (None while the local
    get runs) until ``expires``."""

    request: dict[str, Any]
    expires: float
    replies: tuple[int, ...] | None = None


@dataclass
class Queries:
    """The queries of one node, asking and serving. ``repeats`` false: each request goes
    once (the behaviour before repeats; benches compare against it)."""

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
    repeated: int = 0  # requests sent again
    duplicates: int = 0  # replies or requests heard again (dropped, or served from answers)
    cache: dict[str, tuple[Any, str, float]] = field(default_factory=dict)
    answers: dict[Served, Answered] = field(default_factory=dict)
    repeats: bool = True
    answers_kept: int = ANSWERS_KEPT
    explain: Callable[[str, float], str | None] | None = None
    """Where the route to a server breaks (nodes behind relays): added to a timeout."""
    drop: Callable[[str, str, float, str], None] | None = None
    """``(key, reason, now, cause)``: a get or a reply that cannot be used, counted and told
    as the put path does (the node's ``drop_payload``)."""
    told_left_out: Callable[[str, list[str], float], None] | None = None
    """``(key, fields, now)``: fields of a get no request field carries (as a put's)."""
    surfacing: Surfacing | None = None
    """The peers reachable over IP (set by the node): gets to them do not cross the water."""

    def __post_init__(self) -> None:
        codecs = self.table.query_codecs
        self.requests = {c.spec.index: c for c in codecs if not c.reply}
        self.reply_codecs = {c.spec.index: c for c in codecs if c.reply}
        self._qid = -1  # the last query id used
        self._cooling: dict[int, float] = {}  # query id -> when it may be used again
        self._steps = {s.index: left_step_s(self.mission, s) for s in self.table.queries
                       if s.deadline_bits}
        self._serve_until: dict[Served, float] = {}  # a carried deadline, at the server
        self._read = {s.index: schema_tree(s.request.json_schema()) for s in self.table.queries}
        """The names each query's request fields read (to tell those a get gives beside)."""

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

    def _drop(self, key: str, reason: str, now: float, cause: str) -> None:
        if self.drop is not None:
            self.drop(key, reason, now, cause)

    def clamped(self) -> dict[str, dict[str, int]]:
        """Reply values clamped into their field's range so far (sent, but counted), per
        reply entry (``!<name>``) then field path; only fields that clamped some."""
        return {f"!{s.name}": fields for s in self.table.queries
                if (fields := {p: n for p, n in s.reply.clamped.items() if n})}

    # -- asking ------------------------------------------------------------------------------

    def refuse(self, key: str, cause: str, reason: str, now: float) -> str:
        """A get on asked ``key`` refused before it is asked (``cause``: ``too_large``,
        ``undecodable`` or ``unfit``): counted and told, as a put's payload; its reply error."""
        found = self.spec_for(key)
        name = found[0].name if found is not None else key
        self.dropped[name] += 1
        self._drop(key, reason, now, cause)
        return f"query {name!r}: {reason}"

    def ask(self, spec: QuerySpec, server: str, parameters: Any, now: float,
            link: LinkState | None, until: float | None = None,
            refused: str | None = None, wildcard: bool = False) -> Ticket | str | OverIp:
        """Open (or join) a query; returns its ticket, or why it ends at once, or
        :class:`OverIp` while the server is reachable over IP (a query opened before it
        surfaced goes on across the water: its get reached no application over IP). A fresh
        enough latched value (``cached_s``) answers at once, even with the link down.
        ``until``: when the caller stops waiting (None: it waits as long as the query may
        take); ``refused``: why the route to the server is broken (nodes behind relays).
        Parameters no request field reads are told (``told_left_out``), but not a wildcard
        get's: those are for whichever of its queries read them."""
        if self.surfacing is not None and server in self.surfacing.reachable:
            self.surfacing.gets_over_ip += 1
            return OverIp(spec.served_key(server))
        if refused is not None:
            return refused
        if until is not None and until <= now:
            self.failed += 1
            return f"query {spec.name!r}: the caller's deadline has passed, not sent"
        key = spec.asked_key(server)
        if not wildcard and isinstance(parameters, dict) and self.told_left_out is not None \
                and (extra := left_out(parameters, self._read[spec.index])):
            self.told_left_out(key, extra, now)
        hit = self.cache.get(key)
        if spec.cached_s is not None and hit is not None and now - hit[2] <= spec.cached_s:
            self.cached += 1
            ticket = (spec.index, server, -self.cached)  # never an acoustic query id
            self.outputs += [QueryAnswer(ticket, spec.asked_key(server), hit[0], hit[1]),
                             QueryEnd(ticket)]
            return ticket
        if link is not LinkState.UP and link is not LinkState.DEGRADED:
            self.failed += 1
            return f"{server}: acoustic link down, query {spec.name!r} not sent"
        if spec.deadline_bits and isinstance(parameters, dict):
            parameters = {**parameters, LEFT: 0}  # the time left goes in as it is sent
        try:
            packed = spec.request.pack(parameters if spec.request.fields else {})
        except (EncodeError, TypeError, ValueError, KeyError) as exc:
            self.failed += 1
            return self.refuse(key, "unfit", f"malformed parameters: {exc}", now)
        bound = now + deadline_s(self.mission, spec, self.node, server)
        deadline = bound if until is None else min(bound, until)
        for item in self.open.values():
            if item.ticket[:2] == (spec.index, server) and item.packed == packed:
                if deadline > item.deadline:  # the latest caller's
                    item.deadline, item.cut = deadline, deadline < bound
                return item.ticket  # a concurrent get with the same request: share it
        if len(self.open) >= self.mission.max_open_queries:
            self.failed += 1
            return (f"{self.node}: {self.mission.max_open_queries} acoustic queries already "
                    "open (max_open_queries)")
        ticket = (spec.index, server, self._next_qid(now))
        self.open[ticket] = Open(ticket, spec.asked_key(server), packed, deadline,
                                 retry_s(self.mission, self.node, server),
                                 cut=deadline < bound)
        self.asked += 1
        return ticket

    def _next_qid(self, now: float) -> int:
        """The next query id in turn that is neither open nor cooling (else the next one not
        open: more queries than ids in one deadline)."""
        used = {t[2] for t in self.open}
        turn = [(self._qid + k) % (1 << QID_BITS) for k in range(1, (1 << QID_BITS) + 1)]
        free = [q for q in turn if q not in used]
        qid = next((q for q in free if self._cooling.get(q, now) <= now), free[0])
        self._cooling.pop(qid, None)
        self._qid = qid
        return qid

    def candidates(self, now: float) -> list[Candidate]:
        """Requests due (new, or repeated while replies are missing) and replies owed."""
        out: list[Candidate] = []
        late: list[Open] = []
        for item in self.open.values():
            due = item.due_at()
            if due is not None and (item.sent_at is None or self.repeats) and due <= now:
                codec = self.requests[item.ticket[0]]
                packed = self._with_time_left(item, now)
                if packed is None:  # past the deadline, or less than a step left (the server
                    late.append(item)  # would drop it): ended now, not sent
                    continue
                server = self.table.nodes.index(item.ticket[1])
                bits = codec.pack(item.ticket[2], server, packed)
                out.append(Candidate(codec, None, Extra(codec, bits, self._marker(item),
                                                        item.ticket[1]), item.ticket[2]))
        for item in late:
            self._end(item.ticket, self._late(item, now))
        if self._serve_until:
            self._drop_late_replies(now)
        for n, (codec, bits, served) in enumerate(self.replies):
            out.append(Candidate(codec, None, Extra(codec, bits, self._unqueue(served, bits),
                                                    served[1]), n))
        return out

    def _with_time_left(self, item: Open, now: float) -> int | None:
        """The request's fields with the time left until ``item``'s deadline (a query with
        ``deadline_bits``: in whole steps, None when not one is left)."""
        step = self._steps.get(item.ticket[0])
        if step is None:
            return item.packed if now < item.deadline else None
        spec = self.table.queries[item.ticket[0]]
        steps = min(int((item.deadline - now) / step), (1 << spec.deadline_bits) - 1)
        return (item.packed & ~((1 << spec.deadline_bits) - 1)) | steps if steps > 0 else None

    def _drop_late_replies(self, now: float) -> None:
        """Replies owed to askers whose carried deadline passed are not sent (counted)."""
        late = {t for t, until in self._serve_until.items() if now >= until}
        if late:
            kept = [r for r in self.replies if r[2] not in late]
            self.dropped["expired"] += len(self.replies) - len(kept)
            self.replies = kept
            for ticket in late:
                del self._serve_until[ticket]

    def _marker(self, item: Open) -> Callable[[float], None]:
        def sent(built: float) -> None:
            if item.sent_at is not None:
                self.repeated += 1
            item.sent_at = built
        return sent

    def _unqueue(self, served: Served, bits: int) -> Callable[[float], None]:
        def sent(built: float) -> None:
            self.replies = [r for r in self.replies if not (r[2] == served and r[1] == bits)]
        return sent

    def next_due(self) -> float | None:
        if self.replies:
            return float("-inf")
        return min((t for item in self.open.values() if (t := item.due_at()) is not None
                    and (self.repeats or item.sent_at is None)), default=None)

    def on_reply(self, src: str, codec: QueryCodec, header: tuple[int, ...],
                 values: list[dict[str, Any]] | None, now: float) -> None:
        qid, asker, status, index = header[:4]
        if self.table.nodes[asker] != self.node:
            return  # a reply to somebody else
        ticket = (codec.spec.index, src, qid)
        item = self.open.get(ticket)
        if item is None:
            self.dropped["late_reply"] += 1
            return
        if status == ReplyStatus.FAILED:
            self._end(ticket, failed_reply(src, codec.spec.name, header[4]))
            return
        if status == ReplyStatus.DONE:
            item.count = 0
        elif index < item.released or index in item.held:
            self.duplicates += 1
            return
        else:
            if values is not None:
                item.held[index] = values[0]
            if status == ReplyStatus.LAST:
                item.count = index + 1
        self._release(item, codec.spec.encoding)
        if item.count is not None and item.released >= item.count:
            self.answered += 1
            self._end(ticket, None)

    def _release(self, item: Open, encoding: str, flush: bool = False) -> None:
        """Hand on the replies next in order (``flush``: also those after a missing one)."""
        while item.held and (flush or item.released in item.held):
            index = item.released if item.released in item.held else min(item.held)
            self.outputs.append(QueryAnswer(item.ticket, item.key, item.held.pop(index),
                                            encoding))
            item.released = index + 1

    def _end(self, ticket: Ticket, error: str | None) -> None:
        item = self.open.pop(ticket, None)
        if item is not None:
            if item.held:
                self._release(item, self.table.queries[ticket[0]].encoding, flush=True)
            spec = self.table.queries[ticket[0]]  # the server keeps its answer that long:
            self._cooling[ticket[2]] = item.deadline + deadline_s(
                self.mission, spec, self.node, ticket[1])
        if error is not None:
            self.failed += 1
        self.outputs.append(QueryEnd(ticket, error))

    def expire(self, now: float) -> None:
        """End the queries whose deadline passed; forget answers kept past theirs."""
        for ticket, item in list(self.open.items()):
            if now >= item.deadline:
                self._end(ticket, self._late(item, now))
        for served, answered in list(self.answers.items()):
            if now >= answered.expires:
                del self.answers[served]

    def _late(self, item: Open, now: float) -> str:
        """Why ``item`` ends without all its replies: its deadline passed (and, for a server
        behind relays, where its route breaks)."""
        spec = self.table.queries[item.ticket[0]]
        why = self.explain(item.ticket[1], now) if self.explain is not None else None
        route = f"; {why}" if why else ""
        if item.cut:
            return (f"{item.ticket[1]}: no reply to query {spec.name!r} before the caller's "
                    f"deadline{route}")
        return (f"{item.ticket[1]}: no reply to query {spec.name!r} within "
                f"{deadline_s(self.mission, spec, self.node, item.ticket[1]):g} s "
                + ("(its timeout_s)" if spec.timeout_s else "(the MAC's bound)") + route)

    # -- serving -----------------------------------------------------------------------------

    def on_request(self, src: str, codec: QueryCodec, header: tuple[int, ...],
                   values: list[dict[str, Any]] | None, now: float,
                   sent_at: float | None = None) -> None:
        """A request heard at ``now``, its frame sent at ``sent_at`` (as well as this node
        can tell: the time left it carries counts from then)."""
        qid, server = header[:2]
        spec = codec.spec
        if self.table.nodes[server] != self.node or src not in spec.askers:
            return
        ticket = (spec.index, src, qid)
        request = values[0] if values else {}
        timeout = LOCAL_GET_S
        if spec.deadline_bits:
            request = dict(request)
            until = min(now, sent_at if sent_at is not None else now) \
                + request.pop(LEFT, 0) * self._steps[spec.index]
            if until <= now:
                self.dropped["expired"] += 1  # the caller has given up: not served
                return
            self._serve_until[ticket] = until
            timeout = min(timeout, until - now)
        kept = self.answers.get(ticket)
        if kept is not None and kept.request == request and now < kept.expires:
            self.duplicates += 1
            if kept.replies is not None:  # answer again from what the get gave
                self._queue(ticket, kept.replies)
            return  # else the local get still runs: its replies will go out
        self.answers.pop(ticket, None)
        while len(self.answers) >= self.answers_kept:
            del self.answers[next(iter(self.answers))]
        self.answers[ticket] = Answered(
            request, now + deadline_s(self.mission, spec, src, self.node))
        self.outputs.append(LocalGet(ticket, spec.served_key(self.node), request, timeout,
                                     payload_cap(spec.reply.bits)))

    def served(self, ticket: Served, values: list[Any], now: float,
               unusable: Sequence[tuple[str, str]] = ()) -> None:
        """The local get of ``ticket`` ended at ``now`` with ``values`` and the replies it could
        not use, ``(cause, text)`` each (cause :data:`ERROR_REPLY`, :data:`UNDECODABLE`, or
        :data:`TIMED_OUT` when no queryable answered in time). Each reply that cannot be sent
        is counted and told; with none sent, the failed reply says why."""
        spec = self.table.queries[ticket[0]]
        codec = self.reply_codecs[spec.index]
        asker = self.table.nodes.index(ticket[1])
        reasons = {_REASONS[cause] for cause, _ in unusable}
        for cause, text in unusable:
            if cause != TIMED_OUT:  # (no reply came: nothing dropped)
                self._unusable(spec, cause, text, now)
        packed: list[int] = []
        for value in values[:spec.max_replies]:
            try:
                packed.append(spec.reply.pack(value))
            except (EncodeError, TypeError, ValueError, KeyError) as exc:
                self._unusable(spec, "unfit", str(exc), now)
                reasons.add(FailReason.NOT_USABLE)
        if reasons and not packed:
            reason = min(reasons)  # the app's own error first, then replies unusable
            code = reason if reason < 1 << spec.reply.bits else FailReason.UNSAID
            entries = [codec.pack(ticket[2], asker, code, ReplyStatus.FAILED)]
        elif not packed:
            entries = [codec.pack(ticket[2], asker, 0, ReplyStatus.DONE)]
        else:
            entries = [codec.pack(ticket[2], asker, bits, ReplyStatus.LAST
                                  if i == len(packed) - 1 else ReplyStatus.VALUE, i)
                       for i, bits in enumerate(packed)]
        if (kept := self.answers.get(ticket)) is not None:
            kept.replies = tuple(entries)
        self._queue(ticket, entries)

    def _unusable(self, spec: QuerySpec, cause: str, text: str, now: float) -> None:
        """A reply of the local get for ``spec`` that cannot be sent: counted and told."""
        self.dropped[f"{spec.name}:reply"] += 1
        self._drop(spec.served_key(self.node), f"a reply to query {spec.name!r}: {text}", now,
                   cause)

    def _queue(self, ticket: Served, entries: tuple[int, ...] | list[int]) -> None:
        """Owe the asker ``entries`` (once each: a queued one is not queued twice)."""
        codec = self.reply_codecs[ticket[0]]
        for bits in entries:
            if not any(r[2] == ticket and r[1] == bits for r in self.replies):
                self.replies.append((codec, bits, ticket))

    def remember(self, key: str, value: Any, encoding: str, taken: float) -> None:
        """A latched channel's value this node published on ``key``, taken at the source at
        ``taken``; None: the key was deleted."""
        if value is None:
            self.cache.pop(key, None)
        else:
            self.cache[key] = (value, encoding, taken)

    def take(self) -> list[LocalGet | QueryAnswer | QueryEnd]:
        out, self.outputs = self.outputs, []
        return out

    def snapshot(self) -> dict[str, Any]:
        return {"open": [{"query": self.table.queries[t[0]].name, "server": t[1],
                          "deadline": item.deadline} for t, item in self.open.items()],
                "asked": self.asked, "answered": self.answered, "failed": self.failed,
                "cached": self.cached, "repeated": self.repeated,
                "duplicates": self.duplicates, "answers_kept": len(self.answers),
                "dropped": dict(self.dropped), "replies_owed": len(self.replies)}
