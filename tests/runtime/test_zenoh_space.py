"""Zenoh as Zenoh users know it (issue 32), end to end: plain Zenoh applications (``zenoh`` and
``msgpack`` only, no import from the project) at two nodes of one ``zab sim`` process, shared
by every test of this module."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import msgpack
import pytest
import zenoh

from tests.zsim import app, mission_file, zab_sim

MISSION = """
mission: zfid
wire: {auth: off}
link: {heartbeat_s: 2}
modem:
  backend: sim
  frame_bytes: 48
  options: {preset: evologics-s2c-im, seed: 1}
mac: {type: tdma, slot_s: 0.8, guard_s: 0.05, order: [top, auv1]}
nodes:
  top: {address: 1, role: surface, position: {x: 0, y: 0, depth: 0.5}}
  auv1: {address: 2, position: {x: 40, y: 30, depth: 10}}
queries:
  - name: info
    key: auv1/info
    serve: auv1
    request: [{field: detail, type: int, min: 0, max: 3}]
    reply:
      - {field: depth_m, min: 0, max: 200, resolution: 0.5}
      - {field: detail, type: int, min: 0, max: 3}
    max_replies: 2
    deadline_bits: 4
  - name: state
    key: auv1/state
    serve: auv1
    reply: [{field: mode, type: enum, values: [idle, survey]}]
channels:
  - name: status
    from: auv1
    to: top
    latching: true
    interval_s: 2
    elements:
      - in: status
        out: "{src}/status"
        fields:
          - {field: battery, min: 0, max: 100, resolution: 1}
"""


@dataclass
class Space:
    """The running ``zab sim`` and an application session at each node."""

    top: zenoh.Session
    auv1: zenoh.Session
    served: dict[str, int] = field(default_factory=dict)  # queryable runs at auv1, by key


@pytest.fixture(scope="module")
def space(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Space]:
    mission, endpoints = mission_file(MISSION, tmp_path_factory.mktemp("zfid"))
    with zab_sim(mission, endpoints, timeout=600):
        top, auv1 = app(endpoints["top"]), app(endpoints["auv1"])
        space = Space(top, auv1)
        try:
            serve_at_auv1(space)
            wait_until_answered(top)
            yield space
        finally:
            top.close()
            auv1.close()


def serve_at_auv1(space: Space) -> None:
    """auv1's applications: ``auv1/info`` answers twice, ``auv1/state`` once."""
    def info(query: zenoh.Query) -> None:
        space.served["info"] = space.served.get("info", 0) + 1
        detail = int(str(query.parameters).partition("detail=")[2] or 0)
        for depth in (10.5, 11.0):
            query.reply(query.key_expr, msgpack.packb({"depth_m": depth, "detail": detail}))
        query.drop()

    def state(query: zenoh.Query) -> None:
        space.served["state"] = space.served.get("state", 0) + 1
        query.reply(query.key_expr, msgpack.packb({"mode": "survey"}))
        query.drop()

    space.auv1.declare_queryable("auv1/info", info)
    space.auv1.declare_queryable("auv1/state", state)


ALL = zenoh.QueryConsolidation(zenoh.ConsolidationMode.NONE)


def get(session: zenoh.Session, selector: str, timeout: float = 20.0
        ) -> tuple[list[tuple[str, Any]], list[str]]:
    """Every reply of a get (consolidation none): (key, value) in order, and the errors."""
    values, errors = [], []
    for reply in session.get(selector, timeout=timeout, consolidation=ALL):
        if reply.ok is not None:
            values.append((str(reply.ok.key_expr), msgpack.unpackb(reply.ok.payload.to_bytes())))
        else:
            errors.append(reply.err.payload.to_string())
    return values, errors


def wait_until_answered(top: zenoh.Session) -> None:
    """Until the surface has heard auv1 (its link is up) and a get is answered."""
    deadline = time.time() + 30
    while True:
        values, errors = get(top, "auv1/state")
        if values or time.time() > deadline:
            break
        time.sleep(0.5)
    assert values, errors


def test_every_reply_of_the_far_queryable_arrives_in_order(space: Space) -> None:
    values, errors = get(space.top, "auv1/info?detail=2")
    assert values == [("auv1/info", {"depth_m": 10.5, "detail": 2}),
                      ("auv1/info", {"depth_m": 11.0, "detail": 2})], errors
    assert not errors


def test_a_get_whose_caller_gave_up_never_reaches_the_vehicle(space: Space) -> None:
    before = space.served.get("info", 0)
    for _ in range(4):
        values, _ = get(space.top, "auv1/info?detail=1;_timeout=0.3", timeout=0.3)
        assert values == []
    time.sleep(4.0)  # two TDMA cycles: any request sent would have been served by now
    assert space.served.get("info", 0) == before
    values, _ = get(space.top, "auv1/info?detail=1")  # the caller waits: it crosses
    assert len(values) == 2 and space.served["info"] == before + 1


def test_a_wildcard_get_asks_what_it_can_and_says_what_it_cannot(space: Space) -> None:
    values, errors = get(space.top, "auv1/**")
    assert ("auv1/state", {"mode": "survey"}) in values
    assert all(key != "auv1/info" for key, _ in values)
    assert len(errors) == 1 and "auv1/info needs detail" in errors[0]
    values, errors = get(space.top, "auv1/*?detail=3")  # parameters given: both are asked
    assert ("auv1/info", {"depth_m": 10.5, "detail": 3}) in values
    assert ("auv1/state", {"mode": "survey"}) in values
    assert not errors


def test_concurrent_wildcard_and_plain_gets_each_get_their_replies(space: Space) -> None:
    results: dict[str, Any] = {}

    def ask(selector: str) -> None:
        results[selector] = get(space.top, selector)

    threads = [threading.Thread(target=ask, args=(s,))
               for s in ("auv1/state", "auv1/**?detail=0")]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert results["auv1/state"] == ([("auv1/state", {"mode": "survey"})], [])
    values, errors = results["auv1/**?detail=0"]
    assert {k for k, _ in values} >= {"auv1/state", "auv1/info"} and not errors

