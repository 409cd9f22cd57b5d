"""Queries across the water, the Zenoh side: queryables at asking nodes, local gets at serving
nodes. The core (:mod:`bridge.core.queries`) decides; this module only talks to Zenoh.

Asking node: a queryable on each asked key (``auv1/info``). A get's selector parameters
(``?detail=2``; numbers, ``true``/``false`` and text; dotted names nest) and its msgpack/JSON
payload become the request's fields (:func:`get_fields`: a field given in both with two values
is refused, so is a payload over a put's cap for the request's bits); ``_timeout=<s>`` says
how long the caller waits (Zenoh does not tell a queryable the getter's timeout): the query is
not sent, or ends, once that has passed. Other parameters starting with ``_`` are Zenoh's and
are not request fields. The query object is kept until the core ends the query: each reply is
answered on the asked key, then the query is dropped (finalised); an error ends it with
``reply_err`` and a plain-text reason.
Several replies on one key reach an application only with ``consolidation=NONE`` (Zenoh's
default keeps the latest per key).

A wildcard get (``auv1/**``) meets the queryable of every asked key it matches: the first of
them (in key order) answers for all. It asks each matched query that needs no parameters, or
whose parameters the selector gives, and ends with one reply error naming the others.

While the serving node is reachable over IP (the core says
:class:`~bridge.core.queries.OverIp`), nothing crosses the water: on a query whose
``local_key`` is the asked key, Zenoh routes the get to the server's applications itself and
this queryable answers nothing, at once (a get with ``consolidation=NONE`` waits for every
queryable's end: holding it open would hold the caller); on another ``local_key``, the bridge
gets that key over IP and answers each reply on the asked key, as it came (unquantised).

Serving node: a :class:`~bridge.core.queries.LocalGet` becomes ``session.get`` on the local key
with the request's parameters and ``consolidation=NONE``, so every reply of every queryable
counts (up to the query's ``max_replies``); replies are decoded (msgpack or JSON) and handed
back to the core when the get ends, with the replies it could not use: reply errors (their
text, cut to :data:`ERROR_TEXT` characters, for the server's log), undecodable replies, and the
get's own timeout.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import zenoh

from bridge.core.node import NodeCore
from bridge.core.queries import (
    ERROR_REPLY,
    LOCAL_GET_S,
    TIMED_OUT,
    TOO_LARGE,
    UNDECODABLE,
    LocalGet,
    OverIp,
    QueryAnswer,
    QueryEnd,
    Ticket,
)
from bridge.errors import DecodeError
from bridge.wire.payloads import decode_payload, encode_payload, payload_cap

log = logging.getLogger("zab.queries")

CALLER_TIMEOUT = "_timeout"
"""The selector parameter in which a get says how long its caller waits, seconds."""
ERROR_TEXT = 200
"""Characters of a queryable's reply error kept for the serving node's log."""


class GetRefused(ValueError):
    """A get that cannot be asked; ``cause`` as a dropped put's (``too_large``,
    ``undecodable``, ``unfit``)."""

    def __init__(self, cause: str, reason: str) -> None:
        super().__init__(reason)
        self.cause = cause


def parse_parameters(text: str) -> dict[str, Any]:
    """``detail=2;mode=full;pos.x=1.5`` → ``{"detail": 2, "mode": "full", "pos": {"x": 1.5}}``."""
    out: dict[str, Any] = {}
    for part in filter(None, text.split(";")):
        name, _, raw = part.partition("=")
        value: Any = raw
        if raw in ("true", "false"):
            value = raw == "true"
        else:
            for kind in (int, float):
                try:
                    value = kind(raw)
                    break
                except ValueError:
                    continue
        target = out
        *parents, leaf = name.split(".")
        for parent in parents:
            target = target.setdefault(parent, {})
            if not isinstance(target, dict):
                raise ValueError(f"parameter {name!r} clashes with {parent!r}")
        target[leaf] = value
    return out


def _merged(selector: dict[str, Any], payload: dict[str, Any], prefix: str = ""
            ) -> dict[str, Any]:
    """``payload`` with the fields of ``selector`` added; ``GetRefused`` for a field given in
    both with different values (Zenoh's own ``_`` parameters: the selector's)."""
    out = dict(payload)
    for name, value in selector.items():
        mine = out.get(name)
        if name not in out or str(name).startswith("_") or mine == value:
            out[name] = value
        elif isinstance(value, dict) and isinstance(mine, dict):
            out[name] = _merged(value, mine, f"{prefix}{name}.")
        else:
            raise GetRefused("unfit", f"parameter {prefix + str(name)!r} given twice, "
                                      f"{value!r} in the selector and {mine!r} in the payload: "
                                      "give it once")
    return out


def get_fields(parameters: str, payload: bytes | zenoh.ZBytes | None, encoding: str,
               cap: int) -> Any:
    """A get's request fields: its selector ``parameters`` and its ``payload`` (msgpack or
    JSON, at most ``cap`` bytes, as a put on an input key: a longer one is not copied out of
    Zenoh), joined. Raises ``GetRefused``."""
    try:
        selector = parse_parameters(parameters)
    except ValueError as exc:
        raise GetRefused("unfit", f"malformed parameters: {exc}") from None
    if payload is None:
        return selector
    if len(payload) > cap:
        raise GetRefused("too_large", f"a get payload of {len(payload)} bytes, over this "
                                      f"query's cap of {cap}")
    try:
        value = decode_payload(bytes(payload), encoding)
    except DecodeError as exc:
        raise GetRefused("undecodable", f"malformed parameters: {exc}") from None
    if not selector:
        return value
    if not isinstance(value, dict):
        raise GetRefused("unfit", "malformed parameters: a payload that is not a map, and "
                                  "selector parameters")
    return _merged(selector, value)


def format_parameters(values: dict[str, Any], prefix: str = "") -> str:
    """The inverse of :func:`parse_parameters` (for the serving node's local get)."""
    parts = []
    for name, value in values.items():
        path = f"{prefix}{name}"
        if isinstance(value, dict):
            parts.append(format_parameters(value, path + "."))
        else:
            parts.append(f"{path}={str(value).lower() if isinstance(value, bool) else value}")
    return ";".join(p for p in parts if p)


def has_parameters(values: dict[str, Any], paths: tuple[str, ...]) -> bool:
    """Whether ``values`` holds every dotted path of ``paths``."""
    for path in paths:
        item: Any = values
        for part in path.split("."):
            if not isinstance(item, dict) or part not in item:
                return False
            item = item[part]
    return True


WAITING_GETS = 64
"""Zenoh gets waiting for the loop at a time; under a flood the oldest is refused at once."""

@dataclass
class Waiting:
    """A Zenoh get held open until every acoustic query it asked, and every get it made over
    IP (``forwards``), has ended."""

    query: zenoh.Query
    tickets: set[Ticket] = field(default_factory=set)
    errors: list[str] = field(default_factory=list)
    forwards: int = 0

    @property
    def over(self) -> bool:
        return not self.tickets and not self.forwards


class QueryBridge:
    """The Zenoh half of one node's queries."""

    def __init__(self, session: zenoh.Session, core: NodeCore, lock: threading.RLock,
                 clock: Callable[[], float], changed: Callable[[], None],
                 loop: asyncio.AbstractEventLoop,
                 taken_at: Callable[[str], zenoh.Timestamp | None] = lambda key: None) -> None:
        """``core``, used under ``lock``, at the time ``clock`` tells; ``changed``: the core
        has outputs to carry out and may have something due (on the loop); ``taken_at``:
        the timestamp of the latched value this node last published on a key (a reply from
        the cache carries it)."""
        self.session = session
        self.taken_at = taken_at
        self.core = core
        self.lock = lock
        self.clock = clock
        self.changed = changed
        self.loop = loop
        self.waiting: dict[Ticket, list[Waiting]] = {}
        self.entities: list[Any] = []
        self.refused = 0
        """Gets ended at once because :data:`WAITING_GETS` others waited for the loop."""
        self._gets: deque[tuple[Waiting, list[str], Any, bool]] = deque()
        self._lock = threading.Lock()
        self._woken = False  # a call to _take_gets is on its way to the loop
        assert core.queries is not None
        self.asked = core.queries.asked_keys()
        for key in self.asked:
            self.entities.append(session.declare_queryable(
                key, functools.partial(self._from_zenoh, key=key)))

    def _from_zenoh(self, query: zenoh.Query, key: str) -> None:
        """Zenoh thread: read the get's parameters, hand it to the loop (a wildcard get only
        from the first asked key it matches)."""
        asked = str(query.key_expr)
        keys = [key]
        if asked != key:  # a wildcard get: every asked key it matches, answered once
            selector = zenoh.KeyExpr(asked)
            keys = sorted(k for k in self.asked if selector.intersects(zenoh.KeyExpr(k)))
            if keys[0] != key:
                query.drop()
                return
        cap = payload_cap(max(self.asked[k][0].request.bits for k in keys))
        try:
            params = get_fields(str(query.parameters), query.payload, str(query.encoding), cap)
        except GetRefused as exc:
            params = exc
        self._hand_off((Waiting(query), keys, params, asked != key))

    def _hand_off(self, get: tuple[Waiting, list[str], Any, bool]) -> None:
        """Zenoh thread: ``get`` waits for the loop, with at most :data:`WAITING_GETS` others;
        under a flood of gets the oldest waiting one is ended at once with an error and
        counted (``refused``), so memory stays bounded however fast gets come."""
        with self._lock:
            oldest = self._gets.popleft() if len(self._gets) >= WAITING_GETS else None
            if oldest is not None:
                self.refused += 1
            self._gets.append(get)
            wake, self._woken = not self._woken, True
        if oldest is not None:
            self._finish(oldest[0], "too many gets waiting at this bridge: try again")
        if wake:
            with contextlib.suppress(RuntimeError):  # the loop has closed: the node is gone
                self.loop.call_soon_threadsafe(self._take_gets)

    def _take_gets(self) -> None:
        """On the loop: every get waiting, in the order they came."""
        with self._lock:
            gets = list(self._gets)
            self._gets.clear()
            self._woken = False
        for get in gets:
            self._ask(*get)

    def _ask(self, waiting: Waiting, keys: list[str], params: Any, wildcard: bool) -> None:
        core = self.core
        with self.lock:
            now = self.clock()
            if isinstance(params, GetRefused):
                assert core.queries is not None
                self._finish(waiting, core.queries.refuse(keys[0], params.cause, str(params),
                                                          now))
                return
            until = None
            if isinstance(params, dict):
                timeout = params.get(CALLER_TIMEOUT)
                until = now + timeout if isinstance(timeout, int | float) else None
                params = {k: v for k, v in params.items() if not str(k).startswith("_")}
            unasked = []
            for key in keys:
                found = core.queries.spec_for(key) if core.queries is not None else None
                if wildcard and found is not None and not has_parameters(
                        params, found[0].parameters):
                    unasked.append(f"{key} needs {', '.join(found[0].parameters)}")
                    continue
                ticket = core.ask(key, params, now, until, wildcard)
                if isinstance(ticket, str):
                    waiting.errors.append(ticket)
                elif isinstance(ticket, OverIp):  # the server answers over IP
                    if ticket.key != key:  # (else Zenoh routes the get there: nothing to do)
                        self._over_ip(waiting, key, ticket.key, params,
                                      LOCAL_GET_S if until is None else until - now)
                else:
                    waiting.tickets.add(ticket)
                    self.waiting.setdefault(ticket, []).append(waiting)
            if unasked:
                waiting.errors.append(f"a wildcard get does not ask queries that need "
                                      f"parameters it does not give: {'; '.join(unasked)} "
                                      f"(get each on its key with them)")
            if waiting.over:
                self._finish(waiting, None)
        self.changed()  # a request is due at the next opportunity

    def _over_ip(self, waiting: Waiting, asked: str, served: str, params: Any,
                 timeout: float) -> None:
        """Get ``served`` over IP (the server is reachable there) and answer each reply on
        ``asked``, as it came; ``waiting`` ends with the last of its gets."""
        waiting.forwards += 1

        def on_reply(reply: zenoh.Reply) -> None:  # Zenoh thread
            try:
                if reply.ok is not None:
                    sample = reply.ok
                    waiting.query.reply(asked, sample.payload, encoding=sample.encoding,
                                        attachment=sample.attachment, timestamp=sample.timestamp)
                elif reply.err is not None:
                    waiting.errors.append(reply.err.payload.to_string())
            except zenoh.ZError as exc:  # the getter gave up already
                log.debug("reply refused: %s", exc)

        def done() -> None:  # Zenoh thread
            with contextlib.suppress(RuntimeError):  # the loop has closed: the node is gone
                self.loop.call_soon_threadsafe(self._forwarded, waiting)

        text = format_parameters(params) if isinstance(params, dict) else ""
        self.session.get(served + (f"?{text}" if text else ""),
                         zenoh.handlers.Callback(on_reply, done),
                         consolidation=zenoh.ConsolidationMode.NONE, timeout=max(timeout, 0.0))

    def _forwarded(self, waiting: Waiting) -> None:
        """On the loop: one of ``waiting``'s gets over IP ended."""
        waiting.forwards -= 1
        if waiting.over:
            self._finish(waiting, None)

    @staticmethod
    def _finish(waiting: Waiting, error: str | None) -> None:
        """End ``waiting``'s get: one reply error with every reason, then finalised."""
        errors = [*waiting.errors, *([error] if error is not None else [])]
        try:
            if errors:
                waiting.query.reply_err("; ".join(errors).encode())
            waiting.query.drop()
        except zenoh.ZError as exc:  # the getter gave up already
            log.debug("query already finished: %s", exc)

    def handle(self, output: object) -> bool:
        """Carry out a query output of the core; False if it is not one."""
        if isinstance(output, QueryAnswer):
            payload, enc = encode_payload(output.value, output.encoding)
            cached = output.ticket[2] < 0  # answered from the latched value
            stamp = self.taken_at(output.key) if cached else self.session.new_timestamp()
            for waiting in self.waiting.get(output.ticket, []):
                try:
                    waiting.query.reply(output.key, payload, encoding=zenoh.Encoding(enc),
                                        timestamp=stamp)
                except zenoh.ZError as exc:
                    log.debug("reply refused: %s", exc)
            return True
        if isinstance(output, QueryEnd):
            for waiting in self.waiting.pop(output.ticket, []):
                waiting.tickets.discard(output.ticket)
                if output.error is not None:
                    waiting.errors.append(output.error)
                if waiting.over:
                    self._finish(waiting, None)
            return True
        if isinstance(output, LocalGet):
            self._local_get(output)
            return True
        return False

    def _local_get(self, request: LocalGet) -> None:
        session = self.session
        values: list[Any] = []
        unusable: list[tuple[str, str]] = []
        ends = time.monotonic() + request.timeout_s

        def on_reply(reply: zenoh.Reply) -> None:
            if reply.ok is not None:
                sample = reply.ok
                if (size := len(sample.payload)) > request.cap:  # (not copied out of Zenoh)
                    unusable.append((TOO_LARGE, f"{size} bytes, over the cap of {request.cap}"))
                    return
                try:
                    values.append(decode_payload(sample.payload.to_bytes(), str(sample.encoding)))
                except DecodeError as exc:
                    unusable.append((UNDECODABLE, str(exc)))
            elif reply.err is not None:
                text = reply.err.payload.to_bytes()[:4 * ERROR_TEXT].decode(errors="replace")
                # Zenoh's own error at the get's timeout, or an application's of that text
                timed_out = text == "Timeout" and time.monotonic() >= ends - 0.05
                unusable.append((TIMED_OUT, text) if timed_out else (
                    ERROR_REPLY, f"an error reply: {text[:ERROR_TEXT]!r}"))

        def done() -> None:
            self.loop.call_soon_threadsafe(self._served, request, list(values), list(unusable))

        params = format_parameters(request.parameters)
        selector = request.key + (f"?{params}" if params else "")
        session.get(selector, zenoh.handlers.Callback(on_reply, done),
                    consolidation=zenoh.ConsolidationMode.NONE,
                    timeout=request.timeout_s)

    def _served(self, request: LocalGet, values: list[Any],
                unusable: list[tuple[str, str]]) -> None:
        with self.lock:
            self.core.query_served(request.ticket, values, self.clock(), unusable)
        self.changed()

    def close(self) -> None:
        """End every get still waiting (the bridge stops)."""
        for ticket in list(self.waiting):
            for waiting in self.waiting.pop(ticket):
                if waiting.tickets:
                    waiting.tickets.clear()
                    self._finish(waiting, "the bridge is stopping")
