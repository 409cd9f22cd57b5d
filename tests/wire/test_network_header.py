"""The network header, bundles, and the replay window that frames out of order need
(bridge/wire/network.py, bridge/wire/auth.py)."""

from __future__ import annotations

import msgpack
import pytest
from hypothesis import given
from hypothesis import strategies as st

from bridge.errors import FrameError
from bridge.wire.auth import Authenticator
from bridge.wire.network import BUNDLE_MAX, NO_LIMIT, NetCodec, NetHeader

FINGERPRINT = bytes(8)
KEY = bytes(range(32))


@st.composite
def headers(draw: st.DrawFn) -> tuple[NetCodec, NetHeader]:
    nodes = draw(st.integers(2, 16))
    ranks = draw(st.integers(1, 9))
    via = draw(st.booleans())
    codec = NetCodec(nodes, ranks, via)
    serves = frozenset(draw(st.sets(st.integers(0, nodes - 1))))
    if not draw(st.booleans()):
        return codec, NetHeader(serves)
    return codec, NetHeader(serves, draw(st.integers(0, nodes - 1)), draw(st.integers(0, 7)),
                            draw(st.integers(0, 255)), draw(st.integers(0, NO_LIMIT)),
                            draw(st.integers(0, 255)), draw(st.integers(0, ranks - 1)),
                            draw(st.integers(0, nodes - 1)) if via else 0)


@given(headers(), st.binary(max_size=20))
def test_headers_round_trip_before_any_frame(case: tuple[NetCodec, NetHeader],
                                             frame: bytes) -> None:
    codec, header = case
    data = codec.encode(header)
    assert len(data) == (codec.routed_bytes if header.routed else codec.plain_bytes)
    assert codec.decode(data + frame) == (header, len(data))


def test_header_sizes_for_seed_002s_five_rovs_and_an_operator() -> None:
    codec = NetCodec(6, 3)  # 2 kind + 6 for; + 3 origin + 3 hops + 8 seq + 16 life/age + 2 rank
    assert (codec.plain_bytes, codec.routed_bytes) == (1, 5)


def test_the_hop_chosen_among_listed_routes_costs_one_node_index_and_only_there() -> None:
    plain, listed = NetCodec(6, 3), NetCodec(6, 3, via=True)
    assert (listed.plain_bytes, listed.routed_bytes) == (1, 6)  # 40 + 3 bits: one byte more
    header = NetHeader(frozenset({4}), 0, 1, 9, NO_LIMIT, 3, 2)
    assert plain.encode(header) != listed.encode(header)
    assert listed.decode(listed.encode(NetHeader(frozenset({4}), 0, 1, 9, 7, 3, 2, 5)))[0].via == 5
    assert listed.describe() != plain.describe()  # both ends must agree: in the fingerprint
    with pytest.raises(ValueError):
        plain.encode(NetHeader(frozenset({4}), 0, via=2))  # no room for it without lists


def test_bundles_split_back_into_their_frames_and_bad_ones_are_refused() -> None:
    frames = [b"\x00\x01\x02", b"\x40" + bytes(30), bytes([0x00]) * 255]
    data = NetCodec.bundle(frames)
    assert len(data) == NetCodec.bundle_bytes(len(f) for f in frames)
    assert NetCodec.unbundle(data) == frames
    assert NetCodec.unbundle(frames[0]) is None  # one frame is not a bundle
    for bad in (data[:-1], data + b"\x00", data[:1], bytes([0x80, 0])):
        with pytest.raises(FrameError):
            NetCodec.unbundle(bad)
    with pytest.raises(ValueError):
        NetCodec.bundle([b"x"] * (BUNDLE_MAX + 1))
    with pytest.raises(FrameError, match="kind 2"):  # a bundle where one frame was expected
        NetCodec(3, 1).decode(data)


def test_unknown_origin_is_refused() -> None:
    codec = NetCodec(3, 1)  # origin field of 2 bits: 3 is no node
    data = codec.encode(NetHeader(frozenset({1}), 2))
    forged = bytes([data[0] | 0b0000_0010]) + data[1:]  # kind 2, for 3, origin 2 bits: 2 -> 3
    with pytest.raises(FrameError, match="unknown node 3"):
        codec.decode(forged)


def test_a_window_accepts_frames_overtaken_on_another_link_once() -> None:
    sender = Authenticator(KEY, FINGERPRINT, 7, 4)
    frames = [sender.seal(bytes([i])) for i in range(6)]
    strict = Authenticator(KEY, FINGERPRINT, 1, 4)
    window = Authenticator(KEY, FINGERPRINT, 1, 4, window=4)
    for receiver in (strict, window):
        receiver.open(frames[3], 7)  # 3 came first (over RF), then 1 (over acoustics)
    with pytest.raises(FrameError, match="replayed"):
        strict.open(frames[1], 7)
    assert window.open(frames[1], 7) == bytes([1])
    with pytest.raises(FrameError, match="replayed"):
        window.open(frames[1], 7)  # but once only
    window.open(frames[5], 7)
    with pytest.raises(FrameError, match="replayed"):
        window.open(frames[0], 7)  # 5 below the highest: out of a window of 4
    again = Authenticator(KEY, FINGERPRINT, 1, 4, window.state(), window=4)
    assert again.open(frames[4], 7) == bytes([4])  # the window survives a restart
    with pytest.raises(FrameError, match="replayed"):
        again.open(frames[3], 7)


def test_a_window_of_a_thousand_frames_is_saved_as_bytes_and_read_from_an_older_state() -> None:
    """A relay may hold a frame minutes while its origin sends one a second on another link:
    the window spans 1024 counters, and its bitmap goes into the (msgpack) state as bytes;
    a state saved with the 64-bit window of before (an integer) still reads."""
    sender = Authenticator(KEY, FINGERPRINT, 7, 4)
    frames = [sender.seal(bytes([i % 256])) for i in range(1100)]
    receiver = Authenticator(KEY, FINGERPRINT, 1, 4, window=1024)
    receiver.open(frames[1050], 7)
    assert receiver.open(frames[30], 7) == bytes([30])  # 1020 below the highest
    with pytest.raises(FrameError, match="replayed"):
        receiver.open(frames[20], 7)  # 1030 below: out of the window
    saved = msgpack.unpackb(msgpack.packb(receiver.state()), strict_map_key=False)
    again = Authenticator(KEY, FINGERPRINT, 1, 4, saved, window=1024)
    with pytest.raises(FrameError, match="replayed"):
        again.open(frames[30], 7)  # once only, across the restart
    assert again.open(frames[31], 7) == bytes([31])
    older = {**saved, "late": {"7": 0b10}}  # the counter 1 below the mark came
    before = Authenticator(KEY, FINGERPRINT, 1, 4, older, window=1024)
    with pytest.raises(FrameError, match="replayed"):
        before.open(frames[1049], 7)
    assert before.open(frames[1048], 7) == bytes([1048 % 256])
