"""A network, not a star (issue 29), on the virtual clock through the one core: several links
per node, the link policy's failover and failback, relays along static routes, and what
crosses hops end to end (reliable values, queries, authentication)."""

from __future__ import annotations

import io
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from bridge.core.events import Delivery, FrameReceived, FrameRelayed, FrameSent, LinkSwitched
from bridge.core.loaded import LoadedMission, load_mission, parse_mission
from bridge.core.node import Publish
from bridge.image.formats import write_image
from bridge.image.synthetic import seabed
from bridge.mission.loader import MissionProblems
from bridge.runtime.virtual_fleet import FastFleet

MISSIONS = Path(__file__).resolve().parents[2] / "deploy" / "missions"
KEY = bytes(range(32))

# Seed 002 as the paper has it: ROV2 carries only an RF modem, 3 m from ROV1, out of the
# surface's reach; ROV1 relays.
UMCI = """\
mission: umci
{auth}
links:
  acoustic:
    kind: acoustic
    modem: {{backend: sim, frame_bytes: 64, options: {{preset: s2cr-burst}}}}
    mac: {{type: tdma, slot_s: 3.0, guard_s: 0.3, order: [surface, rov1]}}
    nodes: [surface, rov1]
  rf:
    kind: rf
    modem: {{backend: sim, frame_bytes: 64, options: {{preset: s100-rf}}}}
    mac: {{type: polled, master: rov1}}
    nodes: [rov1, rov2]
    link: {{degraded_after_s: 3, down_after_s: 6}}
nodes:
  surface: {{address: 1, role: surface, position: {{x: 0, y: 0, depth: 0}}, routes: {{rov2: rov1}}}}
  rov1: {{address: 2, position: {{x: 500, y: 0, depth: 30}}}}
  rov2: {{address: 3, position: {{x: {rov2_x}, y: 0, depth: 30}}, routes: {{surface: rov1}}}}
channels:
  - name: status
    from: [rov1, rov2]
    to: surface
    interval_s: 10
    elements:
      - in: "{{node}}/status"
        out: "{{src}}/status"
        fields: [{{field: n, type: int, min: 0, max: 1023}}]
  - name: goto
    from: surface
    to: rov2
    reliable: true
    retries: 3
    elements:
      - in: goto
        out: rov2/goto
        fields: [{{field: x, type: int, min: 0, max: 255}}]
queries:
  - name: info
    key: "{{node}}/info"
    serve: rov2
    ask: surface
    reply: [{{field: battery, type: int, min: 0, max: 100}}]
"""


def umci(rov2_x: float = 503, auth: bool = False) -> LoadedMission:
    return parse_mission(UMCI.format(rov2_x=rov2_x, auth="wire: {auth: {tag_bytes: 4}}"
                                     if auth else ""), "umci.yaml")


def published(fleet: FastFleet, node: str, key: str) -> list[object]:
    return [p.value for _, p in fleet.published(node, key)]


def events(fleet: FastFleet, kind: type, node: str | None = None) -> list:
    return [t.output for t in fleet.outputs
            if isinstance(t.output, kind) and (node is None or t.node == node)]


def run_umci(loaded: LoadedMission, until: float = 300.0, **kwargs: object) -> FastFleet:
    fleet = FastFleet(loaded, seed=1, key=KEY if loaded.mission.wire.auth else None,
                      **kwargs)  # type: ignore[arg-type]
    for i in range(int(until // 10) - 2):
        fleet.put("rov2", "rov2/status", {"n": i}, at=1.0 + 10 * i)
        fleet.put("rov1", "rov1/status", {"n": 500 + i}, at=1.0 + 10 * i)
    for i in range(4):
        fleet.put("surface", "goto", {"x": i}, at=20.0 + 40 * i, ref=f"g{i}")
    fleet.run_until(until)
    return fleet


@pytest.mark.parametrize("auth", [False, True], ids=["plain", "auth"])
def test_a_relay_carries_puts_both_ways_and_reliable_values_end_to_end(auth: bool) -> None:
    fleet = run_umci(umci(auth=auth))
    from_rov2 = published(fleet, "surface", "rov2/status")
    assert len(from_rov2) >= 20 and len(set(map(str, from_rov2))) == len(from_rov2)
    assert len(published(fleet, "surface", "rov1/status")) >= 20
    assert published(fleet, "rov2", "rov2/goto") == [{"x": i} for i in range(4)]  # once each
    reports = [d for d in events(fleet, Delivery, "surface") if d.state == "delivered"]
    assert sorted(d.ref for d in reports) == ["g0", "g1", "g2", "g3"]  # end to end, once
    delivered_at = {d.ref: d.time for d in reports}
    arrived = [t.time for t in fleet.outputs if t.node == "rov2"
               and isinstance(t.output, Publish) and t.output.key == "rov2/goto"]
    assert all(delivered_at[f"g{i}"] > arrived[i] for i in range(4))  # it has it, then says so
    relayed = Counter((e.origin, e.link) for e in events(fleet, FrameRelayed, "rov1"))
    assert relayed[("rov2", "acoustic")] >= 20 and relayed[("surface", "rf")] >= 4
    heard = [e for e in events(fleet, FrameReceived, "surface") if e.src == "rov2"]
    assert heard and all(e.meta["via"] == "rov1" and e.meta["hops"] == 1 for e in heard)
    assert not events(fleet, FrameSent, "rov2") or {e.link for e in events(fleet, FrameSent,
                                                                             "rov2")} == {"rf"}
    dropped = {n: c.stats.frames_dropped for n, c in fleet.cores.items()}
    assert all(not (set(d) - {"duplicate"}) for d in dropped.values()), dropped


def test_a_get_at_the_surface_is_answered_on_the_node_behind_the_relay() -> None:
    fleet = FastFleet(umci(), seed=2)
    fleet.queries.queryable("rov2", "rov2/info", lambda params: [{"battery": 77}])
    fleet.run_until(30.0)
    result = fleet.queries.get("surface", "rov2/info")
    fleet.run_until(120.0)
    assert result.done and result.error is None
    assert [value for _, value, _ in result.replies] == [{"battery": 77}]


CAMERA = """\
images:
  - name: camera
    from: rov2
    to: surface
    in: rov2/camera
    out: rov2/camera
    control: rov2/camera/control
    width: 160
    height: 120
    budget_bytes: 600
    publish_interval_s: 0
"""


def test_a_picture_behind_the_relay_sharpens_at_the_surface_and_takes_its_roi() -> None:
    """Seed 002's feedback from the ROV the surface reaches only through ROV1 (CAPTURE's
    multi-hop pictures): the operator's ROI crosses the relay one way, the picture the other."""
    fleet = FastFleet(parse_mission(UMCI.format(rov2_x=503, auth="") + CAMERA, "umci.yaml"),
                      seed=3)
    fleet.put("surface", "rov2/camera/control", {"roi": [0.0, 0.0, 0.5, 0.5],
                                                 "budget_bytes": 400, "request": "none"}, at=1.0)
    picture = seabed(120, 160, seed=4, colour=False)
    fleet.put("rov2", "rov2/camera", write_image(picture, "jpeg", quality=92),
              encoding="image/jpeg", at=40.0)
    fleet.run_until(200.0)
    shown = [Image.open(io.BytesIO(p.value)) for _, p in fleet.published("surface",
                                                                         "rov2/camera")]
    texts = [dict(image.text) for image in shown]  # type: ignore[attr-defined]
    assert len(shown) >= 4
    sizes = [int(t["zab:bytes"]) for t in texts]
    assert sizes == sorted(sizes) and texts[-1]["zab:final"] == "true"
    assert texts[-1]["zab:roi"] == "[0.0, 0.0, 0.5, 0.5]" and sizes[-1] <= 400
    error = np.asarray(shown[-1]).astype(float) - picture
    roi, rest = (10 * np.log10(255 ** 2 / float(np.mean(e ** 2)))
                 for e in (error[:60, :80], error[60:, 80:]))
    assert roi > 35 and roi > rest + 10  # (the ROI's top left quarter against the far one)
    relayed = Counter(e.origin for e in events(fleet, FrameRelayed, "rov1"))
    assert relayed["rov2"] >= 4 and relayed["surface"] >= 1


def test_a_route_nobody_reaches_fails_naming_the_missing_hop() -> None:
    fleet = run_umci(umci(rov2_x=530), until=600.0)  # 30 m: beyond the S100's 5 m
    failed = [d for d in events(fleet, Delivery, "surface") if d.state == "failed"]
    assert {d.ref for d in failed} == {"g0", "g1", "g2", "g3"}
    assert all("route surface -> rov1 -> rov2: the hop rov1 -> rov2 is missing (rov2 never "
               "heard)" in (d.reason or "") for d in failed), failed[0].reason
    assert not published(fleet, "rov2", "rov2/goto")
    result = fleet.queries.get("surface", "rov2/info")  # its first hop is up: it goes
    fleet.run_until(700.0)
    assert result.done and "no reply" in (result.error or "") \
        and "the hop rov1 -> rov2 is missing" in (result.error or "")
    fleet.stop("rov1")
    fleet.run_until(900.0)  # the first hop is down too: a get ends at once
    result = fleet.queries.get("surface", "rov2/info")
    assert result.done and "no route to rov2" in (result.error or "") \
        and "the hop surface -> rov1 is missing" in (result.error or "")


@pytest.mark.parametrize("keep_state", [True, False], ids=["with-state", "without-state"])
@pytest.mark.parametrize("victim", ["surface", "rov1", "rov2"])
def test_any_node_on_the_route_killed_and_restarted_never_delivers_twice(
        victim: str, keep_state: bool) -> None:
    fleet = FastFleet(umci(), seed=3)
    for i in range(12):
        fleet.put("surface", "goto", {"x": i}, at=5.0 + 15 * i, ref=f"g{i}")
    for t in (40.0, 95.0):
        fleet.run_until(t)
        fleet.stop(victim)  # kill -9: a relay loses what it carried, an end its memory
        fleet.run_until(t + 12.0)
        fleet.restart(victim, keep_state=keep_state)
    fleet.run_until(900.0)
    got = published(fleet, "rov2", "rov2/goto")
    assert len(got) == len({str(v) for v in got})  # never twice
    final = {d.ref: d.state for d in events(fleet, Delivery, "surface")
             if d.state in ("delivered", "failed")}
    down = [(40.0, 52.0), (95.0, 107.0)] if victim == "surface" else []  # its puts are lost
    accepted = {f"g{i}" for i in range(12)
                if not any(a < 5.0 + 15 * i < b for a, b in down)}
    if victim == "surface" and not keep_state:  # its disk lost: what it held, unreported
        assert set(final) <= accepted
    else:
        assert set(final) == accepted  # every value its bridge took reported, once
    assert sum(state == "delivered" for state in final.values()) == len(got)


def test_traffic_fails_over_to_acoustics_and_back_as_rov2_drifts_out_of_rf_range() -> None:
    loaded = load_mission(MISSIONS / "umci_relay.yaml")
    fleet = FastFleet(loaded, seed=1)
    for i in range(50):
        fleet.put("rov2", "rov2/status", {"x": i, "depth": 10, "battery": 90}, at=1.0 + 10 * i)
    fleet.run_until(500.0)
    switches = [(e.peer, e.was, e.link, e.reason) for e in events(fleet, LinkSwitched, "rov2")]
    assert ("surface", "rf", "acoustic", "failover") in switches
    assert ("surface", "acoustic", "rf", "failback") in switches
    # the drift: RF is out of range beyond 5 m, and the values keep coming, once each
    sent = Counter(e.link for e in events(fleet, FrameSent, "rov2") if "status" in e.channels)
    assert sent["rf"] >= 5 and sent["acoustic"] >= 5
    got = [v["x"] for v in published(fleet, "surface", "rov2/status")]  # type: ignore[index]
    assert len(got) >= 35 and len(got) == len(set(got)) and got == sorted(got)


def test_a_line_of_four_reaches_end_to_end_through_two_relays() -> None:
    fleet = FastFleet(load_mission(MISSIONS / "acoustic_line.yaml"), seed=5)
    for i in range(10):
        for node in ("n1", "n2", "tail"):
            fleet.put(node, f"{node}/pose", {"x": i, "depth": 50}, at=1.0 + 30 * i)
    fleet.put("head", "tail/abort", {"reason": "weather"}, at=10.0, ref="a")
    fleet.run_until(320.0)
    poses = published(fleet, "head", "tail/pose")
    assert len(poses) >= 8
    hops = {e.meta.get("hops") for e in events(fleet, FrameReceived, "head") if e.src == "tail"}
    assert hops == {2}
    assert published(fleet, "tail", "tail/abort") == [{"reason": "weather"}]
    assert [d.state for d in events(fleet, Delivery, "head") if d.state not in
            ("queued", "sent")] == ["delivered"]
    ocean = fleet.ocean.stats()
    lost = Counter(r for link in ocean["links"] for r in link["lost"])
    assert lost["out_of_range"] > 0  # the ends really are out of each other's reach


@pytest.mark.parametrize(("old", "new", "words"), [
    ("rov1: {address: 2,", "rov1: {address: 2, routes: {rov2: surface},",
     "nodes.rov1.routes: rov1 to rov2: routing loop rov1 -> surface -> rov1"),
    ("routes: {surface: rov1}", "routes: {surface: nobody}", "unknown node 'nobody'"),
    ("routes: {surface: rov1}}", "routes: {surface: rov1}, prefer: [wifi]}",
     "unknown link 'wifi' (links: acoustic, rf)"),
    ("links:", "modem: {frame_bytes: 32}\nlinks:", "give modem per link in `links`"),
    ("nodes: [rov1, rov2]", "nodes: [rov1]", "rov2 is on no link"),
    ("routes: {rov2: rov1}", "routes: {rov2: rov2}", "cannot route rov2 through rov2"),
    ("routes: {rov2: rov1}", "routes: {rov2: rov1, surface: rov1}",
     "nodes.surface.routes.surface: a route from surface to itself"),
    ("mission: umci", "mission: umci\nmax_hops: 1", "takes more than max_hops 1"),
    ("mission: umci", "mission: umci\nwire: {dlbl: true}", "DLBL ranging over several links"),
])
def test_mistakes_in_links_and_routes_are_refused_with_their_place(old: str, new: str,
                                                                   words: str) -> None:
    text = UMCI.format(rov2_x=503, auth="")
    assert old in text
    with pytest.raises(MissionProblems) as caught:
        parse_mission(text.replace(old, new, 1), "bad.yaml")
    assert words in str(caught.value)


def _frame_for(core: object, now: float, link: str) -> bytes:
    """What ``core`` sends at its next opportunity on ``link`` (at or after ``now``)."""
    from bridge.core.node import NodeCore, SendFrame
    assert isinstance(core, NodeCore)
    at = core.wake_at(now, link)
    assert at is not None
    action = core.act(at, at, link)
    assert isinstance(action, SendFrame)
    core.done(action, at, at + 0.1)
    return action.frame.data


def test_a_relay_can_neither_forge_nor_replay_what_it_carries() -> None:
    import random

    from bridge.core.node import NodeCore
    from bridge.core.reception import Reception
    from bridge.wire.frame import CHECK_BYTES, check_value

    loaded = umci(auth=True)
    cores = {n: NodeCore(loaded, n, key=KEY, rng=random.Random(n)) for n in loaded.mission.nodes}
    surface, rov1, rov2 = cores["surface"], cores["rov1"], cores["rov2"]
    surface.ingest("goto", b"\x81\xa1x\x07", "application/msgpack", 1.0)  # {"x": 7}
    sent = _frame_for(surface, 1.0, "acoustic")
    rov1.receive(Reception(sent, 1, 7.0), 7.0, 7.0, "acoustic")
    carried = _frame_for(rov1, 7.5, "rf")  # the frame it carries for rov2
    sealed = slice(-CHECK_BYTES - 12, -CHECK_BYTES)
    assert carried[sealed] == sent[sealed]  # the same sealed frame, behind a new header

    def heard(data: bytes, t: float) -> list[object]:
        rov2.receive(Reception(data, 2, t), t, t, "rf")
        return rov2.take()

    body = bytearray(carried[:-CHECK_BYTES])
    body[-10] ^= 0x01  # the relay alters the value inside, and fixes the check
    forged = bytes(body) + check_value(bytes(body), loaded.table.fingerprint)
    assert not [o for o in heard(forged, 8.0) if isinstance(o, Publish)]
    assert rov2.stats.frames_dropped["forged"] == 1
    assert [o.value for o in heard(carried, 8.5) if isinstance(o, Publish)] == [{"x": 7}]
    assert not [o for o in heard(carried, 9.0) if isinstance(o, Publish)]  # again: a copy
    assert rov2.stats.frames_dropped["duplicate"] == 1
    restarted = NodeCore(loaded, "rov2", key=KEY, state=rov2.state(), rng=random.Random(9))
    rov2 = restarted  # (its memory of copies is gone; its replay window is not)
    assert not [o for o in heard(carried, 20.0) if isinstance(o, Publish)]
    assert rov2.stats.frames_dropped["replayed"] == 1


def test_interest_bitmaps_cross_the_relays_of_a_demand_mission() -> None:
    text = (MISSIONS / "acoustic_line.yaml").read_text().replace(
        "channels:", "demand: {refresh_s: 60}\nchannels:")
    fleet = FastFleet(parse_mission(text, "line-demand.yaml"), seed=6)
    for i in range(30):
        fleet.put("tail", "tail/pose", {"x": i, "depth": 50}, at=1.0 + 20 * i)
    fleet.run_until(200.0)
    assert not published(fleet, "head", "tail/pose")  # nobody at the head wants it yet
    assert not [e for e in events(fleet, FrameSent, "tail") if "pose" in e.channels]
    fleet.subscribe("head", "tail/pose")  # an application subscribes at the head
    fleet.run_until(600.0)
    got = published(fleet, "head", "tail/pose")
    assert len(got) >= 8  # its @want went 3 hops to the tail, the poses 3 hops back
    wanted = fleet.cores["tail"].interest
    assert wanted is not None and "pose" in wanted.snapshot(fleet.loaded.table)["peers"]["head"]


def test_a_restarted_origin_numbers_its_routed_frames_past_those_it_used() -> None:
    import random

    from bridge.core.node import NodeCore

    loaded = umci()
    net = loaded.table.net
    assert net is not None
    surface = NodeCore(loaded, "surface", rng=random.Random(1))
    used = []
    t = 0.0
    for i in range(40):  # 40 routed frames: one save per 32 of them
        surface.ingest("goto", b"\x81\xa1x" + bytes([i]), "application/msgpack", t)
        data = _frame_for(surface, t, "acoustic")
        header, _ = net.decode(data)
        used.append(header.seq)
        t += 7.0
    saved = surface.state()
    again = NodeCore(loaded, "surface", state=saved, rng=random.Random(2))
    again.ingest("goto", b"\x81\xa1x\x63", "application/msgpack", t)
    header, _ = net.decode(_frame_for(again, t, "acoustic"))
    assert header.routed and header.seq not in used[-64:]  # never taken for a copy


FEED = """\
  - name: feed
    from: [rov1, rov2]
    to: surface
    elements:
      - in: "{node}/feed"
        out: "{src}/feed"
        fields: [FIELDS]
""".replace("FIELDS", ", ".join(
    f"{{field: {f}, type: int, min: 0, max: 4294967295}}" for f in ("n", *"abcdefgh")))


def test_a_relays_own_values_take_turns_with_those_it_carries_at_the_same_priority() -> None:
    """rov1 relays rov2's feed and sends its own, the same channel, each value nearly a frame:
    at equal rank they take turns (before, rov1's own never went while rov2's kept coming:
    0 of 300 in 600 s, against 100 of rov2's)."""
    head, tail = UMCI.format(rov2_x=503, auth="").split("queries:")
    fleet = FastFleet(parse_mission(f"{head}{FEED}queries:{tail}", "feed.yaml"), seed=1)
    for i in range(300):
        for node in ("rov1", "rov2"):
            fleet.put(node, f"{node}/feed", {"n": i, **dict.fromkeys("abcdefgh", 2**31)},
                      at=1.0 + 2 * i)
    fleet.run_until(600)
    rov1, rov2 = (len(published(fleet, "surface", f"{n}/feed")) for n in ("rov1", "rov2"))
    assert rov1 >= 40 and rov2 >= 40 and abs(rov1 - rov2) <= 4, (rov1, rov2)


@pytest.mark.parametrize("drift", [False, True], ids=["rov2-near", "rov2-drifting"])
def test_a_picture_behind_a_slow_relay_crosses_whole_sent_about_once(drift: bool) -> None:
    """umci_relay with a camera on ROV2: ROV2 sends a fragment a second over RF, ROV1 carries
    one every 7.5 s on to the surface over acoustics, so a fragment waits minutes in its
    queue. Before, ROV2 sent again what was still queued (after retry_s, and at each
    acknowledgement that showed a gap the queued copy had not filled yet): the picture failed
    after 11 copies of one fragment. Drifting (RF lost and back, the surface hearing ROV2
    directly), the surface refused ROV2's relayed frames as replayed (more than 64 counters
    behind what it had heard), and the picture took over 1000 s."""
    text = (MISSIONS / "umci_relay.yaml").read_text() + CAMERA.replace(
        "budget_bytes: 600", "budget_bytes: 1600").replace("publish_interval_s: 0",
                                                            "publish_interval_s: 5")
    if not drift:  # ROV2 holds 3 m from ROV1, always in RF range
        text = text.replace("{x: 408,", "{x: 403,")
    loaded = parse_mission(text, "umci_camera.yaml")
    fleet = FastFleet(loaded, seed=3, key=KEY)
    picture = seabed(120, 160, seed=4, colour=False)
    fleet.put("rov2", "rov2/camera", write_image(picture, "jpeg", quality=92),
              encoding="image/jpeg", at=10.0)
    fleet.run_until(1000.0)
    finals = [t for t, p in fleet.published("surface", "rov2/camera")
              if Image.open(io.BytesIO(p.value)).text["zab:final"] == "true"]  # type: ignore[attr-defined]
    from bridge.report.check import check_mission

    [bound] = check_mission(loaded).data["images"]
    assert len(finals) == 1 and finals[0] - 10.0 <= bound["seconds_per_picture"]
    sent = fleet.cores["rov2"].stats.sent_per_channel["camera"]
    assert sent <= 1.4 * bound["fragments_per_picture"]  # (before: 115 and 92 of 48)
    assert "replayed" not in fleet.cores["surface"].stats.frames_dropped


def test_zab_check_warns_of_a_channel_and_a_query_with_no_route() -> None:
    """Without the surface's route through ROV1, neither the operator's command nor its get
    can reach ROV2: zab check says so for both (it said nothing of the query)."""
    from bridge.report.check import check_mission

    text = UMCI.format(rov2_x=503, auth="").replace(", routes: {rov2: rov1}}", "}")
    warnings = check_mission(parse_mission(text, "no_route.yaml")).warnings
    assert "channel 'goto': surface to rov2: surface has no route to rov2" in warnings
    assert "query 'info': surface asking rov2: surface has no route to rov2" in warnings
