"""Queries under acoustic loss, on the virtual clock: the asker repeats its request until every
reply arrived, the server answers repeats from the replies it kept (its local get runs once),
replies reach the application once each and in order, and what is kept stays bounded."""

from __future__ import annotations

import random

import pytest

from bridge.core.link import LinkState
from bridge.core.loaded import load_mission, parse_mission
from bridge.core.node import NodeCore
from bridge.core.queries import ANSWERS_KEPT, LocalGet, QueryAnswer, QueryEnd, deadline_s
from bridge.runtime.virtual_fleet import FastFleet
from bridge.wire import queries as wire_queries
from bridge.wire.queries import QID_BITS, ReplyStatus
from tests.conftest import MISSIONS

LOADED = load_mission(MISSIONS / "zspace.yaml")
TWO = [{"depth_m": 1.0, "state": "idle", "detail": 0},
       {"depth_m": 2.0, "state": "survey", "detail": 0}]


def success_rate(loss: float, repeats: bool, gets: int = 40) -> tuple[float, int, int]:
    """(share of gets answered completely, gets answered more than once, local gets run)."""
    fleet = FastFleet(LOADED, seed=3, loss=loss)
    runs = [0]

    def answer(params: dict) -> list[dict]:
        runs[0] += 1
        return [dict(v, detail=int(params.get("detail", 0))) for v in TWO]

    fleet.queries.queryable("auv1", "auv1/info", answer)
    for core in fleet.cores.values():
        core.queries.repeats = repeats
    fleet.run_until(20.0)
    rng, complete, doubled = random.Random(1), 0, 0
    for _ in range(gets):
        fleet.run_until(fleet.now + rng.uniform(0.0, 10.0))
        result = fleet.queries.get("top", "auv1/info", {"detail": 1})
        while not result.done:
            fleet.run_until(fleet.now + 0.5)
        values = [v for _, v, _ in result.replies]
        doubled += len(values) > len(TWO)
        if result.error is None:
            assert values == [dict(v, detail=1) for v in TWO]  # all, once each, in order
            complete += 1
    return complete / gets, doubled, runs[0]


def test_at_30_percent_loss_repeated_requests_answer_far_more_gets() -> None:
    before, doubled_before, _ = success_rate(0.3, repeats=False)
    after, doubled_after, runs = success_rate(0.3, repeats=True)
    assert before < 0.6 and after >= before + 0.2, (before, after)
    assert doubled_before == doubled_after == 0
    assert runs <= 40  # a repeated request never runs the server's local get again


def test_a_repeat_is_answered_from_the_kept_replies_without_a_second_local_get() -> None:
    fleet = FastFleet(LOADED, seed=1)
    runs: list[dict] = []
    fleet.queries.queryable("auv1", "auv1/info", lambda p: runs.append(p) or TWO)
    fleet.run_until(10.0)
    result = fleet.queries.get("top", "auv1/info", {"detail": 0})
    fleet.run_until(12.9)  # top's request left in its slot at 12 s, auv1 heard it
    fleet.stop("top")  # top misses auv1's replies (slot 13 s)
    fleet.run_until(14.5)
    fleet.resume("top")
    assert not result.done and len(runs) == 1
    fleet.run_until(20.0)  # repeated in top's slot at 15 s, answered at 16 s
    assert result.error is None and [v for _, v, _ in result.replies] == TWO
    assert len(runs) == 1
    top, auv1 = fleet.cores["top"].queries, fleet.cores["auv1"].queries
    assert top.repeated == 1 and auv1.duplicates == 1 and top.answered == 1
    assert result.ended_at is not None and result.ended_at - result.asked_at <= deadline_s(
        fleet.mission, LOADED.table.queries[0], "top", "auv1")


def test_duplicate_and_out_of_order_replies_reach_the_application_once_in_order() -> None:
    queries = NodeCore(LOADED, "top").queries
    assert queries is not None
    spec = LOADED.table.queries[0]
    ticket = queries.ask(spec, "auv1", {"detail": 0}, 0.0, LinkState.UP)
    assert isinstance(ticket, tuple)
    reply = queries.reply_codecs[spec.index]
    qid, top = ticket[2], LOADED.table.nodes.index("top")
    second = (qid, top, ReplyStatus.LAST, 1)
    queries.on_reply("auv1", reply, second, [TWO[1]], 1.0)
    queries.on_reply("auv1", reply, second, [TWO[1]], 1.5)  # heard twice
    assert queries.take() == [] and queries.duplicates == 1  # waits for reply 0
    queries.on_reply("auv1", reply, (qid, top, ReplyStatus.VALUE, 0), [TWO[0]], 2.0)
    out = queries.take()
    assert [o.value for o in out if isinstance(o, QueryAnswer)] == TWO
    assert isinstance(out[-1], QueryEnd) and out[-1].error is None
    queries.on_reply("auv1", reply, second, [TWO[1]], 3.0)  # after the end: dropped, counted
    assert queries.take() == [] and queries.dropped["late_reply"] == 1


def test_query_ids_rotate_and_kept_answers_stay_bounded() -> None:
    spec = LOADED.table.queries[0]
    asker = NodeCore(LOADED, "top").queries
    server = NodeCore(LOADED, "auv1").queries
    assert asker is not None and server is not None
    from bridge.core.link import LinkState

    ids = []
    for n in range(3):
        ticket = asker.ask(spec, "auv1", {"detail": 0}, float(n), LinkState.UP)
        assert isinstance(ticket, tuple)
        ids.append(ticket[2])
        asker._end(ticket, None)
    assert ids == [0, 1, 2]  # a new query never reuses the id of one just ended
    request = server.requests[spec.index]
    server.answers_kept = 8
    auv1 = LOADED.table.nodes.index("auv1")
    for n in range(40):  # each a new query: a fresh id, or a reused one with a new request
        header = (n % (1 << QID_BITS), auv1, 0, 0)
        server.on_request("top", request, header, [{"detail": (n // 16) % 4}], n / 100)
        gets = [o for o in server.take() if isinstance(o, LocalGet)]
        assert len(gets) == 1
        server.served(gets[0].ticket, TWO, n / 100)
        server.on_request("top", request, header, [{"detail": (n // 16) % 4}], n / 100)
        assert not any(isinstance(o, LocalGet) for o in server.take())  # a repeat: kept
    assert len(server.answers) == 8 and server.duplicates == 40
    assert ANSWERS_KEPT >= (1 << QID_BITS)  # the default keeps every id of one asker
    server.expire(100.0)  # past every deadline
    assert server.answers == {}


def test_the_query_entries_version_is_in_the_fingerprint_of_missions_with_queries(
        monkeypatch: pytest.MonkeyPatch) -> None:
    text = (MISSIONS / "zspace.yaml").read_text()
    now = parse_mission(text).table.fingerprint
    monkeypatch.setattr(wire_queries, "QUERY_WIRE", 1)  # a node built before reply indexes
    assert parse_mission(text).table.fingerprint != now
    plain = (MISSIONS / "morph.yaml").read_text()  # no queries: unchanged
    monkeypatch.undo()
    before = parse_mission(plain).table.fingerprint
    monkeypatch.setattr(wire_queries, "QUERY_WIRE", 1)
    assert parse_mission(plain).table.fingerprint == before
