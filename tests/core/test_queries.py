"""Queries across the water: a plain Zenoh get at one node answered by a queryable on another,
ended with a reply error at the MAC's deadline, bounded, refused when the link is down."""

from __future__ import annotations

import pytest
import yaml

from bridge.core.loaded import load_mission, parse_mission
from bridge.core.queries import deadline_s
from bridge.errors import MissionError
from bridge.runtime.virtual_fleet import FastFleet
from bridge.runtime.zenoh_queries import format_parameters, parse_parameters
from bridge.wire.frame import FrameCodec
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
                             {"depth_m": 4.5, "state": "idle", "detail": 1}), 1, 1))])
    first, second, third = codec.decode(data).entries
    assert first.header == (5, 1, 0, 0) and first.values == [{"detail": 2}]
    assert second.header == (3, 0, 2, 0) and second.values is None
    assert third.header == (3, 0, 1, 1) and third.values == [
        {"depth_m": 4.5, "state": "idle", "detail": 1}]
    text = yaml.safe_load(ZSPACE.read_text())
    text["queries"][0]["key"] = "info"
    with pytest.raises(MissionError, match=r"queries\[0\]\.key.*\{node\}"):
        parse_mission(yaml.safe_dump(text))


def test_selector_parameters_round_trip() -> None:
    values = parse_parameters("detail=2;mode=full;pos.x=1.5;on=true")
    assert values == {"detail": 2, "mode": "full", "pos": {"x": 1.5}, "on": True}
    assert parse_parameters(format_parameters(values)) == values


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


