"""Queries across the water: a plain Zenoh get at one node answered by a queryable on another,
ended with a reply error at the MAC's deadline, bounded, refused when the link is down."""

from __future__ import annotations

import msgpack
import pytest
import yaml

from bridge.core.link import LinkState
from bridge.core.loaded import load_mission, parse_mission
from bridge.core.node import NodeCore
from bridge.core.queries import ERROR_REPLY, TIMED_OUT, UNDECODABLE, deadline_s, failed_reply
from bridge.errors import MissionError
from bridge.runtime.virtual_fleet import FastFleet
from bridge.runtime.zenoh_queries import (
    GetRefused,
    format_parameters,
    get_fields,
    parse_parameters,
)
from bridge.wire.frame import FrameCodec
from bridge.wire.payloads import PAYLOAD_FLOOR_BYTES
from bridge.wire.queries import FailReason, ReplyStatus
from tests.conftest import MISSIONS

ZSPACE = MISSIONS / "zspace.yaml"


def info(params: dict) -> list[dict]:
    return [{"depth_m": 12.5, "state": "survey", "detail": int(params.get("detail", 0))}]


def fleet_with_info() -> FastFleet:
    fleet = FastFleet(load_mission(ZSPACE), seed=1)
    fleet.queries.queryable("auv1", "auv1/info", info)
    fleet.run_until(10.0)  # heartbeats: every link is up
    return fleet


def test_a_get_is_answered_within_the_macs_bound_and_concurrent_gets_share_a_request() -> None:
    fleet = fleet_with_info()
    first = fleet.queries.get("top", "auv1/info", {"detail": 2})
    second = fleet.queries.get("top", "auv1/info", {"detail": 2})
    fleet.run_until(30.0)
    for result in (first, second):
        assert result.error is None and result.done
        assert [v for _, v, _ in result.replies] == [{"depth_m": 12.5, "state": "survey",
                                                      "detail": 2}]
    bound = deadline_s(fleet.mission, fleet.loaded.table.queries[0], "top", "auv1")
    assert first.ended_at is not None and first.ended_at - first.asked_at <= bound
    assert fleet.cores["top"].queries.asked == 1  # one acoustic request for both gets


def test_no_queryable_at_the_server_ends_without_replies() -> None:
    fleet = fleet_with_info()
    result = fleet.queries.get("top", "auv2/info", {"detail": 1})
    fleet.run_until(30.0)
    assert result.done and result.error is None and result.replies == []


def test_several_replies_come_back_in_order_up_to_max_replies() -> None:
    fleet = FastFleet(load_mission(ZSPACE), seed=1)
    fleet.queries.queryable("auv2", "auv2/info", lambda p: [
        {"depth_m": d, "state": "idle", "detail": 0} for d in (1.0, 2.0, 3.0)])
    fleet.run_until(10.0)
    result = fleet.queries.get("top", "auv2/info", {"detail": 0})
    fleet.run_until(30.0)
    assert [v["depth_m"] for _, v, _ in result.replies] == [1.0, 2.0]  # max_replies: 2
    assert result.error is None


def test_bad_input_ends_at_once_with_a_reason() -> None:
    fleet = fleet_with_info()
    bad = fleet.queries.get("top", "auv1/info", {"detail": 9})
    assert bad.done and "malformed parameters" in (bad.error or "")
    assert fleet.cores["top"].queries.dropped["info"] == 1
    opened = [fleet.queries.get("top", "auv1/info", {"detail": d}) for d in range(4)]
    opened.append(fleet.queries.get("top", "auv2/info", {"detail": 0}))
    assert [r.done for r in opened] == [False] * 4 + [True]
    assert "4 acoustic queries already open" in (opened[-1].error or "")
    fleet.run_until(40.0)
    assert all(r.error is None and r.replies for r in opened[:4])


def test_a_lost_reply_ends_with_an_error_at_the_deadline() -> None:
    fleet = fleet_with_info()
    result = fleet.queries.get("top", "auv1/info", {"detail": 1})
    fleet.stop("auv1")  # it never hears the request
    fleet.run_until(11.0)
    assert fleet.cores["top"].link_states["auv1"].value == "up"
    fleet.run_until(40.0)
    bound = deadline_s(fleet.mission, fleet.loaded.table.queries[0], "top", "auv1")
    assert result.error is not None and "auv1: no reply" in result.error
    assert "MAC's bound" in result.error
    assert result.ended_at is not None and bound <= result.ended_at - result.asked_at <= bound + 1.5
    fleet.run_until(10.0 + fleet.cores["top"].thresholds.down_after_s + 1.0)
    late = fleet.queries.get("top", "auv1/info", {"detail": 1})  # by now the link is down
    assert late.done and late.error is not None and "auv1: acoustic link down" in late.error


def test_request_and_reply_entries_and_mission_errors() -> None:
    loaded = load_mission(ZSPACE)
    codec = FrameCodec(loaded.table)
    request, reply = loaded.table.query_codecs
    # reply: query id 4 + node 2 + status 2 + index 1 (max_replies 2) + the fields
    assert request.wire_bits == 4 + 2 + 2
    assert reply.wire_bits == 4 + 2 + 2 + 1 + reply.layout.bits
    data = codec.encode([(request, request.pack(5, 1, 2)), (reply, reply.pack(3, 0, 0, 2)),
                         (reply, reply.pack(3, 0, reply.layout.pack(
                             {"depth_m": 4.5, "state": "idle", "detail": 1}), 1, 1)),
                         (reply, reply.pack(4, 0, FailReason.TIMEOUT, ReplyStatus.FAILED))])
    first, second, third, fourth = codec.decode(data).entries
    assert first.header == (5, 1, 0, 0, 0) and first.values == [{"detail": 2}]
    assert second.header == (3, 0, 2, 0, 0) and second.values is None
    assert third.header == (3, 0, 1, 1, 0) and third.values == [
        {"depth_m": 4.5, "state": "idle", "detail": 1}]
    assert fourth.header == (4, 0, 3, 0, FailReason.TIMEOUT) and fourth.values is None
    text = yaml.safe_load(ZSPACE.read_text())
    text["queries"][0]["key"] = "info"
    with pytest.raises(MissionError, match=r"queries\[0\]\.key.*\{node\}"):
        parse_mission(yaml.safe_dump(text))


def test_selector_parameters_round_trip() -> None:
    values = parse_parameters("detail=2;mode=full;pos.x=1.5;on=true")
    assert values == {"detail": 2, "mode": "full", "pos": {"x": 1.5}, "on": True}
    assert parse_parameters(format_parameters(values)) == values


def test_a_gets_selector_and_payload_join_and_never_contradict() -> None:
    def fields(selector: str, payload: object, cap: int = PAYLOAD_FLOOR_BYTES) -> object:
        return get_fields(selector, msgpack.packb(payload), "application/msgpack", cap)

    assert fields("", {"detail": 2}) == {"detail": 2}
    assert fields("detail=2", {"detail": 2}) == {"detail": 2}  # the same value twice: fine
    assert fields("pos.x=1;_timeout=3", {"pos": {"y": 2}, "_timeout": 9}) == {
        "pos": {"x": 1, "y": 2}, "_timeout": 3}  # Zenoh's own parameters: the selector's
    assert get_fields("detail=1", None, "", PAYLOAD_FLOOR_BYTES) == {"detail": 1}
    refused = [("detail=0", {"detail": 2}, "unfit",
                "parameter 'detail' given twice, 0 in the selector and 2 in the payload"),
               ("pos.x=1", {"pos": {"x": 2}}, "unfit", "parameter 'pos.x' given twice"),
               ("detail=0", [1], "unfit", "a payload that is not a map, and selector"),
               ("", {"detail": 2, "pad": "y" * 1_000_000}, "too_large",
                "a get payload of 1000018 bytes, over this query's cap of 16384")]
    for selector, payload, cause, reason in refused:
        with pytest.raises(GetRefused, match=reason) as info:
            fields(selector, payload)
        assert info.value.cause == cause
    with pytest.raises(GetRefused, match=r"nor msgpack \(reserved byte 0xc1 at offset 0\)"):
        get_fields("", b"\xc1junk", "zenoh/bytes", PAYLOAD_FLOOR_BYTES)


def test_a_refused_get_and_its_extra_fields_are_told_as_a_puts(
        caplog: pytest.LogCaptureFixture) -> None:
    """The put path's ledger counts and logs them; fields no request field carries are
    counted and said once, as a put's."""
    loaded = load_mission(ZSPACE)
    top = NodeCore(loaded, "top")
    assert top.queries is not None
    with caplog.at_level("WARNING"):
        why = top.queries.refuse("auv1/info", "too_large", "a get payload of 9 bytes", 0.0)
        spec = loaded.table.queries[0]
        for at in (1.0, 2.0):
            top.queries.ask(spec, "auv1", {"detail": 1, "pad": "y"}, at, LinkState.UP)
    assert why == "query 'info': a get payload of 9 bytes"
    assert top.queries.dropped == {"info": 1}
    assert top.outbound.drops.causes() == {"auv1/info": {"too_large": 1}}
    assert top.stats.fields_left_out == {"auv1/info": 2}
    said = [r.getMessage() for r in caplog.records]
    assert sum("dropped a payload on 'auv1/info'" in s for s in said) == 1
    assert sum("fields pad of 'auv1/info' are carried by no channel" in s for s in said) == 1


def test_a_query_under_the_polled_mac_is_answered_in_the_reply_to_its_poll() -> None:
    data = yaml.safe_load(ZSPACE.read_text())
    data["mac"] = {"type": "polled", "master": "top", "ipg_s": 1.5}
    loaded = parse_mission(yaml.safe_dump(data, sort_keys=False), "polled.yaml")
    fleet = FastFleet(loaded, seed=2)
    fleet.queries.queryable("auv2", "auv2/info", info)
    fleet.run_until(10.0)
    result = fleet.queries.get("top", "auv2/info", {"detail": 3})
    fleet.run_until(25.0)
    assert [v for _, v, _ in result.replies] == info({"detail": 3}) and result.error is None
    bound = deadline_s(loaded.mission, loaded.table.queries[0], "top", "auv2")
    assert result.ended_at is not None and result.ended_at - result.asked_at <= bound


def test_a_fresh_latched_value_answers_at_once_without_a_request() -> None:
    data = yaml.safe_load(ZSPACE.read_text())
    data["queries"].append({"name": "state", "key": "{node}/status", "serve": "auv.*",
                            "ask": "top", "cached_s": 10,
                            "reply": [{"field": "battery", "min": 0, "max": 100,
                                       "resolution": 1}]})
    loaded = parse_mission(yaml.safe_dump(data, sort_keys=False), "cached.yaml")
    fleet = FastFleet(loaded, seed=1)
    fleet.subscribe("top", "auv1/status")
    fleet.put("auv1", "auv1/status", {"battery": 80, "mode": "survey"}, at=0.5)
    fleet.run_until(10.0)
    arrived = fleet.published("top", "auv1/status")[-1][0]
    result = fleet.queries.get("top", "auv1/status")
    assert result.done and result.error is None and result.ended_at == result.asked_at
    assert [v for _, v, _ in result.replies] == [{"battery": 80, "mode": "survey"}]
    assert fleet.cores["top"].queries.asked == 0 and fleet.cores["top"].queries.cached == 1
    fleet.unsubscribe("top", "auv1/status")  # no fresher values: the cache ages
    fleet.run_until(arrived + 8.0)  # the new @want has crossed: auv1 stopped sending
    last = fleet.published("top", "auv1/status")[-1][0]
    fleet.run_until(last + 11.0)
    stale = fleet.queries.get("top", "auv1/status")
    assert not stale.done and fleet.cores["top"].queries.asked == 1  # goes over the water




def test_a_reply_that_does_not_fit_is_a_counted_drop_and_the_asker_is_told_why(
        caplog: pytest.LogCaptureFixture) -> None:
    fleet = FastFleet(load_mission(ZSPACE), seed=1)
    fleet.queries.queryable("auv1", "auv1/info", lambda p: [
        {"depth_m": 5.0, "state": "dive", "detail": 3}])  # no such state
    fleet.queries.queryable("auv2", "auv2/info", lambda p: [
        {"depth_m": 500.0, "state": "idle", "detail": 0}])  # over max 200: clamped
    fleet.run_until(10.0)
    with caplog.at_level("WARNING", logger="zab.core"):
        bad = fleet.queries.get("top", "auv1/info", {"detail": 3})
        deep = fleet.queries.get("top", "auv2/info", {"detail": 0})
        fleet.run_until(40.0)
    assert bad.replies == [] and bad.error == (
        "auv1: query 'info': not-usable: its replies could not be decoded or did not fit the "
        "reply fields (counted and logged at auv1)")
    auv1 = fleet.cores["auv1"]
    assert auv1.queries is not None and auv1.queries.dropped == {"info:reply": 1}
    assert auv1.outbound.drops.causes() == {"auv1/info": {"unfit": 1}}
    said = [r.getMessage() for r in caplog.records if "dropped a payload" in r.getMessage()]
    assert len(said) == 1 and "auv1: dropped a payload on 'auv1/info': a reply to query " \
        "'info': " in said[0] and "dive" in said[0] and "(unfit;" in said[0]
    assert [v["depth_m"] for _, v, _ in deep.replies] == [200.0] and deep.error is None
    assert fleet.cores["auv2"].snapshot(40.0)["clamped"] == {"!info": {"depth_m": 1}}


@pytest.mark.parametrize(("unusable", "reason", "cause"), [
    ([(ERROR_REPLY, "an error reply: 'sensor offline'")], "app-error", "error_reply"),
    ([(UNDECODABLE, "neither JSON (x) nor msgpack (y)")], "not-usable", "undecodable"),
    ([(TIMED_OUT, "Timeout")], "timeout", None),
    ([(TIMED_OUT, "Timeout"), (UNDECODABLE, "x"), (ERROR_REPLY, "e")], "app-error", None)])
def test_a_failed_local_get_crosses_as_a_reason_code(unusable: list[tuple[str, str]],
                                                     reason: str, cause: str | None) -> None:
    """The serving node's failure is two bits in the failed reply's unused fields: the
    asker's reply error names it; every reply the server could not use is a counted drop."""
    loaded = load_mission(ZSPACE)
    spec = loaded.table.queries[0]
    top, auv1 = NodeCore(loaded, "top"), NodeCore(loaded, "auv1")
    asker, server = top.queries, auv1.queries
    assert asker is not None and server is not None
    ticket = asker.ask(spec, "auv1", {"detail": 1}, 0.0, LinkState.UP)
    assert isinstance(ticket, tuple)
    (candidate,) = asker.candidates(0.0)
    codec = FrameCodec(loaded.table)
    request = codec.decode(codec.encode([(candidate.channel, candidate.what.bits)])).entries[0]
    server.on_request("top", request.channel, request.header, request.values, 0.5)
    (get,) = server.take()
    server.served(get.ticket, [], 1.0, unusable)
    (answer,) = server.candidates(1.0)
    entry = codec.decode(codec.encode([(answer.channel, answer.what.bits)])).entries[0]
    assert entry.header[2] == ReplyStatus.FAILED
    asker.on_reply("auv1", entry.channel, entry.header, entry.values, 2.0)
    (end,) = asker.take()
    assert end.error is not None and end.error.startswith(f"auv1: query 'info': {reason}: ")
    drops = [c for c, _ in unusable if c != TIMED_OUT]
    assert server.dropped == ({"info:reply": len(drops)} if drops else {})
    if cause is not None:
        assert auv1.outbound.drops.causes() == {"auv1/info": {cause: 1}}


def test_a_node_that_says_no_reason_gets_the_old_reply_error() -> None:
    assert failed_reply("auv1", "info", 0) == failed_reply("auv1", "info", 7) == (
        "auv1: the serving node's get failed or gave no usable reply")
    assert failed_reply("auv1", "info", 3) == (
        "auv1: query 'info': timeout: no queryable at auv1 answered within its local get's "
        "time")
