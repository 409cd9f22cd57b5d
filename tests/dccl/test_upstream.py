"""libdccl's own test messages and the behaviour its tests assert, as zab's test data.

GobySoft/dccl ``src/test/dccl_min_repeat`` (``test.cpp`` and ``test.proto``, restated in
``protos/libdccl/min_repeat.proto``): a list longer than ``max_repeat`` loses its tail (non-strict),
one shorter than ``min_repeat`` is filled with the field's ``min``, and the three invalid
messages are refused at load. The hex is derived by hand (see each docstring).
"""

from __future__ import annotations

import pytest

from bridge.dccl import DcclRangeError, DcclSchemaError, load_message
from tests.dccl.conftest import PROTOS

FILE = PROTOS / "libdccl" / "min_repeat.proto"


def test_min_and_max_repeat_golden() -> None:
    """TestMsg{a: [0, 1, 2], b: [10, 11], c: [20, 21, 22]}: id 1 → 0x02. Elements are int32
    -100..100 required: ceil_log2(201) = 8 bits, code v + 100. a: count 3 in ceil_log2(5+1) = 3
    bits | b: count - min_repeat = 0 in ceil_log2(3-2+1) = 1 bit | c: count in ceil_log2(1) = 0
    bits. 3+24+1+16+0+24 = 68 bits → 9 bytes."""
    msg = load_message(FILE, "TestMsg")
    value = {"a": [0, 1, 2], "b": [10, 11], "c": [20, 21, 22]}
    assert msg.encode(value).hex() == "02232b33e3f68697a707"
    assert msg.decode(bytes.fromhex("02232b33e3f68697a707")) == value


def test_too_many_values_lose_their_tail() -> None:
    msg = load_message(FILE, "TestMsg")
    value = {"a": [0, 1, 2, 3, 4, 5], "b": [10, 11], "c": [20, 21, 22]}
    assert msg.decode(msg.encode(value)) == {**value, "a": [0, 1, 2, 3, 4]}
    with pytest.raises(DcclRangeError):
        msg.encode(value, strict=True)


def test_too_few_values_are_filled_with_min() -> None:
    msg = load_message(FILE, "TestMsg")
    value = {"a": [0, 1, 2, 3, 4], "c": [20, 21, 22]}
    assert msg.decode(msg.encode(value)) == {**value, "b": [-100, -100]}


@pytest.mark.parametrize(("name", "reason"), [
    ("InvalidTestMsgMissingMaxRepeat", "Missing (dccl.field).max_repeat"),
    ("InvalidTestMsgMaxRepeatLessThanOne", "max_repeat must not be less than 1"),
    ("InvalidTestMsgMaxRepeatLessThanMinRepeat", "must not be less than (dccl.field).min_repeat"),
])
def test_invalid_repeat_settings_are_refused(name: str, reason: str) -> None:
    with pytest.raises(DcclSchemaError, match=reason.replace("(", r"\(").replace(")", r"\)")):
        load_message(FILE, name)
