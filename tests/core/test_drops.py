"""Dropped payloads: every shape a counted drop by key and cause, told at a bounded rate
(bridge.core.drops), and clamped values counted."""

from __future__ import annotations

import json
import logging
import math
from itertools import pairwise

import msgpack
import pytest

from bridge.core.drops import LOG_EVERY_S, MAX_KEYS, OTHER_KEYS, DropLedger
from bridge.core.events import PayloadDrops
from bridge.core.loaded import parse_mission
from bridge.core.node import NodeCore
from bridge.wire.payloads import MAX_DEPTH

MISSION = """\
mission: shapes
modem: {backend: sim, frame_bytes: 64}
mac: {type: none}
nodes:
  a: {address: 1}
  b: {address: 2}
channels:
  - name: c
    from: a
    to: b
    elements: [{in: k, out: a/k, fields: [
      {field: x, min: -10, max: 10, bits: 8},
      {field: n, type: int, min: 0, max: 65535},
      {field: m, values: [a, b, c]},
      {field: s, type: string, max_length: 8},
      {field: arr, min: 0, max: 1, bits: 4, count: 3},
      {field: p.q, type: int, min: 0, max: 3}]}]
"""

GOOD = {"x": 1.0, "n": 7, "m": "b", "s": "hi", "arr": [0, 0.5, 1], "p": {"q": 2}}


def raw_map(key: bytes, value: bytes = b"\x01") -> bytes:
    """A msgpack map of one entry whose key is the msgpack object ``key``."""
    return b"\x81" + key + value


# (name, payload, encoding, cause)
SHAPES = [
    ("map key that is a map", raw_map(msgpack.packb({"x": 1})), "application/msgpack",
     "undecodable"),
    ("map key that is an array", raw_map(msgpack.packb([1, 2])), "application/msgpack",
     "undecodable"),
    ("map key that is a map, untagged", raw_map(msgpack.packb({"x": 1})), "zenoh/bytes",
     "undecodable"),
    ("NaN key", raw_map(msgpack.packb(math.nan)), "application/msgpack", "unfit"),
    ("integer keys", msgpack.packb({1: 2, 3: 4}), "application/msgpack", "unfit"),
    ("nil key", raw_map(b"\xc0"), "application/msgpack", "unfit"),
    ("binary keys", msgpack.packb({b"x": 1}, use_bin_type=True), "application/msgpack",
     "unfit"),
    ("extension type", msgpack.packb(msgpack.ExtType(5, b"zz")), "application/msgpack",
     "unfit"),
    ("timestamp", b"\xd6\xff\x00\x00\x00\x01", "application/msgpack", "unfit"),
    ("reserved byte", b"\xc1", "application/msgpack", "undecodable"),
    ("truncated", msgpack.packb(GOOD)[:-3], "application/msgpack", "undecodable"),
    ("trailing bytes", msgpack.packb(GOOD) + b"\x00", "application/msgpack", "undecodable"),
    ("deep nesting", b"\x91" * (MAX_DEPTH + 1) + b"\x01", "application/msgpack", "undecodable"),
    ("deep JSON", b"[" * 1000 + b"]" * 1000, "application/json", "undecodable"),
    ("JSON NaN field", b'{"x": NaN, "n": 1, "m": "a", "s": "", "arr": [0,0,0], "p": {"q": 0}}',
     "application/json", "unfit"),
    ("JSON huge integer", b'{"n": ' + b"9" * 5000 + b"}", "application/json", "undecodable"),
    ("wrong types", msgpack.packb({**GOOD, "m": {"a": 1}, "arr": "abc"}), "application/msgpack",
     "unfit"),
    ("a list, not a map", msgpack.packb([GOOD]), "application/msgpack", "unfit"),
    ("nested path not a map", msgpack.packb({**GOOD, "p": [1]}), "application/msgpack", "unfit"),
    ("random bytes", bytes(range(256)) * 4, "zenoh/bytes", "undecodable"),
    ("over the cap", msgpack.packb({**GOOD, "pad": "x" * 100_000}), "application/msgpack",
     "too_large"),
]


@pytest.fixture
def core() -> NodeCore:
    return NodeCore(parse_mission(MISSION), "a")


def test_every_payload_shape_is_a_counted_drop_by_cause(core: NodeCore,
                                                        caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.WARNING)
    for i, (name, data, encoding, cause) in enumerate(SHAPES):
        before = dict(core.outbound.drops.by_cause)
        core.ingest("k", data, encoding, float(i))  # never raises
        after = core.outbound.drops.by_cause
        assert after[("k", cause)] == before.get(("k", cause), 0) + 1, name
        assert sum(after.values()) == sum(before.values()) + 1, name
    assert core.stats.payloads_dropped["k"] == len(SHAPES)
    core.ingest("k", msgpack.packb(GOOD), "application/msgpack", 100.0)
    assert core.stats.payloads_dropped["k"] == len(SHAPES)
    assert core.store.next_due(100.0) is not None  # a good value after them all goes on
    assert not [r for r in caplog.records if r.exc_info]
    causes = core.snapshot(100.0)["payload_drop_causes"]["k"]
    assert sum(causes.values()) == len(SHAPES)


def test_the_cap_comes_from_the_bits_and_refuses_before_decoding(core: NodeCore) -> None:
    cap = core.payload_cap("k")
    assert 16 * 1024 < cap < 32 * 1024
    core.ingest("k", b"[" * (cap + 1), "application/json", 1.0)  # would be a depth error
    assert core.outbound.drops.by_cause == {("k", "too_large"): 1}
    fits = json.dumps({**GOOD, "pad": "x" * (cap - 200)}).encode()
    assert len(fits) <= cap
    core.ingest("k", fits, "application/json", 2.0)
    assert core.stats.payloads_dropped["k"] == 1


def test_clamped_values_are_counted_in_the_stats(core: NodeCore) -> None:
    core.ingest("k", msgpack.packb({**GOOD, "n": 70000, "x": -99.0}), "application/msgpack", 1.0)
    core.ingest("k", msgpack.packb({**GOOD, "n": 70001}), "application/msgpack", 2.0)
    assert core.snapshot(2.0)["clamped"] == {"c": {"n": 2, "x": 1}}
    assert core.stats.payloads_dropped["k"] == 0


def test_a_flood_of_drops_logs_once_a_minute_and_summarises_once_a_second(
        caplog: pytest.LogCaptureFixture) -> None:
    """10 000 drops a second for two minutes, on 3 keys with 2 causes each."""
    caplog.set_level(logging.WARNING)
    ledger = DropLedger("a")
    summaries: list[PayloadDrops] = []
    drops = 0
    for step in range(120 * 100):  # 100 steps a second, 100 drops each
        now = step / 100
        for i in range(100):
            key, cause = f"key{i % 3}", ("undecodable", "unfit")[i % 2]
            summary = ledger.drop(key, cause, f"reason {i}", now)
            drops += 1
            if summary is not None:
                summaries.append(summary)
    lines = [r.getMessage() for r in caplog.records]
    assert 6 <= len(lines) <= 6 * (1 + 120 // LOG_EVERY_S)
    assert len(summaries) <= 121
    times = [s.time for s in summaries]
    assert all(b - a >= 1.0 for a, b in pairwise(times))
    assert sum(s.total for s in summaries) + sum(
        count for count, _ in ledger._pending.values()) == drops
    assert sum(ledger.by_key.values()) == drops
    assert "dropped a payload on 'key0'" in lines[0]
    assert any("more payloads on 'key0' (undecodable) in 60 s" in line for line in lines)


def test_the_ledger_names_a_bounded_number_of_keys() -> None:
    ledger = DropLedger("a")
    for i in range(MAX_KEYS + 500):
        ledger.drop(f"family/{i}", "unfit", "no", 0.0)
    assert len(ledger.by_key) == MAX_KEYS + 1
    assert ledger.by_key[OTHER_KEYS] == 500


def test_a_summary_waits_for_the_tick_when_drops_stop(core: NodeCore) -> None:
    core.ingest("k", b"\xc1", "application/msgpack", 10.0)
    core.ingest("k", b"\xc1", "application/msgpack", 10.5)
    first = [o for o in core.take() if isinstance(o, PayloadDrops)]
    assert [s.total for s in first] == [1]
    core.tick(10.9)
    assert not [o for o in core.take() if isinstance(o, PayloadDrops)]
    core.tick(11.0)
    [later] = [o for o in core.take() if isinstance(o, PayloadDrops)]
    assert later.drops == (("k", "undecodable", 1, later.drops[0][3]),)


def test_a_channel_no_frame_can_hold_is_a_counted_drop_not_due_for_ever() -> None:
    """15-byte frames with DLBL for three peers and a query (its repeatable entries make the
    count field 6 bits): the 26-bit channel fits in no frame (zab check says so). It was
    stored, due for ever and never built into a frame, and the MAC asked the core to act at
    the same instant without end (zab sim --fast hung on such a mission)."""
    text = """\
mission: tight
wire: {dlbl: true}
modem: {backend: sim, frame_bytes: 15}
mac: {type: none}
nodes:
  a: {address: 1}
  b: {address: 2}
  c: {address: 3}
  d: {address: 4}
channels:
  - name: sensors
    from: d
    to: a
    elements: [{in: s, out: d/s, fields: [{field: v, type: int, min: 0, max: 67108863}]}]
queries:
  - {name: health, key: "{node}/health", serve: d, ask: a, reply: [{field: ok, type: bool}]}
"""
    core = NodeCore(parse_mission(text), "d")
    core.ingest("s", msgpack.packb({"v": 5}), "application/msgpack", 10.0)
    assert core.stats.payloads_dropped == {"s": 1}
    drops = [o for o in core.take() if isinstance(o, PayloadDrops)]
    assert "can never fit in a 15-byte frame of 'd'" in drops[0].drops[0][3]
    assert core.wake_at(10.0) != 10.0  # nothing due now: the MAC does not spin on it
