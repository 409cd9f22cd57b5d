"""Routes that list several next hops (issue 29: "a relay that dies is routed around where
another path exists"), on the virtual clock through the one core: a diamond surface–{r1,r2}–
far whose first relay is killed mid-run and restarted."""

from __future__ import annotations

from typing import Any

import pytest

from bridge.core.events import Delivery, FrameReceived, FrameRelayed, RouteSwitched
from bridge.core.loaded import LoadedMission, parse_mission
from bridge.core.node import Publish
from bridge.mission.loader import MissionProblems
from bridge.runtime.virtual_fleet import FastFleet

DIAMOND = """\
mission: diamond
link: {degraded_after_s: 20, down_after_s: 30, failback_s: 45}
links:
  upper:
    kind: acoustic
    modem: {backend: sim, frame_bytes: 64, options: {preset: s2cr-burst}}
    mac: {type: tdma, slot_s: 3.0, guard_s: 0.3, order: [surface, r1, r2]}
    nodes: [surface, r1, r2]
  lower:  # the same modems, another channel; far hears neither the surface nor its link
    modem: {backend: sim, frame_bytes: 64, options: {preset: s2cr-burst}}
    mac: {type: tdma, slot_s: 3.0, guard_s: 0.3, order: [r1, r2, far]}
    nodes: [r1, r2, far]
nodes:
  surface: {address: 1, role: surface, position: {x: 0, y: 0, depth: 0},
            routes: {far: [r1, r2]}}
  r1: {address: 2, position: {x: 500, y: 100, depth: 30}}
  r2: {address: 3, position: {x: 500, y: -100, depth: 30}}
  far: {address: 4, position: {x: 1000, y: 0, depth: 30}, routes: {surface: [r1, r2]}}
channels:
  - name: status
    from: far
    to: surface
    interval_s: 10
    elements:
      - in: far/status
        out: far/status
        fields: [{field: n, type: int, min: 0, max: 1023}]
  - name: goto
    from: surface
    to: far
    reliable: true
    retries: 6
    elements:
      - in: goto
        out: far/goto
        fields: [{field: x, type: int, min: 0, max: 255}]
queries:
  - name: info
    key: "{node}/info"
    serve: far
    ask: surface
    reply: [{field: battery, type: int, min: 0, max: 100}]
"""

ONE_LINK = DIAMOND.split("nodes:\n", 1)[1].replace("x: 500, y: 100", "x: 2000, y: 1000").replace(
    "x: 500, y: -100", "x: 2000, y: -1000").replace("x: 1000, y: 0", "x: 4000, y: 0")
ONE_LINK = """\
mission: diamond1
link: {degraded_after_s: 30, down_after_s: 45, failback_s: 45}
modem: {backend: sim, frame_bytes: 64, options: {preset: s2cr-burst}}
mac: {type: tdma, slot_s: 3.0, guard_s: 1.6, order: [surface, r1, r2, far]}
nodes:
""" + ONE_LINK
"""The diamond on one acoustic link: far is 4 km from the surface, beyond the modem's 3.5
(2.2 km a hop: 1.5 s of travel, within each slot's guard; 12-s cycles)."""
KILLED, RESTARTED = 150.0, 400.0


def diamond(text: str = DIAMOND) -> LoadedMission:
    return parse_mission(text, "diamond.yaml")


def events(fleet: FastFleet, kind: type, node: str | None = None) -> list:
    return [t.output for t in fleet.outputs
            if isinstance(t.output, kind) and (node is None or t.node == node)]


def published(fleet: FastFleet, node: str, key: str) -> list[tuple[float, object]]:
    return [(t.time, t.output.value) for t in fleet.outputs if t.node == node
            and isinstance(t.output, Publish) and t.output.key == key]


GETS = (100.0, KILLED + 2.0, 250.0, RESTARTED + 10.0, 600.0)
"""When the surface asks far for its info: through r1, just after r1's death, through r2,
while r1 comes back, through r1 again."""


def run_diamond(seed: int, text: str = DIAMOND) -> tuple[FastFleet, list[Any]]:
    fleet = FastFleet(diamond(text), seed=seed)
    fleet.queries.queryable("far", "far/info", lambda params: [{"battery": 77}])
    for i in range(64):
        fleet.put("far", "far/status", {"n": i}, at=1.0 + 10 * i)
    for i in range(30):
        fleet.put("surface", "goto", {"x": i}, at=5.0 + 20 * i, ref=f"g{i}")
    gets = []
    for t in sorted({*GETS, KILLED, RESTARTED}):
        fleet.run_until(t)
        if t == KILLED:
            fleet.stop("r1")  # killed: it sends nothing more, and loses what it carried
        if t == RESTARTED:
            fleet.restart("r1")
        if t in GETS:
            gets.append(fleet.queries.get("surface", "far/info"))
    fleet.run_until(900.0)
    return fleet, gets


@pytest.mark.parametrize(("seed", "text"), [(1, DIAMOND), (2, DIAMOND), (3, DIAMOND),
                                            (1, ONE_LINK), (2, ONE_LINK)],
                         ids=["two-links-1", "two-links-2", "two-links-3", "one-link-1",
                              "one-link-2"])
def test_a_dead_relay_is_routed_around_and_traffic_returns_when_it_comes_back(
        seed: int, text: str) -> None:
    fleet, gets = run_diamond(seed, text)
    link = fleet.loaded.mission.link
    assert link.down_after_s is not None and link.failback_s is not None
    down_after_s, failback_s = link.down_after_s, link.failback_s
    for node, dest in (("surface", "far"), ("far", "surface")):
        switches = [(e.time, e.was, e.via, e.reason) for e in events(fleet, RouteSwitched, node)
                    if e.peer == dest]
        assert [s[1:] for s in switches] == [("r1", "r2", "failover"),
                                             ("r2", "r1", "failback")], switches
        (over, *_), (back, *_) = switches
        # r1's last frame went out before the kill: down within down_after_s (plus a tick)
        assert KILLED < over <= KILLED + down_after_s + 1.0
        # back once r1 has been up (heard again) for failback_s, not before
        assert RESTARTED + failback_s <= back <= RESTARTED + failback_s + 30.0
    # r2 carries only while r1 is dead (and until the failback), r1 the rest of the time
    by_relay = {node: [e.time for e in events(fleet, FrameRelayed, node)] for node in ("r1", "r2")}
    assert len([t for t in by_relay["r1"] if t < KILLED]) >= 10
    assert len([t for t in by_relay["r1"] if t > RESTARTED + failback_s + 30.0]) >= 10
    assert len([t for t in by_relay["r2"] if KILLED + down_after_s + 1 < t < RESTARTED]) >= 10
    assert not [t for t in by_relay["r2"] if t < KILLED or t > RESTARTED + failback_s + 30.0]
    # the status of far keeps coming through r2 while r1 is dead, each value once
    status = published(fleet, "surface", "far/status")
    values = [v["n"] for _, v in status]  # type: ignore[index]
    assert len(values) == len(set(values))
    assert len([t for t, _ in status if KILLED + down_after_s + 1 < t < RESTARTED]) >= 10
    heard = {e.meta["via"] for e in events(fleet, FrameReceived, "surface") if e.src == "far"}
    assert heard == {"r1", "r2"}
    # reliable commands: delivered once or reported failed, none twice, none unreported
    got = [v["x"] for _, v in published(fleet, "far", "far/goto")]  # type: ignore[index]
    assert len(got) == len(set(got))
    final = [(d.ref, d.state) for d in events(fleet, Delivery, "surface")
             if d.state in ("delivered", "failed")]
    assert len(final) == len({ref for ref, _ in final}) == 30
    delivered = {ref for ref, state in final if state == "delivered"}
    assert delivered == {f"g{x}" for x in got}
    assert len(delivered) >= 27
    dropped = {n: c.stats.frames_dropped for n, c in fleet.cores.items()}
    assert all(not (set(d) - {"duplicate", "expired"}) for d in dropped.values()), dropped
    # queries: one reply each, through whichever relay, or an error (a request or reply
    # lost: queries are not retried), never two
    answered = 0
    for at, result in zip(GETS, gets, strict=True):
        assert result.done, at
        if result.error is not None:
            assert "no reply" in result.error and not result.replies, (at, result.error)
            continue
        assert [value for _, value, _ in result.replies] == [{"battery": 77}], at
        answered += 1
    assert answered >= 4


def test_with_both_relays_up_only_the_chosen_one_carries() -> None:
    fleet = FastFleet(diamond(), seed=4)
    for i in range(30):
        fleet.put("far", "far/status", {"n": i}, at=1.0 + 10 * i)
    fleet.run_until(310.0)
    assert not events(fleet, FrameRelayed, "r2")  # it hears everything, and carries nothing
    assert len(events(fleet, FrameRelayed, "r1")) >= 15  # (one value per ~18 s: TDMA)
    assert not events(fleet, RouteSwitched)
    assert fleet.cores["surface"].stats.frames_dropped["duplicate"] == 0


@pytest.mark.parametrize(("old", "new", "words"), [
    # loops that only a listed alternative takes
    ("r1: {address: 2,", "r1: {address: 2, routes: {far: [r2, surface]},",
     "nodes.r1.routes: r1 to far: routing loop r1 -> surface -> r1"),
    ("r2: {address: 3,", "r2: {address: 3, routes: {far: [r1, surface]},",
     "nodes.r2.routes: r2 to far: routing loop r2 -> surface -> r2"),
    ("routes: {far: [r1, r2]}", "routes: {far: [r1, nobody]}",
     "nodes.surface.routes.far[1]: unknown node 'nobody'"),
    ("routes: {far: [r1, r2]}", "routes: {far: [r1, r2], r1: far}",
     "nodes.surface.routes.r1: surface shares no link with far"),
    ("routes: {far: [r1, r2]}", "routes: {far: [r1, far]}",
     "nodes.surface.routes.far[1]: surface cannot route far through far"),
    ("routes: {far: [r1, r2]}", "routes: {far: [r1, r1]}", "a hop listed twice"),
    ("routes: {far: [r1, r2]}", "routes: {far: []}", "name at least one hop"),
    ("routes: {far: [r1, r2]}", "routes: {far: [r1, r2], default: [r2, r1]}",
     "list the same ones in the same order"),
    ("mission: diamond", "mission: diamond\nmax_hops: 1", "takes more than max_hops 1"),
])
def test_mistakes_in_listed_routes_are_refused_with_their_place(old: str, new: str,
                                                                words: str) -> None:
    assert old in DIAMOND
    with pytest.raises(MissionProblems) as caught:
        diamond(DIAMOND.replace(old, new, 1))
    assert words in str(caught.value)
