"""Positioning, pure: modem ranges, no-fix reports, both ends' sound speed, ping turns, paths."""

from __future__ import annotations

import math

import pytest
import yaml

from bridge.core.loaded import parse_mission
from bridge.core.positioning import Positioning, needs_positioning, ping_plan, simulated_preset
from bridge.errors import MissionError
from bridge.mission.model import Mission
from bridge.ranging import Fix, NoFix, SoundSpeed, mackenzie

# seed 001's mobile case: three anchors on a jetty (x = 0), the vehicle east of it
BASE = {
    "mission": "jetty",
    "nodes": {
        "a1": {"address": 1, "role": "surface", "position": {"x": 0, "y": 0, "depth": 0.5}},
        "a2": {"address": 2, "role": "surface", "position": {"x": 0, "y": 20, "depth": 0.5}},
        "a3": {"address": 3, "role": "surface", "position": {"x": 0, "y": 40, "depth": 0.5}},
        "auv": {"address": 4, "position": {"x": 10, "y": 12, "depth": 1.0}},
    },
    "ranging": {"water": {"temperature_c": 12.0, "salinity_psu": 0.5, "depth_m": 1.0}},
}
AUV = (10.0, 12.0, 1.0)


def mission(**ranging: object) -> Positioning:
    data = yaml.safe_load(yaml.safe_dump(BASE))
    data["ranging"].update(ranging)
    return Positioning(parse_mission(yaml.safe_dump(data)).mission, "auv")


def travel(peer: str, p: Positioning, where: tuple[float, float, float] = AUV) -> float:
    return math.dist(where, p.anchor_positions[peer]) / p.sound_speed.mps


def test_modem_ranges_are_published_like_dlbl_and_give_fixes() -> None:
    p = mission()
    first = p.on_modem_range("a1", travel("a1", p), "ping", now=100.0)
    (rng,) = first.ranges
    payload = p.range_payload(rng)
    assert payload["method"] == "ping" and payload["peer"] == "a1" and payload["time"] == 100.0
    assert payload["range_m"] == pytest.approx(math.dist(AUV, (0, 0, 0.5)))
    assert payload["sound_speed_mps"] == p.sound_speed.mps and payload["sound_speed_source"] == \
        "unesco"
    assert first.fix == NoFix("too_few_anchors", ("a1",))  # said so, not silent
    second = p.on_modem_range("a2", travel("a2", p), "propagation", now=101.0)
    assert isinstance(second.fix, Fix)  # two anchors, the start position picks the side
    assert (second.fix.x, second.fix.y) == pytest.approx(AUV[:2], abs=1e-6)
    third = p.on_modem_range("a3", travel("a3", p), "ping", now=102.0)
    assert isinstance(third.fix, Fix) and third.fix.anchors == ("a1", "a2", "a3")
    assert third.fix.payload(5.0)["fix"] is True
    # a range older than fix_max_age_s no longer counts
    late = p.on_modem_range("a1", travel("a1", p), "ping", now=102.0 + p.fix_max_age_s + 1.0)
    assert late.fix == NoFix("too_few_anchors", ("a1",))


def test_bad_modem_ranges_are_counted_not_used() -> None:
    p = mission()
    for peer, tw in (("a1", -0.1), ("a1", math.nan), ("a1", 1e9), ("ghost", 0.01), ("auv", 0.01)):
        assert p.on_modem_range(peer, tw, "ping", now=1.0).ranges == ()
    assert p.drops == {"bad travel time": 3, "unknown peer": 2}
    assert p.latest == {}
    with pytest.raises(ValueError, match="unknown modem ranging method"):
        p.on_modem_range("a1", 0.01, "sonar", now=1.0)


def test_no_depth_and_anchors_do_not_localise() -> None:
    data = yaml.safe_load(yaml.safe_dump(BASE))
    del data["nodes"]["auv"]["position"]
    loaded = parse_mission(yaml.safe_dump(data))
    p = Positioning(loaded.mission, "auv")
    update = p.on_modem_range("a1", 0.01, "ping", now=1.0)
    assert update.fix == NoFix("no_depth", ("a1",))
    anchor = Positioning(loaded.mission, "a1")
    assert not anchor.localises
    assert anchor.on_modem_range("auv", 0.01, "ping", now=1.0).fix is None


def test_a_fixed_sound_speed_wins_over_the_water_and_the_simulated_water_keeps_its_own() -> None:
    # docs/ranging.md: c is ranging.sound_speed_mps if given, else computed from ranging.water
    p = mission(sound_speed_mps=1450.0)
    rng = p.on_modem_range("a1", 0.01, "ping", now=1.0).ranges[0]
    payload = p.range_payload(rng)
    assert payload["sound_speed_mps"] == 1450.0 and payload["sound_speed_source"] == "fixed"
    # the simulated ocean's truth is the water's (UNESCO, 12 °C fresh: ~1456 m/s): a bridge
    # assuming 1450 m/s then measures ranges 0.4 % short, as it would at sea
    water = mission().sound_speed.mps
    assert water == pytest.approx(1455.7, abs=0.5)
    assert simulated_preset(p.mission).sound_speed_mps == water
    data = yaml.safe_load(yaml.safe_dump(BASE))
    data["ranging"] = {"sound_speed_mps": 1450.0}  # no water described: the fixed speed
    assert simulated_preset(parse_mission(yaml.safe_dump(data)).mission).sound_speed_mps == 1450.0


def test_mean_of_both_ends_sound_speed() -> None:
    p = mission(sound_speed_mode="mean_of_ends", peer_ctd_key="{src}/ctd",
                ctd_key="ctd")
    assert p.peer_ctd_keys() == {"a1": "a1/ctd", "a2": "a2/ctd", "a3": "a3/ctd"}
    local = p.sound_speed.mps
    rng = p.on_modem_range("a1", 0.01, "ping", now=1.0).ranges[0]
    assert p.range_payload(rng)["sound_speed_source"] == "unesco"  # peer's water not known yet
    theirs = p.set_peer_water("a1", 24.0, 35.0, 0.5)  # warmer, saltier at the surface anchor
    payload = p.range_payload(rng)
    assert payload["sound_speed_source"] == "mean"
    assert payload["sound_speed_mps"] == pytest.approx((local + theirs.mps) / 2)
    assert payload["range_m"] == pytest.approx(0.01 * (local + theirs.mps) / 2)
    assert p.sound_speed_for("a2").mps == local  # other peers keep ours
    with pytest.raises(ValueError, match="temperature_c 99"):
        p.set_peer_water("a2", 99.0, 35.0, 0.5)
    with pytest.raises(ValueError, match="not a peer"):
        p.set_peer_water("auv", 10.0, 35.0, 0.5)
    assert mission(peer_ctd_key="{src}/ctd").peer_ctd_keys() == {}  # local mode needs none


def test_local_ctd_uses_the_mission_equation() -> None:
    p = mission(water={"temperature_c": 12.0, "salinity_psu": 0.5, "depth_m": 1.0,
                       "equation": "mackenzie"})
    p.set_water(20.0, 35.0, 10.0)
    assert p.sound_speed == SoundSpeed(mackenzie(20.0, 35.0, 10.0), "mackenzie")
    with pytest.raises(ValueError, match="salinity_psu"):
        p.set_water(20.0, -5.0, 10.0)


def test_ping_turns_and_defaults() -> None:
    p = mission(ping={"interval_s": 3.0})
    assert p.ping_peers == ("a1", "a2", "a3")  # default: the anchors, from every non-anchor
    assert p.fix_max_age_s >= 9.0  # a peer's range lasts until its turn comes again
    assert p.ping_due(0.0) == "a1" and p.next_ping() == -math.inf
    p.pinged("a1", 0.0)
    assert p.ping_due(2.9) is None and p.next_ping() == 3.0
    assert p.ping_due(3.0) == "a2"
    p.pinged("a2", 3.0)
    p.pinged("a3", 6.0)
    assert p.ping_due(9.0) == "a1"
    loaded = parse_mission(yaml.safe_dump({**BASE, "ranging": {
        "ping": {"peers": ["a2"], "nodes": ["auv", "a1"]}}}))
    assert ping_plan(loaded.mission, "a1") == ("a2",)
    assert ping_plan(loaded.mission, "a3") == ()
    assert needs_positioning(loaded.mission, "auv") and not needs_positioning(loaded.mission, "a3")
    assert mission().ping_due(0.0) is None and mission().next_ping() is None  # never
    bad = {**BASE, "ranging": {"ping": {"peers": ["nobody"]}}}
    with pytest.raises(MissionError, match=r"ranging\.ping\.peers\[0\]: unknown node 'nobody'"):
        parse_mission(yaml.safe_dump(bad))  # zab check says so
    with pytest.raises(ValueError, match=r"ranging\.ping\.peers: unknown node"):
        Positioning(Mission.model_validate(bad), "auv")  # and so does a node, if it gets that far


def test_a_node_on_a_path_starts_from_its_first_waypoint() -> None:
    data = yaml.safe_load(yaml.safe_dump(BASE))
    del data["nodes"]["auv"]["position"]
    data["nodes"]["auv"]["path"] = {"waypoints": [{"x": 5, "y": 5, "depth": 1.5},
                                                  {"x": 15, "y": 5, "depth": 1.5}],
                                    "speed_mps": 0.5, "loop": True}
    loaded = parse_mission(yaml.safe_dump(data))
    p = Positioning(loaded.mission, "auv")
    assert p.depth == 1.5 and p.start == (5.0, 5.0)
    where = (6.0, 5.0, 1.5)
    p.on_modem_range("a1", travel("a1", p, where), "ping", now=1.0)
    fix = p.on_modem_range("a2", travel("a2", p, where), "ping", now=1.0).fix
    assert isinstance(fix, Fix) and (fix.x, fix.y) == pytest.approx(where[:2], abs=1e-6)


def test_the_track_restarts_when_the_vehicle_is_not_where_it_predicts() -> None:
    p = mission()
    t = 0.0
    for _ in range(4):
        for peer in ("a1", "a2", "a3"):
            t += 1.0
            p.on_modem_range(peer, travel(peer, p), "ping", now=t)
    assert p.track.position == pytest.approx(AUV[:2], abs=0.01)
    moved = (10.0, 30.0, 1.0)  # e.g. a navigation reset: 18 m away at once
    fixes = []
    for _ in range(3):
        for peer in ("a1", "a2", "a3"):
            t += 1.0
            fixes.append(p.on_modem_range(peer, travel(peer, p, moved), "ping", now=t).fix)
    assert all(isinstance(f, Fix) for f in fixes)  # published as measured all along
    assert p.track.refused >= 2
    assert p.track.position == pytest.approx(moved[:2], abs=0.5)  # then the track follows


def test_a_moving_anchor_is_placed_back_in_time_too() -> None:
    # a DLBL range's first leg may predate the anchor's latest report (the frame bringing the
    # range brought the report too): the anchor was then where its motion puts it, not at the
    # report (before: held at the report, 4.8 m off for lsv's 6 s spans in zab demo)
    p = mission(anchors=["a1", "a2"], anchor_keys={"a2": "a2/nav"})
    p.set_anchor("a2", (0.0, 20.0, 0.5), now=10.0)
    p.set_anchor("a2", (0.0, 26.0, 0.5), now=17.5)  # 0.8 m/s north
    (x, y, _), sigma, age = p.anchor_at("a2", 17.5 - p.report_latency_s - 3.0)
    assert (x, y) == pytest.approx((0.0, 23.6), abs=1e-9) and age == 0.0
    assert sigma == pytest.approx(p.anchor_at("a2", 17.5 - p.report_latency_s + 3.0)[1])
    (x, y, _), _, age = p.anchor_at("a2", 17.5 - p.report_latency_s + 1.0)
    assert (x, y) == pytest.approx((0.0, 26.8), abs=1e-9) and age == pytest.approx(1.0)
