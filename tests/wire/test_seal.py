"""Confidential frames (issue 32): AES-CCM from ``cryptography``, the counter as the nonce,
the DLBL delays in the clear and authenticated, replay protection, key rotation."""

from __future__ import annotations

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from bridge.core.loaded import parse_mission
from bridge.errors import FrameError, MissionError
from bridge.runtime.virtual_fleet import FastFleet
from bridge.wire.frame import FrameCodec, check_value
from bridge.wire.seal import COUNTS_PER_S, LEAD, KeyRing, Sealer, frame_authenticator
from tests.conftest import MISSIONS
from tests.harness import bench_module

KEY, NEXT = b"k" * 32, b"n" * 32


def morph(**auth: object) -> tuple[FrameCodec, FrameCodec, FrameCodec]:
    """MORPH (DLBL on) with ``wire.auth``: codecs of gcv (address 1) and lsv (address 3), and
    one of the same mission unsealed (the plaintext packing)."""
    data = yaml.safe_load((MISSIONS / "morph.yaml").read_text())
    data["wire"]["auth"] = {"tag_bytes": 4, **auth}
    loaded = parse_mission(yaml.safe_dump(data, sort_keys=False), "m.yaml")
    gcv = FrameCodec(loaded.table, frame_authenticator(loaded.table, KEY, 1))
    lsv = FrameCodec(loaded.table, frame_authenticator(loaded.table, KEY, 3))
    data["wire"]["auth"] = {"tag_bytes": 4}
    plain = parse_mission(yaml.safe_dump(data, sort_keys=False), "p.yaml")
    return gcv, lsv, FrameCodec(plain.table, frame_authenticator(plain.table, KEY, 1))


def items(codec: FrameCodec) -> list[tuple[object, int]]:
    channel = codec.table.by_name("target_reference")
    return [(channel, channel.pack([{"vector": {"x": 3.0, "y": 0.02}}]))]


DELAYS = [1000, None, 250_000, 7]


def test_a_sealed_frame_reveals_no_field_and_costs_what_an_authenticated_one_does() -> None:
    gcv, lsv, plain = morph(encrypt=True)
    sealed = gcv.encode(items(gcv), DELAYS, now=100.0)
    clear = plain.encode(items(plain), DELAYS)
    assert len(sealed) == len(clear)  # same counter and tag, the body the same length
    delays = 3 * len(DELAYS)
    body = clear[delays:-2 - 8]  # the plaintext packing: count, index, fields
    assert body and body not in sealed and sealed[:delays] == clear[:delays]  # DLBL clear
    frame = lsv.decode(sealed, 1, now=100.0)
    assert frame.delays == (1000, None, 250_000, 7)
    assert frame.entries[0].values == items(gcv)[0][0].unpack(items(gcv)[0][1])
    assert gcv.table.fingerprint != plain.table.fingerprint  # never mistaken for the other


def test_a_tampered_replayed_or_misattributed_frame_is_refused() -> None:
    gcv, lsv, _ = morph(encrypt=True)
    sealed = gcv.encode(items(gcv), DELAYS, now=100.0)
    for where in (0, 3 * len(DELAYS), 3 * len(DELAYS) + 4, len(sealed) - 3):  # delay,
        tampered = bytearray(sealed)  # counter, body, tag
        tampered[where] ^= 0x01
        with pytest.raises(FrameError) as refused:  # the check value first, or the tag
            lsv.decode(_rechecked(lsv, bytes(tampered)), 1, now=100.0)
        assert refused.value.reason == "forged"
    with pytest.raises(FrameError, match="forged"):
        lsv.decode(sealed, 2, now=100.0)  # as if from another address
    lsv.decode(sealed, 1, now=100.0)
    with pytest.raises(FrameError) as replay:
        lsv.decode(sealed, 1, now=101.0)
    assert replay.value.reason == "replayed"


def _rechecked(codec: FrameCodec, frame: bytes) -> bytes:
    """``frame`` with its check value made right again (as a forger would)."""
    body = frame[:-2]
    return body + check_value(body, codec.table.fingerprint)


def test_a_sender_without_its_state_starts_its_counter_from_its_clock() -> None:
    gcv, lsv, _ = morph(encrypt=True)
    lsv.decode(gcv.encode(items(gcv), DELAYS, now=1_700_000_000.0), 1, now=1_700_000_000.5)
    assert gcv.auth is not None and gcv.auth.counter == 1_700_000_000 * COUNTS_PER_S + LEAD + 2
    again = FrameCodec(gcv.table, frame_authenticator(gcv.table, KEY, 1))  # restarted afresh
    lsv.decode(again.encode(items(again), DELAYS, now=1_700_000_060.0), 1,
               now=1_700_000_060.2)  # a counter never used, accepted
    resumed = FrameCodec(gcv.table, frame_authenticator(gcv.table, KEY, 1, again.auth.state()))
    lsv.decode(resumed.encode(items(resumed), DELAYS, now=5.0), 1, now=1_700_000_061.0)
    with pytest.raises(FrameError, match="forged"):  # a first counter far from the clock
        morph(encrypt=True)[1].decode(sealed_at(0.0), 1, now=1_700_000_000.0)


def test_restarts_with_and_without_state_never_reuse_a_nonce() -> None:
    """Found from outside: started afresh, killed and restarted with its state (which resumed
    a whole block of 1024 counters on, 64 s of clock count), sending for 35 s, killed again and
    started without its state 66 s after the first start: the third life sealed with counters
    the second had used (the receiver refused them as replays *after* their tags checked
    out)."""
    t = 1_700_000_000.0
    used = _lives([(None, t, 1, 0.0), ("state", t + 1, 73, 0.48), (None, t + 66, 40, 0.5)])
    assert len(used) == len(set(used))


@settings(max_examples=80, deadline=None)
@given(st.lists(st.tuples(st.sampled_from(["state", None]),
                          st.one_of(st.floats(0.07, 5), st.floats(5, 900)),
                          st.integers(0, 40), st.floats(1 / COUNTS_PER_S, 5)),
                min_size=1, max_size=12))
def test_no_sequence_of_restarts_reuses_a_nonce(lives: list[tuple[str | None, float, int,
                                                                  float]]) -> None:
    """Lives of one sender, each after a gap, restarted with its saved state or without,
    sending frames (at most COUNTS_PER_S a second): never one counter twice."""
    t, plan = 1_700_000_000.0, []
    for keep, gap, frames, every in lives:
        t += gap
        plan.append((keep, t, frames, every))
        t += frames * every
    used = _lives(plan)
    assert len(used) == len(set(used))


def _lives(plan: list[tuple[str | None, float, int, float]]) -> list[int]:
    """The counters one sender (address 1) seals with over ``plan``'s lives, each ``(kept
    state or None, start time, frames, seconds between them)``; its state is saved whenever
    it changes (as the runtime does before a frame leaves)."""
    table, saved, used = morph(encrypt=True)[0].table, None, []
    for keep, start, frames, every in plan:
        sealer = frame_authenticator(table, KEY, 1, saved if keep else None)
        saved = saved if keep else None
        for i in range(frames):
            sealer.seal(b"\0" * 8, now=start + i * every)
            used.append(sealer.counter - 1)
            if sealer.changed:
                saved, sealer.changed = sealer.state(), False
    return used


def sealed_at(now: float) -> bytes:
    gcv = morph(encrypt=True)[0]
    return gcv.encode(items(gcv), DELAYS, now=now)


def test_keys_rotate_and_both_are_accepted_across_the_switch() -> None:
    ring = KeyRing(KEY, NEXT, switch_at=1000.0, overlap_s=60.0)
    table = morph(encrypt=True)[0].table
    old = FrameCodec(table, frame_authenticator(table, KEY, 1))  # not told of the rotation
    rotating = FrameCodec(table, frame_authenticator(table, ring, 3))
    new_only = FrameCodec(table, frame_authenticator(table, NEXT, 1))
    rotating.decode(old.encode(items(old), DELAYS, now=990.0), 1, now=1010.0)  # in flight
    rotating.decode(new_only.encode(items(new_only), DELAYS, now=1005.0), 1, now=995.0)
    with pytest.raises(FrameError, match="forged"):  # long after: the old key is gone
        rotating.decode(old.encode(items(old), DELAYS, now=2000.0), 1, now=2000.0)
    assert ring.keys(500.0) == [KEY] and ring.keys(1500.0) == [NEXT]
    assert ring.keys(990.0) == [KEY, NEXT] and ring.keys(1010.0) == [NEXT, KEY]


def test_the_mission_says_encrypt_with_an_even_tag_and_rotation_needs_it() -> None:
    with pytest.raises(MissionError, match="tag_bytes is even"):
        morph(encrypt=True, tag_bytes=5)
    with pytest.raises(MissionError, match="give encrypt: true"):
        morph(next_key={"at": "2026-06-01T12:00:00Z"})
    with pytest.raises(MissionError, match="4 to 16 bytes"):
        Sealer(KEY, b"f" * 8, 1, 3, 0)


ROTATING = """
mission: rot
wire: {auth: {tag_bytes: 4, encrypt: true, next_key: {at: "1970-01-01T00:02:00Z",
                                                      overlap_s: 20}}}
modem: {backend: sim, frame_bytes: 48, options: {preset: evologics-s2c-im}}
mac: {type: tdma, slot_s: 1.0, guard_s: 0.1, order: [ops, auv]}
nodes:
  ops: {address: 1, role: surface, position: {x: 0, y: 0, depth: 0}}
  auv: {address: 2, position: {x: 300, y: 0, depth: 20}}
channels:
  - name: command
    from: ops
    to: auv
    reliable: true
    elements:
      - {in: cmd, out: ops/cmd, fields: [{field: n, type: int, min: 0, max: 1023}]}
  - name: nav
    from: auv
    to: ops
    elements:
      - {in: nav, out: auv/nav, fields: [{field: depth, min: 0, max: 100, resolution: 0.1}]}
"""


def test_a_key_rotation_in_the_middle_of_a_run_loses_nothing() -> None:
    loaded = parse_mission(ROTATING, "rot.yaml")
    ring = KeyRing(KEY, NEXT, switch_at=120.0, overlap_s=20.0)
    fleet = FastFleet(loaded, seed=2, key=ring)
    fleet.subscribe("ops", "**")
    for i in range(100):  # a command and a depth every 2 s, across the switch at 120 s
        fleet.put("ops", "cmd", {"n": i}, at=20.0 + 2 * i)
        fleet.put("auv", "nav", {"depth": i / 10}, at=21.0 + 2 * i)
    fleet.run_until(260.0)
    assert [p.value["n"] for _, p in fleet.published("auv", "ops/cmd")] == list(range(100))
    assert len(fleet.published("ops", "auv/nav")) >= 95  # each latest value, in turn
    for core in fleet.cores.values():
        assert dict(core.stats.frames_dropped) == {}


def test_the_bench_rows_compare_sealed_frames_with_plain_and_authenticated_ones() -> None:
    rows = {mode: (size, rate) for mode, size, rate in
            bench_module("codec_bench").frame_rows(0.05)}
    assert rows["sealed"][0] == rows["authenticated"][0] == rows["plain"][0] + 8
    assert all(rate > 0 for _, rate in rows.values())


def test_a_key_holders_frame_under_another_mission_file_is_told_from_junk() -> None:
    gcv, lsv, _ = morph(encrypt=True)
    data = yaml.safe_load((MISSIONS / "morph.yaml").read_text())
    data["wire"]["auth"] = {"tag_bytes": 4, "encrypt": True}
    data["channels"][0]["interval_s"] = 99  # not on the wire: the same fingerprint
    data["channels"][0]["name"] = "renamed"  # on the wire: another mission file
    other = parse_mission(yaml.safe_dump(data, sort_keys=False), "o.yaml").table
    theirs = FrameCodec(other, frame_authenticator(other, KEY, 1))
    frame = theirs.encode([(other.channels[0], items(gcv)[0][1])], DELAYS, now=100.0)
    with pytest.raises(FrameError) as refused:
        lsv.decode(frame, 1, now=100.0)
    assert refused.value.reason == "check"
    fingerprint = lsv.sender_fingerprint(frame)
    assert fingerprint is not None and lsv.vouch(frame, 1, fingerprint) is not None
    junk = bytearray(frame)
    junk[-4] ^= 1
    assert lsv.vouch(bytes(junk), 1, fingerprint) is None
