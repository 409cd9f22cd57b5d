"""Authenticated frames: forged, altered and replayed frames are refused; mismatch still seen."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bridge.core.loaded import parse_mission
from bridge.errors import FrameError, MissionError
from bridge.runtime.keys import load_key
from bridge.wire.auth import Authenticator
from bridge.wire.frame import CHECK_BYTES, FrameCodec, check_value
from tests.conftest import MISSIONS

KEY = b"0123456789abcdef-mission-key"
TEXT = (MISSIONS / "morph.yaml").read_text()  # ships with auth: {tag_bytes: 4}
PLAIN = TEXT.replace("auth: {tag_bytes: 4}", "auth: off")
LOADED = parse_mission(TEXT, "auth.yaml")
TABLE = LOADED.table
LSV, GCV = LOADED.mission.address_of("lsv"), LOADED.mission.address_of("gcv")


def codec(address: int, key: bytes = KEY) -> FrameCodec:
    return FrameCodec(TABLE, Authenticator(key, TABLE.fingerprint, address, 4))


def frame_from_lsv(sender: FrameCodec) -> bytes:
    target = TABLE.by_name("target_reference")
    return sender.encode([(target, 1234)], [None] * sender.delay_count)


def test_overhead_is_counted_by_check() -> None:
    assert codec(LSV).overhead_bytes() == 12 + 4 + 4 + CHECK_BYTES


def test_sealed_frame_round_trips_once() -> None:
    sender, receiver = codec(LSV), codec(GCV)
    data = frame_from_lsv(sender)
    decoded = receiver.decode(data, LSV)
    assert decoded.channels[0][0].name == "target_reference"
    with pytest.raises(FrameError) as replay:
        receiver.decode(data, LSV)
    assert replay.value.reason == "replayed"
    later = frame_from_lsv(sender)
    assert receiver.decode(later, LSV).channels


def test_wrong_key_is_forged() -> None:
    data = frame_from_lsv(codec(LSV, b"another-key-of-16-bytes-or-more"))
    with pytest.raises(FrameError) as info:
        codec(GCV).decode(data, LSV)
    assert info.value.reason == "forged"


def test_claiming_another_sender_is_forged() -> None:
    data = frame_from_lsv(codec(LSV))
    with pytest.raises(FrameError) as info:
        codec(GCV).decode(data, LOADED.mission.address_of("cv1"))
    assert info.value.reason == "forged"


def test_altered_frame_with_recomputed_check_is_forged() -> None:
    data = bytearray(frame_from_lsv(codec(LSV)))
    data[13] ^= 0x10  # inside the channel payload
    body = bytes(data[:-CHECK_BYTES])
    crc = check_value(body, TABLE.fingerprint)
    with pytest.raises(FrameError) as info:
        codec(GCV).decode(body + crc, LSV)
    assert info.value.reason == "forged"


def test_bit_flips_are_refused_and_other_missions_still_fail_the_check() -> None:
    data = frame_from_lsv(codec(LSV))
    for i in range(len(data) * 8):
        flipped = bytearray(data)
        flipped[i // 8] ^= 1 << (i % 8)
        with pytest.raises(FrameError):
            codec(GCV).decode(bytes(flipped), LSV)
    plain = parse_mission(PLAIN, "plain.yaml")
    with pytest.raises(FrameError) as info:
        FrameCodec(plain.table).decode(data, LSV)
    assert info.value.reason == "check"


@settings(max_examples=1000, deadline=None)
@given(st.binary(max_size=64))
def test_random_bodies_with_valid_check_never_authenticate(body: bytes) -> None:
    crc = check_value(body, TABLE.fingerprint)
    with pytest.raises(FrameError):
        codec(GCV).decode(body + crc, LSV)


def test_key_comes_from_env_or_file(tmp_path, monkeypatch) -> None:
    monkeypatch.delenv("ZAB_TEST_KEY", raising=False)
    with pytest.raises(MissionError, match="no key"):
        load_key("ZAB_TEST_KEY", None)
    key_file = tmp_path / "key"
    key_file.write_text("file-key-0123456789\n")
    assert load_key("ZAB_TEST_KEY", key_file) == b"file-key-0123456789"
    monkeypatch.setenv("ZAB_TEST_KEY", "env-key-0123456789")
    assert load_key("ZAB_TEST_KEY", key_file) == b"env-key-0123456789"
    with pytest.raises(MissionError, match="16 bytes"):
        Authenticator(b"short", TABLE.fingerprint, 1, 4)
