"""One pub/sub space: values put at one node's Zenoh endpoint arrive decoded at another's.

The outside sessions use only ``zenoh`` and ``msgpack`` (see tests/harness.py), standing for
an application written in any language.
"""

from __future__ import annotations

import asyncio
import time

import msgpack
import pytest

from bridge.modems.base import ModemSetup
from bridge.modems.udp import UdpBackend
from bridge.wire.auth import Authenticator
from bridge.wire.frame import FrameCodec
from tests.conftest import MISSIONS, mission_on_free_ports, on_free_ports, udp_ports
from tests.harness import (
    Inbox,
    listing1_crosses_in_the_next_slot,
    outside_session,
    put,
    running_fleet,
)


def test_target_reference_crosses_the_simulated_ocean() -> None:
    loaded = mission_on_free_ports(MISSIONS / "morph.yaml")
    with running_fleet(loaded) as fleet:
        listing1_crosses_in_the_next_slot(loaded)
        assert fleet.nodes["gcv"].stats.received_per_channel["target_reference"] == 1


LAB = """\
mission: lab
modem: {backend: udp, frame_bytes: 16}
mac: {type: none, min_gap_s: 0.4}
nodes:
  a: {address: 1, modem: {options: {port: PORT_A}}}
  b: {address: 2, modem: {options: {port: PORT_B}}}
channels:
  - name: fast
    from: a
    to: b
    elements: [{in: fast, out: a/fast, fields: [{field: v, type: int, min: 0, max: 100}]}]
  - name: slow
    from: a
    to: b
    interval_s: 1.0
    elements: [{in: slow, out: a/slow, fields: [{field: v, type: int, min: 0, max: 1000}]}]
  - name: latched
    from: a
    to: b
    latching: true
    interval_s: 0.5
    elements: [{in: latched, out: a/latched, fields: [{field: v, type: int, min: 0, max: 7}]}]
  - name: big_low
    from: a
    to: b
    elements: [{in: big_low, out: a/big_low, fields: [{field: v, bits: 60, min: 0, max: 1}]}]
  - name: big_high
    from: a
    to: b
    priority: 5
    elements: [{in: big_high, out: a/big_high, fields: [{field: v, bits: 60, min: 0, max: 1}]}]
  - name: echo
    from: b
    to: a
    elements: [{in: a/fast, out: b/echo, fields: [{field: v, type: int, min: 0, max: 100}]}]
"""


@pytest.fixture(scope="module")
def lab():
    text = udp_ports(LAB)
    loaded = on_free_ports(text, "lab.yaml")
    with running_fleet(loaded) as fleet:
        a, b = outside_session(loaded, "a"), outside_session(loaded, "b")
        try:
            yield loaded, fleet, a, b
        finally:
            a.close()
            b.close()


def subscribe(session, key: str) -> Inbox:
    inbox = Inbox()
    session.declare_subscriber(key, inbox)
    time.sleep(0.2)  # let the declaration reach the bridge's session
    return inbox


def test_newest_overwrites_older(lab) -> None:
    _, _, a, b = lab
    inbox = subscribe(b, "a/fast")
    put(a, "fast", {"v": 0})  # leaves at once; the next frame waits min_gap_s
    time.sleep(0.05)
    for v in (1, 2, 3, 4):  # all arrive within the gap: only the newest is sent
        put(a, "fast", {"v": v})
    values = [v["v"] for _, v, _ in inbox.drain(1.5)]
    assert values == [0, 4]


def test_latching_repeats_and_late_subscriber_gets_last_value(lab) -> None:
    loaded, _, a, b = lab
    inbox = subscribe(b, "a/latched")
    put(a, "latched", {"v": 5})
    got = inbox.drain(2.5)
    assert len(got) >= 3 and {v["v"] for _, v, _ in got} == {5}
    late = outside_session(loaded, "b")
    try:
        replies = list(late.get("a/latched", timeout=2.0))
        values = [msgpack.unpackb(r.ok.payload.to_bytes()) for r in replies if r.ok]
        assert values == [{"v": 5}]
    finally:
        late.close()


def test_interval_throttles(lab) -> None:
    _, _, a, b = lab
    inbox = subscribe(b, "a/slow")
    end = time.time() + 3.0
    v = 0
    while time.time() < end:
        put(a, "slow", {"v": v})
        v += 1
        time.sleep(0.05)
    got = inbox.drain(1.5)
    assert 2 <= len(got) <= 5, got  # about one per second, never each of the ~60 puts


def test_priority_under_a_full_frame(lab) -> None:
    _, _, a, b = lab
    low, high = subscribe(b, "a/big_low"), subscribe(b, "a/big_high")
    put(a, "fast", {"v": 9})  # a frame leaves now; the next waits min_gap_s
    time.sleep(0.05)
    put(a, "big_low", {"v": 0.25})
    put(a, "big_high", {"v": 0.75})  # both due, only one 60-bit channel fits in 16 bytes
    _, v_high, t_high = high.get(timeout=3)
    _, v_low, t_low = low.get(timeout=3)
    assert t_high < t_low
    assert abs(v_high["v"] - 0.75) < 1e-9 and abs(v_low["v"] - 0.25) < 1e-9


def test_loop_safety(lab) -> None:
    _, _fleet, a, b = lab
    echo = subscribe(a, "b/echo")
    put(a, "fast", {"v": 11})  # reaches b as a/fast, published by b's bridge: not re-bridged
    assert echo.drain(1.5) == []
    put(b, "a/fast", {"v": 12})  # an application at b using that key IS bridged back
    _, value, _ = echo.get(timeout=3)
    assert value == {"v": 12}


def test_malformed_payloads_are_counted_and_skipped(lab) -> None:
    _, fleet, a, b = lab
    inbox = subscribe(b, "a/fast")
    a.put("fast", b"\xc1\xc1", encoding="application/msgpack")
    put(a, "fast", {"wrong": 1})
    put(a, "fast", "a string")
    dropped = fleet.nodes["a"].stats.payloads_dropped
    deadline = time.time() + 10  # a loaded machine may take a while; no fixed wait
    while dropped["fast"] < 3 and time.time() < deadline:
        time.sleep(0.05)
    time.sleep(0.2)  # and no fourth drop after them
    assert dropped["fast"] == 3
    put(a, "fast", {"v": 42})
    assert any(v == {"v": 42} for _, v, _ in inbox.drain(1.5))


def test_mismatched_mission_is_detected_and_counted(lab) -> None:
    loaded, fleet, _, _ = lab
    other = loaded.mission.model_copy(deep=True)
    fields = other.channels[0].elements[0].fields
    fields[0] = fields[0].model_copy(update={"max": 200})
    foreign = FrameCodec(type(loaded.table).from_mission(other))
    target = foreign.table.channels[0]
    before = fleet.nodes["b"].stats.frames_dropped["check"]
    port_b = loaded.mission.nodes["b"].modem.options["port"]

    async def send() -> None:
        setup = ModemSetup(node="a", address=1, frame_bytes=16, options={"port": 0},
                           peers={2: {"port": port_b}})
        async with UdpBackend(setup) as modem:
            await modem.send(foreign.encode([(target, 50)], []), None)
            await asyncio.sleep(0.3)

    asyncio.run(send())
    assert fleet.nodes["b"].stats.frames_dropped["check"] == before + 1


RF_PAIR = """\
mission: rf
modem: {backend: sim, frame_bytes: 32, options: {preset: s100-rf, seed: 7}}
mac: {type: none, min_gap_s: 0.3}
nodes:
  a: {address: 1, position: {x: 0, y: 0, depth: 1}}
  b: {address: 2, position: {x: 2, y: 0, depth: 1}, nav_key: nav}
channels:
  - name: ping
    from: a
    to: b
    latching: true
    elements: [{in: ping, out: a/ping, fields: [{field: n, type: int, min: 0, max: 255}]}]
"""


def test_live_position_moves_a_node_out_of_and_back_into_range() -> None:
    loaded = on_free_ports(RF_PAIR, "rf.yaml")
    with running_fleet(loaded) as fleet:
        a, b = outside_session(loaded, "a"), outside_session(loaded, "b")
        try:
            inbox = subscribe(b, "a/ping")
            put(a, "ping", {"n": 1})
            assert inbox.drain(1.0), "in range (2 m of 5 m): the latched ping arrives"
            put(b, "nav", {"x": 50.0, "y": 0.0, "depth": 1.0})  # beyond the RF modem's 5 m
            time.sleep(0.5)
            inbox.drain(0.1)
            assert inbox.drain(1.5) == []
            lost = next(link for link in fleet.report().links if link.name == "a->b")
            assert lost.lost.get("out_of_range", 0) >= 2
            put(b, "nav", {"x": 3.0, "y": 0.0, "depth": 1.0})
            assert inbox.drain(1.5), "back in range"
            put(b, "nav", {"x": "far"})
            time.sleep(0.3)
            assert fleet.nodes["b"].stats.payloads_dropped["nav"] == 1
        finally:
            a.close()
            b.close()


def test_stats_and_peers_under_the_reserved_prefix(lab) -> None:
    _, _, a, b = lab
    wildcard = subscribe(b, "**")
    stats = subscribe(b, "@zab/lab/b/stats")
    peers = subscribe(b, "@zab/lab/b/peers/a")
    put(a, "fast", {"v": 33})
    _, snapshot, _ = stats.get(timeout=3)
    assert snapshot["node"] == "b" and snapshot["frames_received"] >= 1
    assert {"frames_sent", "frames_dropped", "payloads_dropped", "channel_age_s"} <= set(snapshot)
    _, peer, _ = peers.get(timeout=3)
    assert peer["last_heard"] > 0
    keys = {key for key, _, _ in wildcard.drain(1.2)}
    assert "a/fast" in keys and not any(k.startswith("@zab") for k in keys)


def test_authenticated_mission_delivers_and_refuses_forgeries(monkeypatch) -> None:
    monkeypatch.setenv("ZAB_KEY", "lab-key-0123456789abcdef")
    text = udp_ports(LAB).replace(
        "mac: {type: none", "wire: {auth: {tag_bytes: 6}}\nmac: {type: none")
    loaded = on_free_ports(text, "lab-auth.yaml")
    with running_fleet(loaded) as fleet:
        a, b = outside_session(loaded, "a"), outside_session(loaded, "b")
        try:
            inbox = subscribe(b, "a/fast")
            put(a, "fast", {"v": 21})
            assert inbox.get(timeout=3)[1] == {"v": 21}
            forger = Authenticator(b"not-the-mission-key!", loaded.table.fingerprint, 1, 6)
            forged = FrameCodec(loaded.table, forger).encode(
                [(loaded.table.channels[0], 99)], [])
            port_b = loaded.mission.nodes["b"].modem.options["port"]

            async def send() -> None:
                setup = ModemSetup(node="a", address=1, frame_bytes=16, options={"port": 0},
                                   peers={2: {"port": port_b}})
                async with UdpBackend(setup) as modem:
                    await modem.send(forged, None)
                    await asyncio.sleep(0.3)

            asyncio.run(send())
            assert fleet.nodes["b"].stats.frames_dropped["forged"] == 1
            assert all(v != {"v": 99} for _, v, _ in inbox.drain(0.5))
        finally:
            a.close()
            b.close()


def test_link_goes_down_when_a_node_stops_and_up_when_it_returns() -> None:
    text = udp_ports(LAB).replace(
        "mac: {type: none", "link: {degraded_after_s: 0.6, down_after_s: 1.2, heartbeat_s: 0.3}\n"
        "mac: {type: none")
    loaded = on_free_ports(text, "lab-link.yaml")
    with running_fleet(loaded, only=["b"]) as fleet_b:
        app = outside_session(loaded, "b")
        try:
            tokens = Inbox()
            states = subscribe(app, "@zab/lab/b/link/a")
            app.liveliness().declare_subscriber(
                "@zab/lab/b/link/a",
                lambda s: tokens.items.put((str(s.kind), None, time.time())))
            with running_fleet(loaded, only=["a"]):
                _, first, _ = states.get(timeout=3)
                assert first["state"] == "up"
                assert tokens.get(timeout=3)[0] == "SampleKind.PUT"
            stopped = time.time()
            seen = [v["state"] for _, v, _ in states.drain(2.0)]
            assert seen[-1] == "down" and "degraded" in seen
            kind, _, when = tokens.get(timeout=1)
            assert kind == "SampleKind.DELETE" and when - stopped <= 1.2 + 0.5
            assert fleet_b.nodes["b"].link_states["a"].value == "down"
            with running_fleet(loaded, only=["a"]):
                _, back, _ = states.get(timeout=3)
                assert back["state"] == "up"
                assert tokens.get(timeout=3)[0] == "SampleKind.PUT"
        finally:
            app.close()
