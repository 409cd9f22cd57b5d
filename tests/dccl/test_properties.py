"""Property tests: any valid value round-trips (within quantisation), the generated fast path
and the reference path agree bit for bit, and no byte string makes decode raise anything but
DecodeError."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from bridge.dccl import RULES, DcclMessage, load_message
from bridge.errors import DecodeError
from tests.dccl.conftest import PROTOS

GOLDEN: DcclMessage = load_message(PROTOS / "golden.proto", "Golden")
NESTED: DcclMessage = load_message(PROTOS / "golden.proto", "Nested")
CHOICE: DcclMessage = load_message(PROTOS / "golden.proto", "Choice")
V3: DcclMessage = load_message(PROTOS / "golden.proto", "V3Msg")
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
    for msg in (GOLDEN, NESTED, CHOICE, V3):
        try:
            fast = msg.decode(data)
        except DecodeError:
            continue
        assert fast == msg.decode_reference(data)[0]


AUV = PROTOS.parents[2] / "deploy" / "missions" / "dccl" / "auv.proto"
BY_RULE = {rule: {name: load_message(AUV, name, rule)
                  for name in ("NavStatus", "Bathymetry", "MorphVector")} for rule in RULES}
#: ±180 at precision 12 (2**48 steps: the generated code takes libdccl's roundings one by one)
BOUNDS = {rule: load_message(PROTOS / "libdccl" / "numeric_bounds.proto", "NumericMsg", rule)
          for rule in RULES}


def _near_ties(lo: float, hi: float, res: float) -> st.SearchStrategy:
    """Values at and around k*res + res/2, where a double division could round the other way."""
    n = round((hi - lo) / res)
    base = st.integers(0, n - 1).map(lambda k: lo + (k + 0.5) * res)
    return st.one_of(st.floats(lo, hi), base, base.map(lambda x: x * (1 + 1e-16)),
                     base.map(lambda x: x * (1 - 1e-16)), st.integers(int(lo), int(hi)))


nav_values = st.fixed_dictionaries({
    "lat": _near_ties(-90, 90, 1e-6), "lon": _near_ties(-180, 180, 1e-6),
    "depth": _near_ties(0, 6000, 0.1), "heading": _near_ties(0, 360, 0.1),
    "speed": _near_ties(0, 5, 0.01), "battery": st.integers(0, 100),
    "mode": st.sampled_from(["idle", "dive", "survey", "transit", "surface", "hold", "abort",
                             "home"]),
    "time": st.integers(0, 86400)})
bathy_values = st.fixed_dictionaries({
    "depth": st.lists(_near_ties(0, 1000, 0.1), min_size=3, max_size=3),
    "altitude": st.lists(_near_ties(0, 655, 0.1), min_size=3, max_size=3),
    "latitude": st.lists(_near_ties(-90, 90, 1e-4), min_size=3, max_size=3),
    "longitude": st.lists(_near_ties(-180, 180, 1e-4), min_size=3, max_size=3)})


@settings(max_examples=400, deadline=None)
@given(nav_values, bathy_values)
def test_fast_path_matches_exact_rounding_near_ties(nav: dict, bathy: dict) -> None:
    for rule, messages in BY_RULE.items():
        for msg, value in ((messages["NavStatus"], nav), (messages["Bathymetry"], bathy)):
            data = msg.encode(value)
            assert data == msg.encode_reference(value), rule
            assert msg.decode(data) == msg.decode_reference(data)[0], rule


@settings(max_examples=400, deadline=None)
@given(st.binary(min_size=40, max_size=40), st.floats(-181, 181))
def test_fast_path_decodes_every_code_as_the_reference(data: bytes, a: float) -> None:
    """Any bits after the right id decode alike in the generated code and the reference path
    (both rules); the large field's generated encoding too."""
    for rule, messages in BY_RULE.items():
        for msg in (*messages.values(), BOUNDS[rule]):
            ident = msg.encode_head({})[:msg.id_bits // 8]
            buffer = ident + data[len(ident):msg.max_size]
            try:
                reference = msg.decode_reference(buffer)
            except DecodeError:
                continue
            assert msg.decode_prefix(buffer) == reference, rule
        value = {"a": a, "u1": 0, "u2": 0}
        assert BOUNDS[rule].encode(value) == BOUNDS[rule].encode_reference(value), rule


choice_values = st.one_of(*(
    st.fixed_dictionaries({"seq": st.integers(0, 7), member: strategy},
                          optional={"flag": st.booleans()})
    for member, strategy in (("depth", st.floats(0, 100)), ("mode", st.sampled_from(ENUM)),
                             ("note", st.text(st.characters(min_codepoint=32,
                                                            max_codepoint=126), max_size=3)))))


@settings(max_examples=200, deadline=None)
@given(choice_values)
def test_oneof_round_trip(value: dict) -> None:
    data = CHOICE.encode(value)
    assert data == CHOICE.encode_reference(value)
    assert _close(CHOICE.decode(data), value, 0.05 + 1e-9)
