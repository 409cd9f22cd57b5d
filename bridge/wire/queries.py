"""Queries on the wire: a request entry and a reply entry per query of the mission (pure).

Request ``?<name>``: query id (4 bits, per asking node) + the serving node (its place in the
mission, ⌈log2 N⌉ bits) + the request fields (+ with ``deadline_bits``, the asker's remaining
time in that many bits, last: see :data:`LEFT`). Reply ``!<name>``: query id + the asking node +
status (2 bits: 0 a reply, 1 the last reply, 2 done without a reply, 3 failed at the server) +
the reply's index (⌈log2 max_replies⌉ bits: the last reply's index tells the count) + the reply
fields (zero when the status carries none; a failed reply carries a :class:`FailReason` there
instead, when the fields have room for it). Both may repeat in a frame. An asker repeats a
request until every reply arrived; the index lets it drop duplicates and see what is missing.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import IntEnum
from typing import Any

from bridge.codec import Layout
from bridge.mission.model import Mission, Query

QID_BITS = 4
STATUS_BITS = 2
QUERY_WIRE = 2  # 2: replies carry their index (in the fingerprint: older nodes refuse them)
QUERY_PRIORITY = 1 << 19  # requests and replies go before ordinary channels
LEFT = "_zab_left"
"""The request field (last, so the lowest bits) of a query with ``deadline_bits``: the asker's
remaining time in whole steps, rounded down; 0 means less than one step left."""


class ReplyStatus(IntEnum):
    VALUE = 0
    LAST = 1
    DONE = 2
    FAILED = 3


class FailReason(IntEnum):
    """Why a serving node's local get gave no reply it could send, in the low bits of a failed
    reply's (otherwise unused) fields: no bit more on the air. 0, unsaid, is what a node of
    before these reasons sends, and what is sent when the fields have fewer bits than the
    reason needs."""

    UNSAID = 0
    APP_ERROR = 1  # the queryable answered with a reply error (its text stays at the server)
    NOT_USABLE = 2  # its replies were not msgpack/JSON or did not fit the reply fields
    TIMEOUT = 3  # no queryable answered within the local get's time

    @property
    def code(self) -> str:
        """The reason as the asker's reply error names it: ``app-error``, ``not-usable``…"""
        return self.name.lower().replace("_", "-")


@dataclass(frozen=True)
class QuerySpec:
    """A compiled query: who asks whom, on which keys, with which layouts."""

    index: int
    name: str
    key: str
    local_key: str
    servers: tuple[str, ...]
    askers: tuple[str, ...]
    request: Layout
    reply: Layout
    encoding: str
    max_replies: int
    timeout_s: float | None
    cached_s: float | None = None
    deadline_bits: int = 0

    @property
    def parameters(self) -> tuple[str, ...]:
        """The request fields an application gives (the carried deadline is the bridge's)."""
        return tuple(f.path for f in self.request.fields if f.path != LEFT)

    def asked_key(self, server: str) -> str:
        return self.key.format(node=server)

    def served_key(self, server: str) -> str:
        return self.local_key.format(node=server)

    @property
    def index_bits(self) -> int:
        """Bits of a reply's index: enough for ``max_replies`` (none for a single reply)."""
        return (self.max_replies - 1).bit_length()

    def describe(self) -> list[object]:
        return [self.name, list(self.servers), list(self.askers),
                [f"{f.path}:{f.describe()}" for f in self.request.fields],
                [f"{f.path}:{f.describe()}" for f in self.reply.fields], self.max_replies,
                QUERY_WIRE]  # (a carried deadline is among the request fields)


@dataclass(frozen=True)
class QueryCodec:
    """The request (``reply`` false) or reply entry of one query."""

    index: int
    spec: QuerySpec
    reply: bool
    node_bits: int
    repeatable: bool = True
    priority: int = QUERY_PRIORITY

    @property
    def name(self) -> str:
        return ("!" if self.reply else "?") + self.spec.name

    @property
    def layout(self) -> Layout:
        return self.spec.reply if self.reply else self.spec.request

    @property
    def index_bits(self) -> int:
        return self.spec.index_bits if self.reply else 0

    @property
    def wire_bits(self) -> int:
        return (QID_BITS + self.node_bits + (STATUS_BITS if self.reply else 0)
                + self.index_bits + self.layout.bits)

    def pack(self, qid: int, node: int, packed: int, status: int = 0, index: int = 0) -> int:
        n = (qid << self.node_bits) | node
        if self.reply:
            n = (((n << STATUS_BITS) | status) << self.index_bits) | index
        return (n << self.layout.bits) | packed

    def unpack(self, n: int) -> tuple[int, int, int, int, int]:
        """``(qid, node, status, index, packed fields)``; status and index are 0 for a
        request."""
        packed = n & ((1 << self.layout.bits) - 1)
        n >>= self.layout.bits
        status = index = 0
        if self.reply:
            index, n = n & ((1 << self.index_bits) - 1), n >> self.index_bits
            status, n = n & ((1 << STATUS_BITS) - 1), n >> STATUS_BITS
        return n >> self.node_bits, n & ((1 << self.node_bits) - 1), status, index, packed


Match = Callable[[str | Sequence[str], Sequence[str]], tuple[str, ...]]


def compile_query(index: int, query: Query, mission: Mission, match: Match) -> QuerySpec:
    """``match(pattern, nodes)`` resolves node patterns (``bridge.wire.channels.match_nodes``)."""
    nodes = tuple(mission.nodes)
    servers = match(query.serve, nodes)
    askers = (match(query.ask, nodes) if query.ask is not None
              else tuple(n for n in nodes if n not in servers))
    askers = tuple(a for a in askers if any(s != a for s in servers))
    request: list[Any] = list(query.request)
    if query.deadline_bits:
        request.append({"field": LEFT, "type": "int", "min": 0,
                        "max": (1 << query.deadline_bits) - 1})
    return QuerySpec(
        index=index, name=query.name, key=query.key, local_key=query.local_key or query.key,
        servers=servers, askers=askers,
        request=Layout.from_fields(request, on_out_of_range="reject"),
        reply=Layout.from_fields(query.reply, on_out_of_range="clamp"),
        encoding=query.encoding, max_replies=query.max_replies, timeout_s=query.timeout_s,
        cached_s=query.cached_s, deadline_bits=query.deadline_bits)


def query_codecs(first_index: int, specs: Sequence[QuerySpec],
                 n_nodes: int) -> tuple[QueryCodec, ...]:
    """Request then reply codec of each query, indexed from ``first_index``."""
    node_bits = (n_nodes - 1).bit_length()
    out: list[QueryCodec] = []
    for spec in specs:
        for reply in (False, True):
            out.append(QueryCodec(first_index + len(out), spec, reply, node_bits))
    return tuple(out)
