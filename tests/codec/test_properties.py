"""Property tests over random layouts: round trips, exact ends, bit counts, robustness,
and agreement of the generated fast path with the per-field reference path."""

from __future__ import annotations

import contextlib
import math
from typing import Any

import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from bridge.codec import Layout
from bridge.errors import DecodeError, EncodeError

SETTINGS = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])

# Each generated field: (spec dict, levels, value strategy, tolerance, exact values).
Field = tuple[dict[str, Any], int, st.SearchStrategy[Any], float, list[Any]]


@st.composite
def float_bits_field(draw: st.DrawFn) -> Field:
    lo = draw(st.floats(-1e6, 1e6, allow_subnormal=False))
    span = draw(st.floats(1e-3, 1e6))
    hi = lo + span
    assume(hi > lo)
    bits = draw(st.integers(1, 24))
    step = (hi - lo) / (2**bits - 1)
    spec = {"bits": bits, "min": lo, "max": hi}
    return spec, 2**bits, st.floats(lo, hi), step / 2 * (1 + 1e-9) + 1e-9 * abs(hi), [lo, hi]


@st.composite
def float_resolution_field(draw: st.DrawFn) -> Field:
    res = draw(st.sampled_from([1.0, 0.5, 0.25, 0.2, 0.1, 0.05, 0.01, 0.001, 1e-6]))
    start = draw(st.integers(-(10**5), 10**5))
    steps = draw(st.integers(1, 10**6))
    lo, hi = round(start * res, 6), round((start + steps) * res, 6)
    spec = {"type": "float", "min": lo, "max": hi, "resolution": res}
    return spec, steps + 1, st.floats(lo, hi), res / 2 + 1e-9 * max(1, abs(hi), abs(lo)), [lo, hi]


@st.composite
def int_field(draw: st.DrawFn) -> Field:
    step = draw(st.sampled_from([1, 1, 2, 5, 10]))
    lo = draw(st.integers(-(10**9), 10**9))
    steps = draw(st.integers(1, 10**6))
    hi = lo + steps * step
    spec = {"type": "int", "min": lo, "max": hi, "resolution": step}
    return spec, steps + 1, st.integers(lo, hi), step / 2, [lo, hi]


@st.composite
def enum_field(draw: st.DrawFn) -> Field:
    names = draw(
        st.lists(st.text("abcxyz_", min_size=1, max_size=6), min_size=1, max_size=20, unique=True)
    )
    return {"values": names}, len(names), st.sampled_from(names), 0, names


def bool_field() -> st.SearchStrategy[Field]:
    return st.just(({"type": "bool"}, 2, st.booleans(), 0, [True, False]))


@st.composite
def text_field(draw: st.DrawFn) -> Field:
    kind = draw(st.sampled_from(["string", "bytes"]))
    size = draw(st.integers(1, 12))
    fixed = draw(st.booleans())
    spec = {"type": kind, "length" if fixed else "max_length": size}
    levels = 256**size if fixed else (size + 1) * 256**size  # prefix levels x body levels
    if kind == "string":
        values = st.text(st.characters(min_codepoint=1, max_codepoint=0x7F), max_size=size)
    else:
        values = st.binary(min_size=size if fixed else 0, max_size=size)
    return spec, levels, values, 0, []


def ccl_field() -> st.SearchStrategy[Field]:
    return st.sampled_from(
        [
            ({"codec": "ccl.latitude"}, 2**24, st.floats(-90, 90), 90 / (2**23 - 1), [-90.0, 90.0]),
            ({"codec": "ccl.longitude"}, 2**24, st.floats(-180, 180), 180 / (2**23 - 1), [180.0]),
            ({"codec": "ccl.depth"}, 8101, st.floats(0, 6000), 0.5 + 1e-9, [0.0, 6000.0]),
            ({"codec": "ccl.altitude"}, 6551, st.floats(0, 655), 0.05 + 1e-9, [0.0, 655.0]),
        ]
    )


ANY_FIELD = st.one_of(
    float_bits_field(),
    float_resolution_field(),
    int_field(),
    enum_field(),
    bool_field(),
    text_field(),
    ccl_field(),
)


@st.composite
def layouts(draw: st.DrawFn, max_fields: int = 6) -> tuple[Layout, list[Field], dict[str, Any]]:
    fields: list[Field] = draw(st.lists(ANY_FIELD, min_size=1, max_size=max_fields))
    specs, value = [], {}
    for i, (spec, _, values, _, _) in enumerate(fields):
        count = draw(st.sampled_from([None, None, 2]))
        path = f"f{i}" if i % 2 else f"g.f{i}"
        specs.append({**spec, "field": path, **({"count": count} if count else {})})
        drawn = [draw(values) for _ in range(count)] if count else draw(values)
        node = value
        for part in path.split(".")[:-1]:
            node = node.setdefault(part, {})
        node[path.split(".")[-1]] = drawn
    return Layout.from_fields(specs), fields, value


def close(got: Any, want: Any, tol: float) -> bool:
    if isinstance(want, list):
        return all(close(g, w, tol) for g, w in zip(got, want, strict=True))
    if isinstance(want, float) and not isinstance(want, bool):
        return abs(got - want) <= tol
    if isinstance(want, int) and not isinstance(want, bool):
        return abs(got - want) <= tol
    if isinstance(want, bytes):
        return got == want.ljust(len(got), b"\0") if len(got) > len(want) else got == want
    return got == want


def get(value: dict[str, Any], path: str) -> Any:
    for part in path.split("."):
        value = value[part]
    return value


@SETTINGS
@given(layouts())
def test_round_trip_within_half_step(case: tuple[Layout, list[Field], dict[str, Any]]) -> None:
    layout, fields, value = case
    n = layout.pack(value)
    assert 0 <= n < 2**layout.bits
    out = layout.decode(layout.encode(value))
    assert out == layout.unpack(n)
    for codec, (_, _, _, tol, _) in zip(layout.fields, fields, strict=True):
        assert close(get(out, codec.path), get(value, codec.path), tol), codec.describe()
    assert set(layout.clamped.values()) == {0}


@SETTINGS
@given(layouts())
def test_bits_is_sum_of_ceil_log2_levels(case: tuple[Layout, list[Field], dict]) -> None:
    layout, fields, _ = case
    expected = 0
    for codec, (_, levels, _, _, _) in zip(layout.fields, fields, strict=True):
        count = getattr(codec, "count", 1)
        if codec.spec.type in ("string", "bytes") and codec.spec.max_length:
            size = codec.spec.max_length
            per = math.ceil(math.log2(size + 1)) + 8 * size
        else:
            per = math.ceil(math.log2(levels)) if levels > 1 else 0
        expected += per * count
    assert layout.bits == expected
    assert layout.nbytes == math.ceil(layout.bits / 8)


@SETTINGS
@given(
    st.one_of(
        float_bits_field(),
        float_resolution_field(),
        int_field(),
        enum_field(),
        bool_field(),
        ccl_field(),
    )
)
def test_min_and_max_exact(field: Field) -> None:
    spec, _, _, _, exact = field
    layout = Layout.from_fields([{**spec, "field": "v"}])
    for x in exact:
        assert layout.unpack(layout.pack({"v": x}))["v"] == x


@SETTINGS
@given(layouts(), st.data())
def test_random_bytes_only_raise_decode_error(case: tuple[Layout, list, dict], data: Any) -> None:
    layout = case[0]
    size = data.draw(
        st.sampled_from(
            [layout.nbytes, layout.nbytes, 0, layout.nbytes + 1, max(0, layout.nbytes - 1)]
        )
    )
    blob = data.draw(st.binary(min_size=size, max_size=size))
    with contextlib.suppress(DecodeError):
        layout.decode(blob)
    with contextlib.suppress(DecodeError):
        layout.unpack(data.draw(st.integers(-5, 2 ** (layout.bits + 2))))


@st.composite
def wild(draw: st.DrawFn) -> Any:
    return draw(
        st.one_of(
            st.floats(allow_nan=True),
            st.integers(-(2**70), 2**70),
            st.booleans(),
            st.none(),
            st.text(max_size=4),
            st.binary(max_size=4),
            st.lists(st.integers(0, 3), max_size=3),
        )
    )


def _mutate(value: dict[str, Any], data: Any) -> dict[str, Any]:
    """Replace some leaves with wild values (out of range, wrong type, NaN ...)."""
    out: dict[str, Any] = {}
    for key, sub in value.items():
        if isinstance(sub, dict):
            out[key] = _mutate(sub, data)
        elif data.draw(st.integers(0, 3)) == 0:
            out[key] = data.draw(wild())
        else:
            out[key] = sub
    return out


@SETTINGS
@given(layouts(), st.data())
def test_fast_path_agrees_with_reference(case: tuple[Layout, list, dict], data: Any) -> None:
    layout, _, value = case
    value = _mutate(value, data)
    before = dict(layout.clamped)
    try:
        want: Any = layout.pack_reference(value)
    except EncodeError as exc:
        want = ("error", str(exc))
    middle = dict(layout.clamped)
    try:
        got: Any = layout.pack(value)
    except EncodeError as exc:
        got = ("error", str(exc))
    assert got == want
    if not isinstance(want, tuple):
        n = want
        after = layout.clamped
        # the fast call counted exactly the clamps the reference call counted
        assert {k: after[k] - middle[k] for k in after} == {k: middle[k] - before[k] for k in after}
        assert layout.encode(value) == layout.encode_reference(value)
        assert layout.unpack(n) == layout.unpack_reference(n)
        assert layout.decode(layout.encode(value)) == layout.unpack_reference(n)
    rnd = data.draw(st.integers(0, 2**layout.bits - 1))
    try:
        ref: Any = layout.unpack_reference(rnd)
    except DecodeError as exc:
        ref = ("error", str(exc))
    try:
        fast: Any = layout.unpack(rnd)
    except DecodeError as exc:
        fast = ("error", str(exc))
    assert repr(fast) == repr(ref)  # repr: NaN-free, but keeps -0.0 vs 0.0 honest


@SETTINGS
@given(float_bits_field(), st.floats(allow_nan=False, allow_infinity=False), st.data())
def test_clamp_counted_and_reject_raises(field: Field, x: float, data: Any) -> None:
    spec = {**field[0], "field": "v"}
    lo, hi = spec["min"], spec["max"]
    assume(x < lo or x > hi)
    layout = Layout.from_fields([spec])
    calls = data.draw(st.integers(1, 4))
    for _ in range(calls):
        got = layout.unpack(layout.pack({"v": x}))["v"]
    assert got == (lo if x < lo else hi)
    assert layout.clamped == {"v": calls}
    strict = Layout.from_fields([spec], on_out_of_range="reject")
    with pytest.raises(EncodeError, match="out of range"):
        strict.pack({"v": x})
    for bad in (math.nan, math.inf, -math.inf):
        with pytest.raises(EncodeError, match=r"v: .* not a finite number"):
            layout.pack({"v": bad})
    assert layout.clamped == {"v": calls}
