"""Lanes (#14): ``ingest_and_act`` takes a short way, and ends where ``ingest`` + ``act`` do.

Two cores of one mission, one seed: one takes each sample the general way, the other through
its lanes (and reports what it sent with ``sent``, whose books wait for the next call or
``settle``); every action, output, counter and saved state must be the same, sample by sample,
over generated missions (several channels and keys, intervals, latching, ``ttl_s``, shared
keys, frames too small for all, each MAC, authenticated or not) and generated traffic
(payloads that do not decode or do not fit, transmit opportunities between samples). A channel
too big for the frame is fragmented by the loader, and its node has no lanes: the general way
is checked against itself there.
"""

from __future__ import annotations

import random
from typing import Any

import msgpack
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from bridge.core.node import NodeCore, Ping, SendFrame
from bridge.mission.loader import LoadedMission, parse_mission

ENC = "application/msgpack"
MACS = [
    {"type": "none"},
    {"type": "none", "min_gap_s": 1.5},
    {"type": "tdma", "slot_s": 2.0, "guard_s": 0.5, "order": ["a", "b", "c"]},
    {"type": "aloha", "backoff_s": 1.0},
]


def mission(channels: list[dict[str, Any]], mac: dict[str, Any], frame_bytes: int,
            auth: bool = False) -> dict:
    return {
        "mission": "lanes",
        "wire": {"auth": {"tag_bytes": 4}} if auth else {},
        "modem": {"backend": "udp", "frame_bytes": frame_bytes},
        "mac": mac,
        "nodes": {n: {"address": i + 1} for i, n in enumerate("abc")},
        "channels": channels,
    }


def channel(i: int, keys: list[str], bits: list[int], to: str, interval_s: float,
            latching: bool, ttl_s: float | None) -> dict[str, Any]:
    spec = {
        "name": f"c{i}", "from": "a", "to": to, "interval_s": interval_s, "latching": latching,
        "elements": [{"in": key, "out": f"out/{i}/{key}",
                      "fields": [{"field": "v", "type": "int", "min": 0, "max": (1 << b) - 1}]}
                     for key, b in zip(keys, bits, strict=True)],
    }
    if ttl_s is not None:
        spec["ttl_s"] = ttl_s
    return spec


@st.composite
def missions(draw: st.DrawFn, express: bool = False) -> LoadedMission:
    """Generated missions; ``express``: only of channels an express may carry (one element,
    no MAC to ask, no authentication)."""
    n = draw(st.integers(1, 4))
    channels = []
    for i in range(n):
        elements = 1 if express else draw(st.integers(1, 2))
        keys = ["k0"] if express and i == 0 else \
            [draw(st.sampled_from(["k0", "k1", "k2", "k3"])) for _ in range(elements)]
        if len(set(keys)) < len(keys):
            keys = keys[:1]  # one element per key within a channel
        channels.append(channel(
            i, keys, [draw(st.integers(4, 40)) for _ in keys], draw(st.sampled_from(["b", "b|c"])),
            draw(st.sampled_from([0.1, 1.0, 5.0])),
            draw(st.sampled_from([False, False, False, True] if express else [False, True])),
            draw(st.sampled_from([None, 2.0]))))
    auth = not express and draw(st.booleans())  # (its counter and tag: 12 more bytes a frame)
    frame_bytes = draw(st.sampled_from([8, 12, 24, 64])) + (12 if auth else 0)
    macs = [MACS[0]] * 3 + [MACS[1]] if express else MACS
    text = yaml.safe_dump(mission(channels, draw(st.sampled_from(macs)), frame_bytes, auth))
    return parse_mission(text)


def pair(loaded: LoadedMission) -> tuple[NodeCore, NodeCore]:
    return tuple(NodeCore(loaded, "a", rng=random.Random(7), seed=3,  # type: ignore[return-value]
                          key=b"lanes test key 16")
                 for _ in range(2))


def described(action: SendFrame | Ping | None) -> Any:
    if not isinstance(action, SendFrame):
        return action
    out = action.frame
    return (out.data, out.dest, out.ack, out.at, out.built, action.ranged,
            [s.channel.name for s in out.plan.chosen], [s.channel.name for s in out.plan.left_out],
            [(s.channel.name, s.entry(item)) for s, item in out.streams], out.acks,
            len(out.extras))


def carry_out(core: NodeCore, action: SendFrame | Ping | None, now: float,
              refused: bool = False) -> None:
    if action is not None:
        core.done(action, now, now + 0.3, error="refused" if refused else None)


def express_described(express: tuple, now: float, at: float) -> Any:
    """:func:`described` of the lane frame an express stands for."""
    lane, _, data = express
    return (data, lane.dest, lane.ack, at, now, False, [lane.state.channel.name], [], [], (),
            0)


ops = st.lists(st.tuples(
    st.sampled_from([0.0, 0.05, 0.4, 1.0, 2.5]),  # wait before
    st.sampled_from(["k0", "k1", "k2", "k3", "act"]),  # a sample on a key, or an opportunity
    st.sampled_from(["ok"] * 6 + ["too_big", "garbage", "refused"]),  # (refused: by the modem)
    st.integers(0, 15),
), min_size=1, max_size=40)


@settings(max_examples=150, deadline=None)
@given(missions(), ops)
def test_a_lane_ends_where_ingest_then_act_ends(loaded: LoadedMission, steps: list) -> None:
    run_pair(loaded, steps)


express_ops = st.lists(st.tuples(  # mostly samples on k0, the key of the first channel
    st.sampled_from([0.0, 0.05, 0.4, 1.0, 2.5, 6.0]),
    st.sampled_from(["k0"] * 5 + ["k1", "k2", "act"]),
    st.sampled_from(["ok"] * 6 + ["garbage", "refused"]),
    st.integers(0, 15),
), min_size=1, max_size=40)


@settings(max_examples=200, deadline=None)
@given(missions(express=True), express_ops)
def test_an_express_ends_where_ingest_then_act_ends(loaded: LoadedMission, steps: list) -> None:
    run_pair(loaded, steps)


def test_generated_traffic_goes_by_express() -> None:
    """Not vacuous: on a mission an express may carry, most samples go by express."""
    loaded = parse_mission(yaml.safe_dump(mission(
        [channel(0, ["k0"], [40], "b", 0.1, False, None),
         channel(1, ["k1"], [12], "b|c", 1.0, False, 2.0)], MACS[0], 24)))
    rng = random.Random(5)
    steps = [(rng.choice([0.4, 1.0, 2.5]), rng.choice(["k0"] * 6 + ["k1", "act"]),
              rng.choice(["ok"] * 8 + ["garbage", "refused"]), rng.randrange(16))
             for _ in range(300)]
    assert run_pair(loaded, steps) >= 100


def run_pair(loaded: LoadedMission, steps: list) -> int:
    """Two cores through ``steps``, checked step by step; how many samples went by express."""
    general, laned = pair(loaded)
    now, expresses = 100.0, 0
    for wait, key, kind, value in steps:
        now += wait
        at = now + 0.25
        refused = kind == "refused"
        express = None
        if key == "act":
            expected, got = general.act(now, at), laned.act(now, at)
        else:
            data = {"too_big": msgpack.packb({"v": 1 << 41}), "garbage": b"\xc1\xc1"}.get(
                kind, msgpack.packb({"v": value}))
            general.ingest(key, data, ENC, now)
            expected = general.act(now, at)
            for core in (general, laned):  # the runtime saves what must be before a frame
                if core.needs_save:
                    core.saved()
            express = laned.express(key, data, ENC, now)
            got = None if express else laned.ingest_and_act(key, data, ENC, now, at)
        if express:
            expresses += 1
            assert express_described(express, now, at) == described(expected)
        else:
            assert described(got) == described(expected)
        carry_out(general, expected, now, refused)
        if express and refused:
            laned.done(laned.unexpressed(*express, now, at), now, now + 0.3, error="refused")
        elif express:
            laned.expressed(*express, now, now + 0.3, at)
        elif isinstance(got, SendFrame) and not refused:  # the direct path's way: books wait
            laned.sent(got, now, now + 0.3)
        else:
            carry_out(laned, got, now, refused)
        if value % 3 == 0:
            continue  # the books still wait at the next step: its first call keeps them
        assert laned.wake_at(now) == general.wake_at(now)  # (keeps the books)
        assert laned.take() == general.take()
        assert laned.stats == general.stats
        assert laned.state() == general.state()  # (the auth counter, if on, included)
    laned.settle()
    assert (laned.take(), laned.stats) == (general.take(), general.stats)
    assert laned.state() == general.state()
    return expresses


def test_a_sample_goes_by_express_after_its_lanes_first_frame(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """mac none, one channel: the first frame takes the lane, the next ones the express; the
    books kept, the store, the MAC and the counters are where the lane would have left them."""
    loaded = parse_mission(yaml.safe_dump(mission(
        [channel(0, ["k0"], [40], "b", 0.5, False, None)], {"type": "none", "min_gap_s": 0.2},
        64)))
    core = NodeCore(loaded, "a")
    first = core.ingest_and_act("k0", msgpack.packb({"v": 1}), ENC, 1.0, 1.0)
    core.saved()  # (the runtime saves the new run's epoch before its first frame)
    assert isinstance(first, SendFrame) and core.sent(first, 1.0, 1.1)
    assert core.express("k0", msgpack.packb({"v": 2}), ENC, 1.4) is None  # interval: 0.5 s
    monkeypatch.setattr(core, "ingest_and_act", lambda *a: pytest.fail("not by express"))
    for i, now in enumerate((1.5, 2.0, 2.7)):
        express = core.express("k0", msgpack.packb({"v": 10 + i}), ENC, now)
        assert express is not None and express[1] == 10 + i
        core.expressed(*express, now, now + 0.1, now)
    assert core.express("k0", b"\xc1", ENC, 3.5) is None  # (ingest_and_act counts it)
    assert core.settle() and core.stats.frames_sent == 4 and core.store.states[0].last_sent == 2.7
    assert core.express("k0", msgpack.packb({"v": 9}), ENC, 3.5) is not None
    core.ingest("k0", msgpack.packb({"v": 3}), ENC, 3.5)  # the store changed: no clearance
    assert core.express("k0", msgpack.packb({"v": 9}), ENC, 4.5) is None


def test_a_plain_node_sends_its_lone_channel_without_the_general_build(
        monkeypatch: pytest.MonkeyPatch) -> None:
    loaded = parse_mission(yaml.safe_dump(mission(
        [channel(0, ["k0"], [40], "b", 0.1, False, None),
         channel(1, ["k1", "k2"], [8, 8], "b|c", 0.1, False, None)], {"type": "none"}, 64)))
    core = NodeCore(loaded, "a")
    assert sorted(core.lanes) == ["k0", "k1", "k2"]
    monkeypatch.setattr(core, "build_frame", lambda *a, **k: pytest.fail("general build"))
    action = core.ingest_and_act("k0", msgpack.packb({"v": 5}), ENC, 1.0, 1.0)
    assert isinstance(action, SendFrame) and action.frame.dest == 2
    core.done(action, 1.0, 1.1)
    core.ingest("k1", msgpack.packb({"v": 1}), ENC, 2.0)  # c1 incomplete: not due
    action = core.ingest_and_act("k2", msgpack.packb({"v": 2}), ENC, 2.0, 2.0)
    assert isinstance(action, SendFrame) and action.frame.dest is None  # two destinations
    assert [s.channel.name for s in action.frame.plan.chosen] == ["c1"]


def test_a_node_with_more_than_latest_values_has_no_lanes() -> None:
    reliable = channel(0, ["k0"], [8], "b", 0.1, False, None) | {"reliable": True}
    loaded = parse_mission(yaml.safe_dump(mission([reliable], {"type": "none"}, 64)))
    assert NodeCore(loaded, "a").lanes == {}


def test_an_express_waits_for_the_macs_gap_and_gives_way_to_a_channel_come_due() -> None:
    """The clearance holds the MAC's gap after each frame, and ends when another channel (here a
    latching one, repeating every 2 s) comes due: that frame is the general one."""
    loaded = parse_mission(yaml.safe_dump(mission(
        [channel(0, ["k0"], [40], "b", 0.1, False, None),
         channel(1, ["k1"], [8], "b", 2.0, True, None)], {"type": "none", "min_gap_s": 0.5},
        64)))
    core = NodeCore(loaded, "a")
    both = core.ingest_and_act("k1", msgpack.packb({"v": 1}), ENC, 10.0, 10.0)
    assert isinstance(both, SendFrame)
    core.done(both, 10.0, 10.1)  # c1 latched: due again at 12.0
    core.saved()
    first = core.ingest_and_act("k0", msgpack.packb({"v": 1}), ENC, 10.6, 10.6)
    assert isinstance(first, SendFrame) and core.sent(first, 10.6, 10.7)
    value = msgpack.packb({"v": 2})
    assert core.express("k0", value, ENC, 11.0) is None  # the MAC's gap: until 11.1
    express = core.express("k0", value, ENC, 11.2)
    assert express is not None
    core.expressed(*express, 11.2, 11.3, 11.2)
    assert core.express("k0", value, ENC, 11.6) is None  # the gap after the express
    assert core.express("k0", value, ENC, 11.8) is not None
    assert core.express("k0", value, ENC, 12.0) is None  # c1 is due: both go together
    action = core.ingest_and_act("k0", value, ENC, 12.0, 12.0)
    assert isinstance(action, SendFrame)
    assert sorted(s.channel.name for s in action.frame.plan.chosen) == ["c0", "c1"]
