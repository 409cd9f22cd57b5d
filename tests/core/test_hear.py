"""``hear`` (#14): a plain frame's values at once, its books later, and the same end as ``receive``.

Two receiving cores of one mission: one takes every frame with ``receive``, the other with
``hear`` and keeps its books only when something else asks (``settle``, ``tick``, a sample,
an opportunity). Over generated missions (several channels, latching, unicast and broadcast,
a reliable channel beside them, each MAC, authenticated or not) and generated traffic (frames
as sent, replayed, corrupted, or claimed by another node), the values published must be the
same and come out at once; everything else (events, status, counters, links, saved state)
must be the same once the books are kept.
"""

from __future__ import annotations

import random
from typing import Any

import msgpack
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from bridge.core.node import NodeCore, Publish, SendFrame, publications
from bridge.mission.loader import LoadedMission, parse_mission
from bridge.modems.reception import Reception
from tests.core.test_lanes import ENC, MACS, channel, mission

KEY = b"hear test key 16"


@st.composite
def missions(draw: st.DrawFn) -> LoadedMission:
    channels = []
    for i in range(draw(st.integers(1, 3))):
        keys = draw(st.lists(st.sampled_from(["k0", "k1", "k2"]), min_size=1, max_size=2,
                             unique=True))
        channels.append(channel(i, keys, [draw(st.integers(4, 24)) for _ in keys],
                                draw(st.sampled_from(["b", "b|c", "c"])), 0.1,
                                draw(st.booleans()), None))
    if draw(st.booleans()):  # a reliable channel: its frames take receive's way
        channels.append(channel(len(channels), ["k3"], [8], "b", 0.1, False, None)
                        | {"reliable": True})
    auth = draw(st.booleans())
    text = yaml.safe_dump(mission(channels, draw(st.sampled_from(MACS)), 64 + 12 * auth, auth))
    return parse_mission(text)


def core(loaded: LoadedMission, node: str) -> NodeCore:
    return NodeCore(loaded, node, rng=random.Random(7), seed=3, key=KEY)


ops = st.lists(st.tuples(
    st.sampled_from([0.0, 0.05, 0.05, 0.4, 0.4, 2.5, 30.0]),  # wait before (30 s: links go down)
    st.sampled_from(["k0", "k1", "k2", "k3", "send", "send", "hear", "hear", "hear", "tick",
                     "settle"]),
    st.sampled_from(["last"] * 4 + ["replay", "corrupt", "from_c"]),  # which frame is heard
    st.integers(0, 15),
), min_size=20, max_size=60)


def split(outputs: list[Any], values: list[Any], rest: list[Any]) -> None:
    for output in outputs:
        (values if isinstance(output, Publish) else rest).append(output)


def books(node: NodeCore) -> tuple:
    return (node.stats, node.last_heard, node.received_at, node.link_states, node.state(),
            node.snapshot(0.0))


@settings(max_examples=150, deadline=None)
@given(missions(), ops)
def test_hear_ends_where_receive_ends(loaded: LoadedMission, steps: list) -> None:
    sender, general, heard = core(loaded, "a"), core(loaded, "b"), core(loaded, "b")
    sent: list[bytes] = []
    values_g: list[Any] = []
    values_h: list[Any] = []
    rest_g: list[Any] = []
    rest_h: list[Any] = []
    now = 100.0
    for wait, op, which, value in steps:
        now += wait
        if op.startswith("k"):
            sender.ingest(op, msgpack.packb({"v": value}), ENC, now)
        elif op == "send":
            action = sender.act(now, now)
            if isinstance(action, SendFrame):
                sender.done(action, now, now + 0.1)
                sent.append(action.frame.data)
        elif op == "hear" and sent:
            data, src = sent[-1], loaded.mission.address_of("a")
            if which == "replay":
                data = sent[value % len(sent)]
            elif which == "corrupt":
                i = value % len(data)
                data = data[:i] + bytes([data[i] ^ 0x10]) + data[i + 1:]
            elif which == "from_c":
                src = loaded.mission.address_of("c")
            rx = Reception(data, src, now, {"dest": None, "start": now})
            general.receive(rx, now)
            got = heard.hear(rx, now)
            split(general.take(), values_g, rest_g)
            split(heard.take() if got is None else publications(got), values_h, rest_h)
            assert values_h == values_g  # the values come out at once
        elif op == "tick":
            general.tick(now)
            heard.tick(now)  # (keeps the books first)
            split(general.take(), values_g, rest_g)
            split(heard.take(), values_h, rest_h)
            assert rest_h == rest_g
            assert books(heard) == books(general)
        elif op == "settle":
            heard.settle()
            split(heard.take(), values_h, rest_h)
            assert rest_h == rest_g
    heard.settle()
    split(heard.take(), values_h, rest_h)
    assert values_h == values_g
    assert rest_h == rest_g
    assert books(heard) == books(general)
    assert heard.wake_at(now) == general.wake_at(now)


def test_a_plain_frame_is_published_before_its_books_are_kept() -> None:
    loaded = parse_mission(yaml.safe_dump(mission(
        [channel(0, ["k0"], [8], "b", 0.1, False, None)], {"type": "none"}, 64)))
    sender, receiver = NodeCore(loaded, "a"), NodeCore(loaded, "b")

    def frame(value: int, now: float) -> Reception:
        action = sender.ingest_and_act("k0", msgpack.packb({"v": value}), ENC, now, now)
        assert isinstance(action, SendFrame)
        sender.done(action, now, now)
        return Reception(action.frame.data, 1, now, {"dest": 2, "start": now})

    assert receiver.hear(frame(1, 1.0), 1.0) is None  # the link is not up yet: receive's way
    receiver.take()
    heard = receiver.hear(frame(2, 2.0), 2.0)
    assert heard is not None and receiver.take() == []  # (the values are the caller's)
    assert [(o.key, o.value) for o in publications(heard)] == [("out/0/k0", {"v": 2})]
    assert receiver.stats.frames_received == 1  # the books wait
    assert receiver.settle()
    assert receiver.stats.frames_received == 2
    assert receiver.last_heard["a"] == 2.0
    assert [type(o).__name__ for o in receiver.take()][-1] == "FrameReceived"
    assert not receiver.settle()


def test_books_are_kept_before_anything_else_the_core_does() -> None:
    loaded = parse_mission(yaml.safe_dump(mission(
        [channel(0, ["k0"], [8], "b", 0.1, False, None),
         channel(1, ["k1"], [8], "a", 0.1, False, None) | {"from": "b"}], {"type": "none"}, 64)))
    a, b = NodeCore(loaded, "a"), NodeCore(loaded, "b")
    for now in (1.0, 2.0):
        action = a.ingest_and_act("k0", msgpack.packb({"v": 3}), ENC, now, now)
        assert isinstance(action, SendFrame)
        a.done(action, now, now)
        b.hear(Reception(action.frame.data, 1, now, {"dest": 2, "start": now}), now)
    b.take()
    b.ingest("k1", msgpack.packb({"v": 4}), ENC, 3.0)  # b's own sample: the books first
    assert b.stats.frames_received == 2
    assert "FrameReceived" in [type(o).__name__ for o in b.take()]
