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
def missions(draw: st.DrawFn) -> LoadedMission:
    n = draw(st.integers(1, 4))
    channels = []
    for i in range(n):
        elements = draw(st.integers(1, 2))
        keys = [draw(st.sampled_from(["k0", "k1", "k2", "k3"])) for _ in range(elements)]
        if len(set(keys)) < len(keys):
            keys = keys[:1]  # one element per key within a channel
        channels.append(channel(
            i, keys, [draw(st.integers(4, 40)) for _ in keys], draw(st.sampled_from(["b", "b|c"])),
            draw(st.sampled_from([0.1, 1.0, 5.0])), draw(st.booleans()),
            draw(st.sampled_from([None, 2.0]))))
    auth = draw(st.booleans())  # (its counter and tag take 12 more bytes a frame)
    frame_bytes = draw(st.sampled_from([8, 12, 24, 64])) + (12 if auth else 0)
    text = yaml.safe_dump(mission(channels, draw(st.sampled_from(MACS)), frame_bytes, auth))
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


def carry_out(core: NodeCore, action: SendFrame | Ping | None, now: float) -> None:
    if action is not None:
        core.done(action, now, now + 0.3)


ops = st.lists(st.tuples(
    st.sampled_from([0.0, 0.05, 0.4, 1.0, 2.5]),  # wait before
    st.sampled_from(["k0", "k1", "k2", "k3", "act"]),  # a sample on a key, or an opportunity
    st.sampled_from(["ok"] * 6 + ["too_big", "garbage"]),
    st.integers(0, 15),
), min_size=1, max_size=40)


@settings(max_examples=150, deadline=None)
@given(missions(), ops)
def test_a_lane_ends_where_ingest_then_act_ends(loaded: LoadedMission, steps: list) -> None:
    general, laned = pair(loaded)
    now = 100.0
    for wait, key, kind, value in steps:
        now += wait
        at = now + 0.25
        if key == "act":
            expected, got = general.act(now, at), laned.act(now, at)
        else:
            data = {"ok": msgpack.packb({"v": value}), "too_big": msgpack.packb({"v": 1 << 41}),
                    "garbage": b"\xc1\xc1"}[kind]
            general.ingest(key, data, ENC, now)
            expected = general.act(now, at)
            got = laned.ingest_and_act(key, data, ENC, now, at)
        assert described(got) == described(expected)
        carry_out(general, expected, now)
        if isinstance(got, SendFrame):  # the direct path's way: a lone frame's books wait
            laned.sent(got, now, now + 0.3)
        else:
            carry_out(laned, got, now)
        if value % 3 == 0:
            continue  # the books still wait at the next step: its first call keeps them
        assert laned.wake_at(now) == general.wake_at(now)  # (keeps the books)
        assert laned.take() == general.take()
        assert laned.stats == general.stats
        assert laned.state() == general.state()  # (the auth counter, if on, included)
    laned.settle()
    assert (laned.take(), laned.stats) == (general.take(), general.stats)


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
