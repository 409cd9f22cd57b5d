"""Zenoh queries played on the virtual clock: applications' gets and queryables for
:class:`~bridge.runtime.virtual_fleet.FastFleet` (``zab sim --fast``), around the same core."""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

from bridge.core.interest import intersects
from bridge.core.loaded import LoadedMission
from bridge.core.node import NodeCore
from bridge.core.queries import LocalGet, OverIp, QueryAnswer, QueryEnd


class Fleet(Protocol):
    """What the queries need of the fleet they play in
    (:class:`~bridge.runtime.virtual_fleet.FastFleet`)."""

    now: float
    loaded: LoadedMission
    cores: dict[str, NodeCore]

    def call_at(self, t: float, fn: Callable[[], None]) -> None: ...

    def collect_and_replan(self, node: str) -> None: ...

Answer = Callable[[dict[str, Any]], list[Any]]


@dataclass
class GetResult:
    """What an application's get received: replies (key, value, time), then its end."""

    node: str
    key: str
    asked_at: float
    replies: list[tuple[str, Any, float]] = field(default_factory=list)
    error: str | None = None
    ended_at: float | None = None

    @property
    def done(self) -> bool:
        return self.ended_at is not None


QUERY_PERIOD_S = 30.0
"""How often a synthetic operator asks each query of a mission in ``zab sim --fast``."""



def _answer(value: Callable[[Any], Any], layout: Any, params: dict[str, Any]) -> list[Any]:
    """A synthetic queryable's reply: a valid value of the reply's layout."""
    return [value(layout)]


class VirtualQueries:
    """Queryables and pending gets of the applications of a virtual fleet."""

    def __init__(self, fleet: Fleet) -> None:
        self.fleet = fleet
        self.queryables: dict[str, list[tuple[str, Answer]]] = {}
        self.waiting: dict[tuple[str, tuple[int, str, int]], list[GetResult]] = {}

    def queryable(self, node: str, key: str, answer: Answer) -> None:
        """An application on ``node`` answers gets meeting ``key`` with ``answer(params)``."""
        self.queryables.setdefault(node, []).append((key, answer))

    def get(self, node: str, key: str, parameters: dict[str, Any] | None = None,
            timeout: float | None = None) -> GetResult:
        """An application on ``node`` gets ``key`` now, waiting ``timeout`` seconds (None: as
        long as the query may take); the result fills in as time runs."""
        fleet = self.fleet
        result = GetResult(node, key, fleet.now)
        until = None if timeout is None else fleet.now + timeout
        core = fleet.cores[node]
        ticket = core.ask(key, parameters or {}, fleet.now, until)
        if isinstance(ticket, str):
            result.error, result.ended_at = ticket, fleet.now
        elif isinstance(ticket, OverIp):  # Zenoh over IP: the server's applications, at once
            found = core.queries.spec_for(key) if core.queries is not None else None
            assert found is not None  # (a get over IP is one on a query's key)
            for served, answer in self.queryables.get(found[1], []):
                if intersects(served, ticket.key):
                    result.replies += [(key, v, fleet.now) for v in answer(dict(parameters or {}))]
            result.ended_at = fleet.now
        else:
            self.waiting.setdefault((node, ticket), []).append(result)
        fleet.collect_and_replan(node)
        return result

    def synthetic(self, value: Callable[[Any], Any], until: float,
                  period: float = QUERY_PERIOD_S) -> list[GetResult]:
        """Applications for ``zab sim --fast``: a queryable at every server answering with
        ``value(layout)`` (a valid value of the reply fields), and at every asking node a get
        of each asked key every ``period`` until ``until``. Returns the gets, as they fill."""
        fleet = self.fleet
        results: list[GetResult] = []
        for spec in fleet.loaded.table.queries:
            for server in spec.servers:
                self.queryable(server, spec.served_key(server),
                               functools.partial(_answer, value, spec.reply))
            for asker in spec.askers:
                for server in spec.servers:
                    if server == asker:
                        continue

                    def ask(a: str = asker, key: str = spec.asked_key(server),
                            layout: Any = spec.request) -> None:
                        results.append(self.get(a, key, value(layout) if layout.fields else {}))
                        if fleet.now + period <= until:
                            fleet.call_at(fleet.now + period, ask)

                    fleet.call_at(fleet.now + period, ask)
        return results

    def handle(self, node: str, output: object) -> bool:
        """Carry out a query output of ``node``'s core; False if it is not one."""
        fleet = self.fleet
        if isinstance(output, LocalGet):
            values: list[Any] = []
            for key, answer in self.queryables.get(node, []):
                if intersects(key, output.key):
                    values += answer(dict(output.parameters))
            fleet.cores[node].query_served(output.ticket, values, fleet.now)
            fleet.call_at(fleet.now, lambda: fleet.collect_and_replan(node))
            return True
        if isinstance(output, QueryAnswer):
            for result in self.waiting.get((node, output.ticket), []):
                result.replies.append((output.key, output.value, fleet.now))
            return True
        if isinstance(output, QueryEnd):
            for result in self.waiting.pop((node, output.ticket), []):
                result.error, result.ended_at = output.error, fleet.now
            return True
        return False
