"""Property tests: any valid value round-trips (within quantisation), the generated fast path
and the reference path agree bit for bit, and no byte string makes decode raise anything but
DecodeError."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from bridge.dccl import DcclMessage, load_message
from bridge.errors import DecodeError
from tests.dccl.conftest import PROTOS

GOLDEN: DcclMessage = load_message(PROTOS / "golden.proto", "Golden")
NESTED: DcclMessage = load_message(PROTOS / "golden.proto", "Nested")
ENUM = ["ENUM_A", "ENUM_B", "ENUM_C"]


def _opt(strategy: st.SearchStrategy) -> st.SearchStrategy:
    return st.one_of(st.none(), strategy)


golden_values = st.fixed_dictionaries({
    "d": st.floats(-100, 126),
    "i": _opt(st.integers(-20, 3000)),
    "b": _opt(st.booleans()),
    "s": _opt(st.text(st.characters(min_codepoint=32, max_codepoint=126), max_size=8)),
    "e": _opt(st.sampled_from(ENUM)),
    "r": st.lists(st.integers(0, 100), max_size=4),
})
inner = st.fixed_dictionaries({}, optional={"val": st.floats(0, 126),
                                            "raw": st.binary(max_size=3)})
nested_values = st.fixed_dictionaries({
    "seq": st.integers(0, 15), "b": inner, "c": st.lists(inner, min_size=1, max_size=2),
    "loose": st.sampled_from(ENUM),
}, optional={"a": inner, "f": st.floats(-1, 1, width=32)})


def _close(a: object, b: object, tol: float) -> bool:
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_close(a[k], b[k], tol) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_close(x, y, tol) for x, y in zip(a, b, strict=True))
    if isinstance(a, float):
        return abs(a - b) <= tol  # type: ignore[operator]
    return a == b


@settings(max_examples=300, deadline=None)
@given(golden_values)
def test_golden_round_trip(value: dict) -> None:
    data = GOLDEN.encode(value)
    assert data == GOLDEN.encode_reference(value)
    assert len(data) <= GOLDEN.max_size
    expected = {k: v for k, v in value.items() if v is not None}
    assert _close(GOLDEN.decode(data), expected, 0.005 + 1e-9)
    assert GOLDEN.decode(data) == GOLDEN.decode_reference(data)[0]


@settings(max_examples=300, deadline=None)
@given(nested_values)
def test_nested_round_trip(value: dict) -> None:
    data = NESTED.encode(value)
    assert data == NESTED.encode_reference(value)
    assert _close(NESTED.decode(data), value, 0.125 + 1e-9)


@settings(max_examples=500, deadline=None)
@given(st.binary(max_size=24))
def test_any_bytes_decode_or_raise_decode_error(data: bytes) -> None:
    for msg in (GOLDEN, NESTED):
        try:
            fast = msg.decode(data)
        except DecodeError:
            continue
        assert fast == msg.decode_reference(data)[0]
