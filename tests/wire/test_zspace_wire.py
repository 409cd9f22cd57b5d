"""Garbage from the water with a valid check, in a mission using every entry of issue 15
(keyed channels, @key, @want, query requests and replies): the frame parser raises only
FrameError, and a node's core counts or ignores what it cannot use, never crashes."""

from __future__ import annotations

import contextlib

from hypothesis import given, settings
from hypothesis import strategies as st

from bridge.core.loaded import load_mission
from bridge.core.node import NodeCore
from bridge.errors import FrameError
from bridge.modems.base import Reception
from bridge.wire.frame import FrameCodec, check_value
from tests.conftest import MISSIONS

LOADED = load_mission(MISSIONS / "zspace.yaml")
CODEC = FrameCodec(LOADED.table)


def sealed(body: bytes) -> bytes:
    return body + check_value(body, LOADED.table.fingerprint)


@settings(max_examples=1500, deadline=None)
@given(st.binary(max_size=48))
def test_random_bodies_raise_only_frame_error(body: bytes) -> None:
    with contextlib.suppress(FrameError):
        CODEC.decode(sealed(body))


@settings(max_examples=600, deadline=None)
@given(st.binary(max_size=48), st.sampled_from([1, 2, 3]), st.sampled_from(["top", "auv1"]))
def test_a_core_survives_any_frame_that_passes_the_check(body: bytes, src: int,
                                                         node: str) -> None:
    core = NodeCore(LOADED, node)
    core.receive(Reception(sealed(body), src, 0.0), 0.0)
    core.tick(100.0)  # open queries expire, links settle
    core.outbound.build(100.0, 100.0)
    core.take()
    stats = core.stats  # the frame was used or counted as dropped, never lost silently
    assert stats.frames_received + sum(stats.frames_dropped.values()) >= 1


@st.composite
def structured(draw: st.DrawFn) -> bytes:
    """A frame of random entries of every kind, with random (often invalid) field codes."""
    wire = LOADED.table.wire
    picked = draw(st.lists(st.sampled_from(wire), max_size=5))
    items, seen = [], set()
    for codec in picked:
        if codec.index in seen and not codec.repeatable:
            continue
        seen.add(codec.index)
        items.append((codec, draw(st.integers(0, (1 << codec.wire_bits) - 1))))
    return CODEC.encode(items)


@settings(max_examples=1500, deadline=None)
@given(structured(), st.sampled_from([1, 2, 3]), st.sampled_from(["top", "auv1", "auv2"]))
def test_a_core_survives_random_entries_of_every_kind(frame: bytes, src: int,
                                                      node: str) -> None:
    with contextlib.suppress(FrameError):
        CODEC.decode(frame)
    core = NodeCore(LOADED, node)
    core.receive(Reception(frame, src, 0.0), 0.0)
    core.tick(100.0)
    core.outbound.build(100.0, 100.0)
    core.take()
    stats = core.stats  # the frame was used or counted as dropped, never lost silently
    assert stats.frames_received + sum(stats.frames_dropped.values()) >= 1
