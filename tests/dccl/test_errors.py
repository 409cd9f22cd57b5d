"""Out-of-range values (strict and not), bad input, truncated and corrupt buffers."""

from __future__ import annotations

import pytest

from bridge.dccl import DcclMessage, DcclRangeError, DcclSchemaError, load_message, load_proto
from bridge.errors import DecodeError, EncodeError
from tests.dccl.conftest import PROTOS

GOLDEN = {"d": 10.5, "i": 100, "b": True, "s": "hi", "e": "ENUM_C", "r": [1, 2]}


def test_non_strict_out_of_range_is_not_present(golden: dict[str, DcclMessage]) -> None:
    """libdccl writes an out-of-range value as zero bits: an optional field arrives absent, a
    required one as its min; a long string is truncated, a long list cut to max_repeat."""
    msg = golden["Golden"]
    out = msg.decode(msg.encode({**GOLDEN, "i": 5000, "d": 127.0, "s": "abcdefghij",
                                 "r": [1, 2, 3, 4, 5]}))
    assert "i" not in out
    assert out["d"] == -100.0
    assert out["s"] == "abcdefgh"
    assert out["r"] == [1, 2, 3, 4]
    assert "i" not in msg.decode(msg.encode({**GOLDEN, "i": 3001}))


@pytest.mark.parametrize(("rule", "decoded"), [("dccl-2026", None), ("dccl-4.2", -1.0)])
def test_nan(rule: str, decoded: float | None) -> None:
    """NaN fails dccl-2026's bounds (absent); dccl-4.2 compares the quantised NaN, which passes,
    and converts it to the integer indefinite 2**63, whose low bits are zero: the minimum."""
    msg = load_message(PROTOS / "golden.proto", "Nested", rule)
    out = msg.decode(msg.encode({"seq": 1, "b": {}, "c": [{}], "loose": "ENUM_A",
                                 "f": float("nan")}))
    assert out.get("f") == decoded


@pytest.mark.parametrize("change", [{"i": 5000}, {"d": 126.006}, {"s": "abcdefghi"},
                                    {"r": [0] * 5}])
def test_strict_out_of_range_raises(golden: dict[str, DcclMessage], change: dict) -> None:
    with pytest.raises(DcclRangeError):
        golden["Golden"].encode({**GOLDEN, **change}, strict=True)


def test_edges_of_the_range(golden: dict[str, DcclMessage]) -> None:
    """Accepted while min - res/2 <= v < max + res/2 (libdccl's bounds test)."""
    msg = golden["Golden"]
    assert msg.decode(msg.encode({**GOLDEN, "d": 126.004}, strict=True))["d"] == 126.0
    assert msg.decode(msg.encode({**GOLDEN, "d": -100.005}, strict=True))["d"] == -100.0


@pytest.mark.parametrize("value", [{}, {"d": "x"}, {"d": 10**400}, {"d": 1.0, "e": "NOPE"},
                                   {"d": 1.0, "i": 1.5}, {"d": 1.0, "i": 2**70},
                                   {"d": 1.0, "b": 1}, {"d": 1.0, "r": 3}, [1]])
def test_bad_values_raise_encode_error(golden: dict[str, DcclMessage], value: object) -> None:
    with pytest.raises(EncodeError):
        golden["Golden"].encode(value)  # type: ignore[arg-type]


def test_truncated_buffers_raise_decode_error(golden: dict[str, DcclMessage]) -> None:
    for name, value in (("Golden", GOLDEN), ("Nested", {"seq": 1, "b": {}, "c": [{}],
                                                        "loose": "ENUM_A"})):
        data = golden[name].encode(value)
        for cut in range(len(data)):
            with pytest.raises(DecodeError):
                golden[name].decode(data[:cut])


@pytest.mark.parametrize("data", [b"\x0c\x00", b"\x0b", b"", "0a00"])
def test_foreign_or_corrupt_buffers_raise_decode_error(golden: dict[str, DcclMessage],
                                                       data: object) -> None:
    with pytest.raises(DecodeError):
        golden["Golden"].decode(data)  # type: ignore[arg-type]


def test_decoding_takes_only_its_own_bytes(golden: dict[str, DcclMessage]) -> None:
    msg = golden["Golden"]
    data = msg.encode(GOLDEN)
    assert msg.decode_prefix(data + b"\xff\xff") == (GOLDEN, len(data))


@pytest.mark.parametrize(("name", "line", "reason"), [
    ("NoBounds", 7, "missing (dccl.field).max"),
    ("TooBig", 9, "exceeds allowed maximum (dccl.max_bytes = 2)"),
    ("NoRepeat", 15, "Missing (dccl.field).max_repeat option on `repeated` field"),
    ("V2", 17, "codec_version = 2"),
])
def test_refused_definitions_name_file_line_and_reason(name: str, line: int, reason: str) -> None:
    with pytest.raises(DcclSchemaError) as info:
        load_message(PROTOS / "bad.proto", name)
    assert info.value.line == line
    assert info.value.file.endswith("bad.proto")
    assert reason in str(info.value)


@pytest.mark.parametrize(("file", "reason"), [
    ("unknown_option.proto", 'Option "(dccl.field).minimum" unknown'),
    ("unknown_type.proto", '"Missing" is not defined'),
])
def test_protoc_errors_are_located(file: str, reason: str) -> None:
    with pytest.raises(DcclSchemaError) as info:
        load_proto(PROTOS / file)
    assert info.value.line == 7
    assert reason in info.value.reason


def test_unknown_message_name() -> None:
    with pytest.raises(DcclSchemaError, match="no message 'Nope'"):
        load_message(PROTOS / "golden.proto", "Nope")


def test_two_members_of_a_oneof_is_an_error() -> None:
    msg = load_message(PROTOS / "golden.proto", "Choice")
    with pytest.raises(EncodeError, match="more than one"):
        msg.encode({"seq": 1, "depth": 1.0, "mode": "ENUM_A"})
