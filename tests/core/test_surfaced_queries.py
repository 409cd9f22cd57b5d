"""Queries while the serving vehicle is reachable over IP: nothing crosses the water, the get
is answered over IP, unquantised and at once; a query already open goes on acoustically, and
after the dive gets cross the water again."""

from __future__ import annotations

import yaml

from bridge.core.loaded import load_mission, parse_mission
from bridge.core.queries import LocalGet
from bridge.runtime.virtual_fleet import FastFleet
from tests.conftest import MISSIONS

ZSPACE = MISSIONS / "zspace.yaml"
EXACT = {"depth_m": 12.3, "state": "survey", "detail": 2}  # 12.3 m crosses as 12.5
QUANTISED = {"depth_m": 12.5, "state": "survey", "detail": 2}


def info(params: dict) -> list[dict]:
    return [{**EXACT, "detail": int(params.get("detail", 0))}]


def fleet_with_info(local_key: str | None = None) -> FastFleet:
    """The example's fleet, links up, auv1's application answering ``auv1/info`` (or, with
    ``local_key``, the key the serving bridge gets instead)."""
    loaded = load_mission(ZSPACE)
    if local_key is not None:
        data = yaml.safe_load(ZSPACE.read_text())
        data["queries"][0]["local_key"] = local_key
        loaded = parse_mission(yaml.safe_dump(data, sort_keys=False), "z.yaml")
    fleet = FastFleet(loaded, seed=1, kinds=(object,))  # query outputs kept too
    fleet.queries.queryable("auv1", (local_key or "{node}/info").format(node="auv1"), info)
    fleet.run_until(10.0)  # heartbeats: every link is up
    return fleet


def local_gets(fleet: FastFleet, node: str) -> list[LocalGet]:
    return [o.output for o in fleet.outputs if o.node == node and isinstance(o.output, LocalGet)]


def test_a_get_while_the_server_is_surfaced_crosses_nothing_and_is_answered_over_ip() -> None:
    fleet = fleet_with_info()
    fleet.ip_link("auv1", "top", True)
    result = fleet.queries.get("top", "auv1/info", {"detail": 2})
    fleet.run_until(30.0)
    assert result.done and result.error is None
    assert result.replies == [("auv1/info", EXACT, result.asked_at)]  # unquantised, at once
    assert result.ended_at == result.asked_at
    top = fleet.cores["top"]
    assert top.queries.asked == 0 and not top.queries.open  # no acoustic request
    assert local_gets(fleet, "auv1") == []  # auv1's bridge was never asked
    assert top.snapshot(fleet.now)["surfacing"]["gets_over_ip"] == 1


def test_a_get_on_a_key_the_server_serves_elsewhere_is_forwarded_there_over_ip() -> None:
    fleet = fleet_with_info(local_key="{node}/info/local")
    fleet.ip_link("auv1", "top", True)
    result = fleet.queries.get("top", "auv1/info", {"detail": 2})
    fleet.run_until(30.0)
    assert result.replies == [("auv1/info", EXACT, result.asked_at)]
    assert fleet.cores["top"].queries.asked == 0 and local_gets(fleet, "auv1") == []


def test_a_query_open_as_the_server_surfaces_is_answered_once_across_the_water() -> None:
    fleet = fleet_with_info()
    open_before = fleet.queries.get("top", "auv1/info", {"detail": 2})
    fleet.run_until(fleet.now + 0.5)
    fleet.ip_link("auv1", "top", True)
    after = fleet.queries.get("top", "auv1/info", {"detail": 2})  # same request: not shared
    fleet.run_until(40.0)
    assert open_before.error is None and [v for _, v, _ in open_before.replies] == [QUANTISED]
    assert after.replies == [("auv1/info", EXACT, after.asked_at)]
    assert fleet.cores["top"].queries.asked == 1 and len(local_gets(fleet, "auv1")) == 1


def test_after_the_dive_a_get_crosses_the_water_again() -> None:
    fleet = fleet_with_info()
    fleet.ip_link("auv1", "top", True)
    fleet.run_until(20.0)
    fleet.ip_link("auv1", "top", False)
    result = fleet.queries.get("top", "auv1/info", {"detail": 2})
    fleet.run_until(40.0)
    assert result.error is None and [v for _, v, _ in result.replies] == [QUANTISED]
    assert result.ended_at is not None and result.ended_at > result.asked_at
    assert fleet.cores["top"].queries.asked == 1 and len(local_gets(fleet, "auv1")) == 1
