"""The frame format: round trips, size accounting, and untrusted bytes."""

from __future__ import annotations

import contextlib

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bridge.core.builder import Candidate, FramePlan, fill
from bridge.core.loaded import parse_mission
from bridge.core.store import OutboundStore
from bridge.errors import DecodeError, FrameError
from bridge.wire.frame import NO_DELAY, FrameCodec, check_value
from tests.conftest import MISSIONS

# The plain frame format (tests/wire/test_auth.py: the authenticated one morph.yaml ships with).
MORPH_TEXT = (MISSIONS / "morph.yaml").read_text().replace("auth: {tag_bytes: 4}", "auth: off")
MORPH = parse_mission(MORPH_TEXT, "morph.yaml")
CODEC = FrameCodec(MORPH.table)


def valid(channel, n: int) -> bool:
    """Whether ``n`` is a payload the channel can produce (an enum of 6 leaves codes 6, 7)."""
    try:
        channel.unpack(n)
    except DecodeError:
        return False
    return True


def random_payloads(draw: st.DrawFn) -> list[tuple]:
    channels = draw(st.lists(st.sampled_from(MORPH.table.channels), unique_by=lambda c: c.index))
    return [(c, draw(st.integers(0, (1 << c.bits) - 1).filter(lambda n, c=c: valid(c, n))))
            for c in channels]


@st.composite
def frames(draw: st.DrawFn) -> tuple[list[tuple], list[int | None]]:
    items = random_payloads(draw)
    delays = draw(st.lists(st.none() | st.integers(0, NO_DELAY - 1),
                           min_size=CODEC.delay_count, max_size=CODEC.delay_count))
    return items, delays


@settings(max_examples=300, deadline=None)
@given(frames())
def test_random_channel_subsets_round_trip(frame: tuple[list[tuple], list[int | None]]) -> None:
    items, delays = frame
    data = CODEC.encode(items, delays)
    assert len(data) == CODEC.frame_bytes_for([c for c, _ in items])
    decoded = CODEC.decode(data)
    assert decoded.delays == tuple(delays)
    assert [c.index for c, _ in decoded.channels] == [c.index for c, _ in items]
    for (channel, values), (_, packed) in zip(decoded.channels, items, strict=True):
        assert channel.pack(values) == packed  # decode then re-encode gives the same bits


@settings(max_examples=2000, deadline=None)
@given(st.binary(max_size=80))
def test_random_bytes_raise_only_frame_error(data: bytes) -> None:
    with contextlib.suppress(FrameError):
        CODEC.decode(data)


@settings(max_examples=2000, deadline=None)
@given(st.binary(max_size=70))
def test_random_bodies_with_valid_check_raise_only_frame_error(body: bytes) -> None:
    """Past the check value, the parser itself must also refuse garbage cleanly."""
    check = check_value(body, MORPH.table.fingerprint)
    with contextlib.suppress(FrameError):
        CODEC.decode(body + check)


def test_minimum_overhead_and_one_channel_size() -> None:
    target = MORPH.table.by_name("target_reference")
    data = CODEC.encode([(target, 0b10101010_101010)], [None] * CODEC.delay_count)
    # 4 foreign nodes × 3 B delays, 3-bit count + 3-bit index + 14 bits → 3 bytes, 2 B check
    assert CODEC.count_bits == 3 and CODEC.index_bits == 3
    assert len(data) == 12 + 3 + 2


def test_other_mission_is_detected() -> None:
    other = MORPH.mission.model_copy(deep=True)
    fields = other.channels[0].elements[0].fields
    fields[0] = fields[0].model_copy(update={"bits": 9})
    other_table = type(MORPH.table).from_mission(other)
    assert other_table.fingerprint != MORPH.table.fingerprint
    foreign = FrameCodec(other_table).encode([], [None] * CODEC.delay_count)
    with pytest.raises(FrameError, match="another mission"):
        CODEC.decode(foreign)


def test_bit_flip_and_truncation_detected() -> None:
    target = MORPH.table.by_name("target_reference")
    data = bytearray(CODEC.encode([(target, 12345)], [5, None, 7, 9]))
    for i in range(len(data) * 8):
        flipped = bytearray(data)
        flipped[i // 8] ^= 1 << (i % 8)
        with pytest.raises(FrameError):
            CODEC.decode(bytes(flipped))
    with pytest.raises(FrameError):
        CODEC.decode(bytes(data[:-1]))
    with pytest.raises(FrameError):
        CODEC.decode("not bytes")  # type: ignore[arg-type]


def test_builder_priority_first_then_oldest_and_reports_left_out() -> None:
    loaded = parse_mission(MORPH_TEXT.replace("frame_bytes: 64", "frame_bytes: 24"), "m.yaml")
    codec = FrameCodec(loaded.table)
    store = OutboundStore.for_node(loaded.table.channels, "lsv")
    nav, status, target = (loaded.table.by_name(n) for n in ("nav", "status", "target_reference"))
    store.update(nav.index, 0, 1, now=0.0)
    store.update(status.index, 0, 2, now=0.0)
    store.update(target.index, 0, 3, now=0.0)
    picked, left = fill(codec, (Candidate(s.channel, s.last_sent, s) for s in store.due(1.0)),
                        codec.body_capacity_bits(24) - codec.count_bits,
                        (1 << codec.count_bits) - 1)
    plan = FramePlan(tuple(c.what for c in picked), tuple(c.what for c in left))
    # 24 B - 12 B delays - 2 B check = 80 bits - 3 count: nav (2) first, then what fits
    assert next(s.channel.name for s in plan.chosen) == "nav"
    used = sum(codec.channel_cost_bits(s.channel) for s in plan.chosen)
    assert used <= 77
    assert {s.channel.name for s in plan.chosen} | {s.channel.name for s in plan.left_out} == {
        "nav", "status", "target_reference"}
    assert plan.left_out, "something must be left out of a 24-byte frame"
    assert len(codec.encode([(s.channel, s.payload()) for s in plan.chosen],
                            [None] * codec.delay_count)) <= 24
