"""Queries across the water, the Zenoh side: queryables at asking nodes, local gets at serving
nodes. The core (:mod:`bridge.core.queries`) decides; this module only talks to Zenoh.

Asking node: a queryable on each asked key (``auv1/info``). A get's selector parameters
(``?detail=2``; numbers, ``true``/``false`` and text; dotted names nest) or its msgpack/JSON
payload become the request's fields. The query object is kept until the core ends the query:
each reply is answered on the asked key, then the query is dropped (finalised); an error ends
it with ``reply_err`` and a plain-text reason. Several replies on one key reach an application
only with ``consolidation=NONE`` (Zenoh's default keeps the latest per key).

Serving node: a :class:`~bridge.core.queries.LocalGet` becomes ``session.get`` on the local key
with the request's parameters; replies are decoded (msgpack or JSON) and handed back to the core
when the get ends.
"""

from __future__ import annotations

import asyncio
import functools
import logging
import threading
from collections.abc import Callable
from typing import Any

import zenoh

from bridge.core.node import NodeCore
from bridge.core.queries import LocalGet, QueryAnswer, QueryEnd
from bridge.errors import DecodeError
from bridge.wire.payloads import decode_payload, encode_payload

log = logging.getLogger("zab.queries")


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


class QueryBridge:
    """The Zenoh half of one node's queries."""

    def __init__(self, session: zenoh.Session, core: NodeCore, lock: threading.RLock,
                 clock: Callable[[], float], changed: Callable[[], None],
                 loop: asyncio.AbstractEventLoop) -> None:
        """``core``, used under ``lock``, at the time ``clock`` tells; ``changed``: the core
        has outputs to carry out and may have something due (on the loop)."""
        self.session = session
        self.core = core
        self.lock = lock
        self.clock = clock
        self.changed = changed
        self.loop = loop
        self.waiting: dict[Any, list[zenoh.Query]] = {}
        self.entities: list[Any] = []
        assert core.queries is not None
        for key in core.queries.asked_keys():
            self.entities.append(session.declare_queryable(
                key, functools.partial(self._from_zenoh, key=key)))

    def _from_zenoh(self, query: zenoh.Query, key: str) -> None:
        """Zenoh thread: read the get's parameters, hand it to the loop."""
        try:
            if query.payload is not None:
                params = decode_payload(query.payload.to_bytes(), str(query.encoding))
            else:
                params = parse_parameters(str(query.parameters))
        except (DecodeError, ValueError) as exc:
            params = exc
        self.loop.call_soon_threadsafe(self._ask, query, key, params)

    def _ask(self, query: zenoh.Query, key: str, params: Any) -> None:
        core = self.core
        with self.lock:
            now = self.clock()
            if isinstance(params, Exception):
                spec = core.queries.spec_for(key) if core.queries else None
                if spec is not None and core.queries is not None:
                    core.queries.dropped[spec[0].name] += 1
                self._end([query], f"malformed parameters: {params}")
                return
            ticket = core.ask(key, params, now)
            if isinstance(ticket, str):
                self._end([query], ticket)
            else:
                self.waiting.setdefault(ticket, []).append(query)
        self.changed()  # a request is due at the next opportunity

    @staticmethod
    def _end(queries: list[zenoh.Query], error: str | None) -> None:
        for query in queries:
            try:
                if error is not None:
                    query.reply_err(error.encode())
                query.drop()
            except zenoh.ZError as exc:  # the getter gave up already
                log.debug("query already finished: %s", exc)

    def handle(self, output: object) -> bool:
        """Carry out a query output of the core; False if it is not one."""
        if isinstance(output, QueryAnswer):
            payload, enc = encode_payload(output.value, output.encoding)
            for query in self.waiting.get(output.ticket, []):
                try:
                    query.reply(output.key, payload, encoding=zenoh.Encoding(enc))
                except zenoh.ZError as exc:
                    log.debug("reply refused: %s", exc)
            return True
        if isinstance(output, QueryEnd):
            self._end(self.waiting.pop(output.ticket, []), output.error)
            return True
        if isinstance(output, LocalGet):
            self._local_get(output)
            return True
        return False

    def _local_get(self, request: LocalGet) -> None:
        session = self.session
        values: list[Any] = []
        errors: list[str] = []

        def on_reply(reply: zenoh.Reply) -> None:
            if reply.ok is not None:
                sample = reply.ok
                try:
                    values.append(decode_payload(sample.payload.to_bytes(), str(sample.encoding)))
                except DecodeError as exc:
                    errors.append(str(exc))
            elif reply.err is not None:
                errors.append(reply.err.payload.to_string())

        def done() -> None:
            error = "; ".join(errors) if errors and not values else None
            self.loop.call_soon_threadsafe(self._served, request, list(values), error)

        params = format_parameters(request.parameters)
        selector = request.key + (f"?{params}" if params else "")
        session.get(selector, zenoh.handlers.Callback(on_reply, done),
                    timeout=request.timeout_s)

    def _served(self, request: LocalGet, values: list[Any], error: str | None) -> None:
        with self.lock:
            self.core.query_served(request.ticket, values, error)
        self.changed()

    def close(self) -> None:
        """End every get still waiting (the bridge stops)."""
        for ticket in list(self.waiting):
            self._end(self.waiting.pop(ticket), "the bridge is stopping")
