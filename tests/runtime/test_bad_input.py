"""Bad input from outside is a counted drop, never a crash: payloads nested without bound, text
that is not UTF-8 (in payloads and in string fields, both ways), over real Zenoh sessions and
a real UDP modem link."""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import time
from collections.abc import Iterator

import msgpack
import pytest
import zenoh
from hypothesis import given, settings
from hypothesis import strategies as st

from bridge.codec.layout import Layout
from bridge.core.loaded import LoadedMission
from bridge.errors import DecodeError, EncodeError, FrameError
from bridge.modems.base import ModemSetup
from bridge.modems.udp import UdpBackend
from bridge.runtime.fleet import Fleet
from bridge.wire.frame import FrameCodec
from bridge.wire.payloads import MAX_DEPTH, decode_payload
from tests.conftest import on_free_ports, udp_ports
from tests.harness import Inbox, outside_session, put, running_fleet

JSON = "application/json"
MSGPACK = "application/msgpack"
DEEP = 200_000


def nested_json(depth: int) -> bytes:
    return b"[" * depth + b"1" + b"]" * depth


def nested_msgpack(depth: int) -> bytes:
    return b"\x91" * depth + b"\x01"  # fixarray of one element, `depth` times, around 1


@pytest.mark.parametrize("encoding", [JSON, "text/plain", "zenoh/bytes", ""])
def test_a_200k_deep_json_payload_is_a_decode_error(encoding: str) -> None:
    for data in (b"[" * DEEP, nested_json(DEEP), b'{"a":' * DEEP + b"1" + b"}" * DEEP):
        with pytest.raises(DecodeError, match=f"nested deeper than {MAX_DEPTH} levels"):
            decode_payload(data, encoding)


@pytest.mark.parametrize("encoding", [MSGPACK, "application/x-msgpack", "zenoh/bytes"])
def test_a_200k_deep_msgpack_payload_is_a_decode_error(encoding: str) -> None:
    for depth in (DEEP, 1000, MAX_DEPTH + 1):
        with pytest.raises(DecodeError, match=f"nested deeper than {MAX_DEPTH} levels"):
            decode_payload(nested_msgpack(depth), encoding)


@pytest.mark.parametrize("data", [b"\xc1", b"\xc1not msgpack", b"\x92\x01", b"\x01\x02"])
def test_a_msgpack_error_says_what_is_wrong(data: bytes) -> None:
    """msgpack raises some errors with no text (FormatError on a reserved byte): the drop's
    log line still names the error, never ends at 'not valid application/msgpack: '."""
    with pytest.raises(DecodeError, match=r"not valid application/msgpack: \S"):
        decode_payload(data, MSGPACK)


@pytest.mark.parametrize("encoding", [MSGPACK, "zenoh/bytes", ""])
def test_every_path_names_a_reserved_byte_and_where_it_is(encoding: str) -> None:
    """Tagged msgpack and untagged bytes alike: msgpack's FormatError (no text of its own) is
    named, with its offset, never an empty 'nor msgpack ()'."""
    for data, offset in ((b"\xc1junk", 0), (b"\x93\x01\x02\xc1", 3),
                         (b"\x82\xa1a\x01\xa1b\xc1", 6)):
        with pytest.raises(DecodeError, match=f"reserved byte 0xc1 at offset {offset}\\b"):
            decode_payload(data, encoding)


def test_nesting_up_to_the_limit_decodes() -> None:
    value: object = 1
    for _ in range(MAX_DEPTH):
        value = [value]
    assert decode_payload(nested_json(MAX_DEPTH), JSON) == value
    assert decode_payload(nested_msgpack(MAX_DEPTH), MSGPACK) == value
    with pytest.raises(DecodeError):
        decode_payload(nested_json(MAX_DEPTH + 1), JSON)
    # brackets inside strings (escaped quotes too) are text, not nesting
    text = json.dumps({"note": "[" * 100 + '\\"{' * 50, "v": [[1]]})
    assert decode_payload(text.encode(), JSON)["v"] == [[1]]


def depth_of(value: object) -> int:
    if isinstance(value, dict):
        return 1 + max(map(depth_of, value.values()), default=0)
    if isinstance(value, list):
        return 1 + max(map(depth_of, value), default=0)
    return 0


TEXT = st.text(st.sampled_from('ab[]{}"\\\\é\n'), max_size=8)
VALUES = st.recursive(st.none() | st.integers() | TEXT,
                      lambda inner: st.lists(inner, max_size=3)
                      | st.dictionaries(TEXT, inner, max_size=3), max_leaves=60)


@settings(max_examples=300, deadline=None)
@given(VALUES, st.integers(0, 40))
def test_the_depth_check_agrees_with_the_parsed_value(value: object, wrap: int) -> None:
    """Brackets, quotes and backslashes inside strings never count; real nesting always does."""
    for _ in range(wrap):
        value = [value]
    data = json.dumps(value, ensure_ascii=False).encode()
    if depth_of(value) <= MAX_DEPTH:
        assert decode_payload(data, JSON) == value
    else:
        with pytest.raises(DecodeError, match="nested deeper"):
            decode_payload(data, JSON)


def test_the_depth_check_takes_linear_time() -> None:
    """Unterminated strings full of escaped quotes once took a regex quadratic time (45 s for
    120 kB); the check now reads each byte a bounded number of times."""
    for data in (b"[" + b'"a\\' * 400_000, b'["' + b"a" * 1_000_000 + b"\\",
                 b"[" + b"[]," * 333_333 + b"[]]"):
        start = time.process_time()  # this process's CPU: a second suite beside it adds none
        with contextlib.suppress(DecodeError):
            decode_payload(data, JSON)
        assert time.process_time() - start < 5.0  # at most 0.2 s on a 2-core machine


@pytest.mark.parametrize("data", [
    b'{"s": "\xff"}',                    # not UTF-8 at all
    b'{"s": "\xed\xa0\x80"}',            # an encoded surrogate (json.loads would accept it)
    b'{"s": "\xc0\xaf"}',                # an overlong encoding
], ids=["invalid-byte", "encoded-surrogate", "overlong"])
def test_json_that_is_not_strict_utf8_is_a_decode_error(data: bytes) -> None:
    for encoding in (JSON, "zenoh/bytes"):
        with pytest.raises(DecodeError):
            decode_payload(data, encoding)


def test_msgpack_text_that_is_not_utf8_is_a_decode_error() -> None:
    for body in (b"\xff\xfe", b"\xed\xa0\x80"):
        data = b"\x81\xa1s" + bytes([0xA0 | len(body)]) + body  # {"s": <str of body>}
        with pytest.raises(DecodeError):
            decode_payload(data, MSGPACK)
    assert decode_payload(msgpack.packb({"s": "héllo"}), MSGPACK) == {"s": "héllo"}
    assert decode_payload('{"s": "héllo"}'.encode(), JSON) == {"s": "héllo"}


STRINGS = [{"field": "s", "type": "string", "max_length": 4},
           {"field": "n", "type": "int", "min": 0, "max": 3}]


def test_a_string_field_refuses_text_that_is_not_unicode() -> None:
    """A JSON ``"\\ud800"`` escape decodes to a lone surrogate: not encodable as UTF-8."""
    layout = Layout.from_fields(STRINGS)
    value = decode_payload(b'{"s": "a\\ud800", "n": 1}', JSON)
    with pytest.raises(EncodeError, match="s: not valid Unicode text"):
        layout.pack(value)
    with pytest.raises(EncodeError, match="s: not valid Unicode text"):
        layout.encode(value)
    assert layout.unpack(layout.pack({"s": "aé", "n": 1})) == {"s": "aé", "n": 1}


@pytest.mark.parametrize("body", [b"\xff\xfe", b"\xed\xa0\x80", b"a\x80"])
def test_a_string_field_refuses_bytes_that_are_not_utf8(body: bytes) -> None:
    """The receiving side: the code of a string that is not UTF-8 decodes to nothing."""
    layout = Layout.from_fields(STRINGS)
    code = ((len(body) << 32 | int.from_bytes(body.ljust(4, b"\0"), "big")) << 2) | 1
    with pytest.raises(DecodeError, match="s: not valid UTF-8"):
        layout.unpack(code)
    with pytest.raises(DecodeError, match="s: not valid UTF-8"):
        pad = 8 * layout.nbytes - layout.bits  # bytes hold the bits first, then zero pad bits
        layout.decode((code << pad).to_bytes(layout.nbytes, "big"))
    fixed = Layout.from_fields([{"field": "s", "type": "string", "length": 4}])
    with pytest.raises(DecodeError, match="s: not valid UTF-8"):
        fixed.unpack(int.from_bytes(body.ljust(4, b"\0"), "big"))


LAB = """\
mission: bad-input
modem: {backend: udp, frame_bytes: 16}
mac: {type: none, min_gap_s: 0.2}
nodes:
  a: {address: 1, modem: {options: {port: PORT_A}}}
  b: {address: 2, modem: {options: {port: PORT_B}}}
channels:
  - name: note
    from: a
    to: b
    elements: [{in: note, out: a/note, fields: [{field: s, type: string, max_length: 4},
                                                 {field: n, type: int, min: 0, max: 3}]}]
"""


@contextlib.contextmanager
def lab(loaded: LoadedMission) -> Iterator[tuple[Fleet, zenoh.Session, Inbox]]:
    """The LAB fleet running; an application at ``a`` (to put on ``note``) and what an
    application at ``b`` receives on ``a/note``."""
    with running_fleet(loaded) as fleet:
        a, b = outside_session(loaded, "a"), outside_session(loaded, "b")
        try:
            inbox = Inbox()
            b.declare_subscriber("a/note", inbox)
            time.sleep(0.2)
            yield fleet, a, inbox
        finally:
            a.close()
            b.close()


def test_bad_payloads_and_frames_are_counted_drops_in_a_running_fleet(
        caplog: pytest.LogCaptureFixture) -> None:
    """Over real Zenoh and a real UDP link: each bad payload is counted once and logged without
    a traceback, once per cause (too long for the key: refused before decoding; nested too deep
    or not UTF-8: undecodable; a string that is not Unicode: unfit), a frame with a string that
    is not UTF-8 is a malformed frame, and the channel carries the next good value."""
    text = udp_ports(LAB)
    loaded = on_free_ports(text, "bad-input.yaml")
    caplog.set_level(logging.WARNING)
    with lab(loaded) as (fleet, a, inbox):
        bad = [(nested_json(DEEP), JSON), (b"[" * DEEP, "zenoh/bytes"),
               (nested_msgpack(DEEP), MSGPACK), (nested_json(1000), JSON),
               (nested_msgpack(1000), MSGPACK), (b'{"s": "\xff", "n": 1}', JSON),
               (b'{"s": "\\ud800", "n": 1}', JSON)]
        for data, encoding in bad:  # (blocking: Zenoh would drop a put behind a big one)
            a.put("note", data, encoding=zenoh.Encoding(encoding),
                  congestion_control=zenoh.CongestionControl.BLOCK)
        deadline = time.time() + 10
        while fleet.nodes["a"].stats.payloads_dropped["note"] < len(bad):
            assert time.time() < deadline, fleet.nodes["a"].stats.payloads_dropped
            time.sleep(0.05)
        put(a, "note", {"s": "ok", "n": 2})
        _, value, _ = inbox.get(timeout=5)
        assert value == {"s": "ok", "n": 2}

        codec = FrameCodec(loaded.table)
        [note] = [c for c in loaded.table.channels if c.name == "note"]
        body = b"\xff\xfe"
        frame = codec.encode([(note, ((2 << 32 | int.from_bytes(body.ljust(4, b"\0"), "big"))
                                      << 2) | 1)], [])
        with pytest.raises(FrameError, match="not valid UTF-8") as info:
            codec.decode(frame, 1)
        assert info.value.reason == "malformed"
        before = fleet.nodes["b"].stats.frames_dropped["malformed"]
        asyncio.run(_send_as_a(loaded.mission.nodes["b"].modem.options["port"], frame))
        deadline = time.time() + 5
        while fleet.nodes["b"].stats.frames_dropped["malformed"] == before:
            assert time.time() < deadline, "the frame was not counted"
            time.sleep(0.05)
        assert fleet.nodes["b"].stats.frames_dropped["malformed"] == before + 1
        assert [v for _, v, _ in inbox.drain(0.5) if v != {"s": "ok", "n": 2}] == []
    assert fleet.nodes["a"].stats.payloads_dropped["note"] == len(bad)
    records = [r for r in caplog.records if r.exc_info or "Traceback" in r.getMessage()]
    assert records == [], [r.getMessage() for r in records]
    assert not any("RecursionError" in r.getMessage() for r in caplog.records)
    dropped = [r.getMessage() for r in caplog.records if "dropped a payload" in r.getMessage()]
    assert len(dropped) == 3  # logged once per key and cause
    assert "over this key's cap" in dropped[0] and "(too_large;" in dropped[0]
    assert "nested deeper than" in dropped[1] and "(undecodable;" in dropped[1]
    assert "not valid Unicode text" in dropped[2] and "(unfit;" in dropped[2]
    causes = fleet.nodes["a"].snapshot()["payload_drop_causes"]["note"]
    assert causes == {"too_large": 3, "undecodable": 3, "unfit": 1}


async def _send_as_a(port_b: int, frame: bytes) -> None:
    setup = ModemSetup(node="a", address=1, frame_bytes=16, options={"port": 0},
                       peers={2: {"port": port_b}})
    async with UdpBackend(setup) as modem:
        await modem.send(frame, None)
        await asyncio.sleep(0.3)


def test_every_payload_shape_over_zenoh_is_a_counted_drop_without_a_traceback(
        caplog: pytest.LogCaptureFixture) -> None:
    """The shapes of tests/core/test_drops.py (map keys that are maps or arrays, NaN and
    integer keys, extension types, deep nesting, a payload over the key's cap …) put by a
    plain Zenoh application on a running node's input key: each counted once, no traceback,
    no intake error, and the next good value crosses."""
    from bridge.core.node import NodeCore
    from tests.core.test_drops import SHAPES

    loaded = on_free_ports(udp_ports(LAB), "bad-input.yaml")
    alone = NodeCore(loaded, "a")  # which shapes this mission's channel refuses
    shapes = []
    for shape in SHAPES:
        before = alone.stats.payloads_dropped["note"]
        alone.ingest("note", shape[1], shape[2], 0.0)
        if alone.stats.payloads_dropped["note"] > before:
            shapes.append(shape)
    assert len(shapes) >= 15
    caplog.set_level(logging.WARNING)
    with lab(loaded) as (fleet, a, inbox):
        node = fleet.nodes["a"]
        for count, (name, data, encoding, _) in enumerate(shapes, 1):
            a.put("note", data, encoding=zenoh.Encoding(encoding))
            deadline = time.time() + 5
            while node.stats.payloads_dropped["note"] < count:
                assert time.time() < deadline, name
                time.sleep(0.01)
        put(a, "note", {"s": "ok", "n": 2})
        assert inbox.get(timeout=5)[1] == {"s": "ok", "n": 2}
        snapshot = node.snapshot()
    assert node.stats.payloads_dropped["note"] == len(shapes)
    assert snapshot["intake"]["errors"] == {} and snapshot["intake"]["overflow"] == {}
    assert not [r for r in caplog.records if r.exc_info or "Traceback" in r.getMessage()]


def test_the_modem_drivers_counters_are_in_the_nodes_stats() -> None:
    """`@zab/<mission>/<node>/stats` carries the backend's counters (a noisy modem line, its
    bad_lines/malformed, was visible nowhere): here the UDP modem's frames sent and heard."""
    loaded = on_free_ports(udp_ports(LAB), "modem-stats.yaml")
    with lab(loaded) as (fleet, a, inbox):
        put(a, "note", {"s": "ok", "n": 1})
        assert inbox.get(timeout=5)[1] == {"s": "ok", "n": 1}
        sender, receiver = fleet.nodes["a"].snapshot(), fleet.nodes["b"].snapshot()
    assert sender["modem"]["sent"] >= 1 and receiver["modem"]["received"] >= 1
    assert sender["modem"]["errors"] == 0
