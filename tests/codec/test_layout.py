"""Layout behaviour: the MORPH example, bytes, clamping, rejection, errors, schema."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from bridge.codec import FieldSpec, Layout
from bridge.errors import DecodeError, EncodeError, LayoutError

MORPH = [
    {"field": "vector.x", "bits": 8, "min": 0, "max": 6.2831},
    {"field": "vector.y", "bits": 6, "min": -0.052359878, "max": 0.052359878},
]


def test_api_example_verbatim() -> None:
    layout = Layout.from_fields(
        [
            {"field": "vector.x", "bits": 8, "min": 0, "max": 6.2831},
            {"field": "vector.y", "bits": 6, "min": -0.052359878, "max": 0.052359878},
        ]
    )
    assert layout.bits == 14
    value = {"vector": {"x": 6.2831, "y": -0.052359878}, "header": {"stamp": 1}}
    n = layout.pack(value)
    assert 0 <= n < 2**14
    assert n >> 6 == 255 and n & 63 == 0  # first field in the most significant bits
    assert layout.unpack(n) == {"vector": {"x": 6.2831, "y": -0.052359878}}
    data = layout.encode(value)
    assert data == bytes([0xFF, 0x00]) and len(data) == 2
    assert layout.decode(data) == {"vector": {"x": 6.2831, "y": -0.052359878}}
    assert layout.clamped == {"vector.x": 0, "vector.y": 0}
    assert [f.path for f in layout.fields] == ["vector.x", "vector.y"]
    assert [f.bits for f in layout.fields] == [8, 6]
    assert layout.fields[0].describe() == "float 8 bit [0, 6.2831] step 0.0246"
    assert layout.fields[0].json_schema() == {"type": "number", "minimum": 0, "maximum": 6.2831}
    assert Layout.from_fields([FieldSpec(**f) for f in MORPH], on_out_of_range="reject").bits == 14


def test_json_schema_nested() -> None:
    layout = Layout.from_fields([*MORPH, {"field": "mode", "values": ["a", "b"]}])
    schema = layout.json_schema()
    assert schema["type"] == "object"
    assert schema["required"] == ["vector", "mode"]
    vector = schema["properties"]["vector"]
    assert vector["required"] == ["x", "y"]
    assert vector["properties"]["y"]["minimum"] == -0.052359878
    assert schema["properties"]["mode"] == {"enum": ["a", "b"]}


def test_bytes_padding_and_length_errors() -> None:
    layout = Layout.from_fields(MORPH)
    with pytest.raises(DecodeError):
        layout.decode(b"\xff")  # too short
    with pytest.raises(DecodeError):
        layout.decode(b"\xff\x00\x00")  # extra byte
    with pytest.raises(DecodeError):
        layout.decode(b"\xff\x01")  # non-zero pad bit
    with pytest.raises(DecodeError):
        layout.decode("ab")  # type: ignore[arg-type]
    with pytest.raises(DecodeError):
        layout.unpack(1 << 14)
    with pytest.raises(DecodeError):
        layout.unpack(-1)


@pytest.mark.parametrize("kind", ["bytes", "string"])
def test_a_long_field_after_another_compiles_and_round_trips(kind: str) -> None:
    """Found from outside: a 1.8 kB bytes (or string) field after an int crashed zab check
    ("Exceeds the limit (4300 digits) for integer string conversion": the generated code
    wrote its mask out as a decimal literal)."""
    layout = Layout.from_fields([{"field": "id", "type": "int", "min": 0, "max": 255},
                                 {"field": "data", "type": kind, "max_length": 4000},
                                 {"field": "n", "type": "int", "min": 0, "max": 7}])
    data = bytes(range(256)) * 12 if kind == "bytes" else "zab " * 700
    value = {"id": 200, "data": data, "n": 5}
    assert layout.decode(layout.encode(value)) == value
    assert layout.unpack(layout.pack(value)) == value
    with pytest.raises(DecodeError):  # (a corrupt last byte: refused, no crash)
        layout.decode(layout.encode(value)[:-1] + b"\xff")


def test_clamp_counts_and_reject_raises() -> None:
    layout = Layout.from_fields(MORPH)
    low = layout.unpack(layout.pack({"vector": {"x": -5, "y": 1.0}}))
    assert low == {"vector": {"x": 0.0, "y": 0.052359878}}
    assert layout.clamped == {"vector.x": 1, "vector.y": 1}
    strict = Layout.from_fields(MORPH, on_out_of_range="reject")
    with pytest.raises(EncodeError, match=r"vector\.x: 7 is out of range"):
        strict.pack({"vector": {"x": 7, "y": 0}})
    # a per-field setting overrides the layout default
    mixed = Layout.from_fields(
        [{**MORPH[0], "on_out_of_range": "clamp"}, MORPH[1]], on_out_of_range="reject"
    )
    assert mixed.unpack(mixed.pack({"vector": {"x": 7, "y": 0.0}}))["vector"]["x"] == 6.2831
    with pytest.raises(EncodeError, match=r"vector\.y"):
        mixed.encode({"vector": {"x": 1, "y": 5}})


@pytest.mark.parametrize(
    ("value", "text"),
    [
        ({"vector": {"x": math.nan, "y": 0}}, "vector.x: nan is not a finite number"),
        ({"vector": {"x": math.inf, "y": 0}}, "vector.x: inf is not a finite number"),
        ({"vector": {"x": "1", "y": 0}}, "vector.x: expected a number"),
        ({"vector": {"x": None, "y": 0}}, "vector.x: expected a number"),
        ({"vector": {"x": True, "y": 0}}, "vector.x: expected a number, got bool True"),
        ({"vector": {"x": 0, "y": False}}, "vector.y: expected a number, got bool False"),
        ({"vector": {"x": 1}}, "vector.y: missing"),
        ({"vectr": {"x": 1}}, "vector.x: missing ('vector' not found)"),
        ([], "vector.x: missing"),
    ],
)
def test_garbage_is_never_encoded(value: object, text: str) -> None:
    layout = Layout.from_fields(MORPH)
    with pytest.raises(EncodeError) as info:
        layout.pack(value)
    assert text in str(info.value)
    with pytest.raises(EncodeError):
        layout.encode(value)
    assert layout.clamped == {"vector.x": 0, "vector.y": 0}


def test_resolution_int_bool_enum_string_bytes() -> None:
    layout = Layout.from_fields(
        [
            {"field": "depth", "min": 0, "max": 1000, "resolution": 0.1},
            {"field": "battery", "type": "int", "min": 0, "max": 100},
            {"field": "step", "type": "int", "min": -10, "max": 10, "resolution": 5},
            {"field": "ok", "type": "bool"},
            {"field": "mode", "values": ["idle", "survey", "home"]},
            {"field": "name", "type": "string", "length": 4},
            {"field": "note", "type": "string", "max_length": 5},
            {"field": "blob", "type": "bytes", "max_length": 3},
        ]
    )
    assert [f.bits for f in layout.fields] == [14, 7, 3, 1, 2, 32, 3 + 40, 2 + 24]
    value = {
        "depth": 123.4,
        "battery": 87,
        "step": 4,
        "ok": True,
        "mode": "home",
        "name": "ab",
        "note": "héll",
        "blob": b"\x00\x01",
    }
    out = layout.decode(layout.encode(value))
    assert out == {**value, "step": 5}
    assert repr(out["depth"]) == "123.4"
    assert layout.unpack(layout.pack({**value, "mode": 1}))["mode"] == "survey"
    too_long = layout.unpack(layout.pack({**value, "name": "abcdef", "note": "ééé"}))
    assert too_long["name"] == "abcd" and too_long["note"] == "éé"
    assert layout.clamped["name"] == 1 and layout.clamped["note"] == 1
    for bad in (
        {"mode": "dance"},
        {"mode": 3},
        {"ok": 2},
        {"ok": "yes"},
        {"name": 5},
        {"blob": "text"},
        {"battery": math.nan},
    ):
        with pytest.raises(EncodeError):
            layout.pack({**value, **bad})


def test_invalid_codes_raise_decode_error() -> None:
    layout = Layout.from_fields(
        [
            {"field": "mode", "values": ["a", "b", "c"]},
            {"field": "n", "type": "int", "min": 0, "max": 4},
            {"field": "s", "type": "string", "max_length": 2},
        ]
    )
    good = layout.pack({"mode": "c", "n": 4, "s": "hi"})
    assert layout.unpack(good) == {"mode": "c", "n": 4, "s": "hi"}
    bits_after_mode = layout.bits - 2
    with pytest.raises(DecodeError, match="mode: invalid code 3"):
        layout.unpack(3 << bits_after_mode)
    with pytest.raises(DecodeError, match="n: invalid code 5"):
        layout.unpack(5 << 18)
    with pytest.raises(DecodeError, match="exceeds max_length"):
        layout.unpack(3 << 16)


def test_arrays() -> None:
    layout = Layout.from_fields([{"field": "d", "type": "int", "min": 0, "max": 7, "count": 3}])
    assert layout.bits == 9
    assert layout.pack({"d": [1, 2, 3]}) == 0b001010011
    assert layout.unpack(0b001010011) == {"d": [1, 2, 3]}
    assert layout.pack({"d": (1, 2, 3)}) == 0b001010011
    for bad in ([1, 2], [1, 2, 3, 4], "abc", 5):
        with pytest.raises(EncodeError):
            layout.pack({"d": bad})
    assert layout.fields[0].describe() == "3 × int 3 bit [0, 7]"
    assert layout.fields[0].json_schema()["maxItems"] == 3


def test_whole_payload_field() -> None:
    layout = Layout.from_fields([{"type": "int", "min": 0, "max": 255}])
    assert layout.bits == 8
    assert layout.encode(200) == b"\xc8"
    assert layout.decode(b"\xc8") == 200
    assert layout.json_schema()["type"] == "integer"


def test_int_field_accepts_integral_floats_via_reference() -> None:
    layout = Layout.from_fields([{"field": "n", "type": "int", "min": 0, "max": 100}])
    assert layout.unpack(layout.pack({"n": 42.0})) == {"n": 42}
    assert layout.unpack(layout.pack({"n": 41.6})) == {"n": 42}


@pytest.mark.parametrize(
    ("fields", "loc", "text"),
    [
        ([MORPH[0], {"field": "y", "bits": 8, "min": 0}], (1, "bits"), "needs `min` and `max`"),
        ([MORPH[0], MORPH[0]], (1, "field"), "overlaps"),
        (
            [{"field": "v", "type": "bool"}, {"field": "v.x", "type": "bool"}],
            (1, "field"),
            "overlaps",
        ),
        ([{"field": "a", "codec": "nope"}], (0, "codec"), "known codecs: ccl.altitude"),
        ([{"field": "a", "codec": "ccl.depth", "params": {"max": -3}}], (0, "params"), "> 0"),
        (
            [{"field": "a", "codec": "ccl.depth", "params": {"colour": 1}}],
            (0, "params"),
            "only `max`",
        ),
        ([{"field": "a", "layout": "ccl/missing"}], (0, "layout"), "ccl/missing.yaml"),
        ([42], (0,), "expected a field mapping"),
    ],
)
def test_layout_errors(fields: list, loc: tuple, text: str) -> None:
    with pytest.raises(LayoutError) as info:
        Layout.from_fields(fields)
    assert info.value.loc == loc
    assert text in str(info.value)


def test_layout_files_nest_and_report_inner_errors(tmp_path: Path) -> None:
    (tmp_path / "pose.yaml").write_text(
        "description: pose\nfields:\n  - {field: x, bits: 4, min: 0, max: 1}\n"
        "  - {field: y, bits: 4, min: 0, max: 1}\n"
    )
    (tmp_path / "bad.yaml").write_text("fields:\n  - {field: x, bits: 99, min: 0, max: 1}\n")
    layout = Layout.from_fields([{"field": "pose", "layout": "pose"}], layout_dirs=[tmp_path])
    assert [f.path for f in layout.fields] == ["pose.x", "pose.y"]
    assert layout.unpack(layout.pack({"pose": {"x": 1, "y": 0}})) == {"pose": {"x": 1.0, "y": 0.0}}
    with pytest.raises(LayoutError) as info:
        Layout.from_fields([{"layout": "bad"}], layout_dirs=[tmp_path])
    assert info.value.loc == (0, "layout")
    assert "fields.0.bits" in str(info.value) and "bits must be 1..64" in str(info.value)
    (tmp_path / "loop.yaml").write_text("fields:\n  - {field: a, layout: loop}\n")
    with pytest.raises(LayoutError, match="nest deeper"):
        Layout.from_fields([{"layout": "loop"}], layout_dirs=[tmp_path])


def test_reject_policy_inherited_by_nested_layout() -> None:
    layout = Layout.from_fields(
        [{"field": "s", "layout": "ccl/state", "on_out_of_range": "reject"}]
    )
    value = {
        "s": {
            "latitude": 1,
            "longitude": 2,
            "heading": 3,
            "speed": 1,
            "depth": 5,
            "altitude": 6,
            "battery": 50,
            "leg": 1,
            "fix_age": 3,
            "fault": False,
        }
    }
    assert layout.unpack(layout.pack(value))["s"]["battery"] == 50
    with pytest.raises(EncodeError, match=r"s\.battery"):
        layout.pack({"s": {**value["s"], "battery": 101}})


def test_readme_example_verbatim() -> None:
    from bridge.codec import Layout

    layout = Layout.from_fields([{"field": "vector.x", "bits": 8, "min": 0, "max": 6.2831},
                                 {"field": "vector.y", "bits": 6, "min": -0.052359878,
                                  "max": 0.052359878}])  # fmt: skip
    assert layout.bits == 14
    data = layout.encode({"vector": {"x": 1.0, "y": 0.01}})  # 2 bytes
    assert len(data) == 2
    out = layout.decode(data)
    assert abs(out["vector"]["x"] - 1.0) <= 6.2831 / 255 / 2
    assert abs(out["vector"]["y"] - 0.01) <= 2 * 0.052359878 / 63 / 2


@pytest.mark.parametrize("field", [{"field": "n", "type": "int", "min": 0, "max": 100},
                                   {"field": "n", "min": 0, "max": 100, "resolution": 0.5},
                                   {"field": "n", "codec": "ccl.latitude"},
                                   {"field": "n", "codec": "ccl.depth"}])
def test_a_bool_in_a_number_field_is_refused_not_taken_for_0_or_1(field: dict) -> None:
    """A bool is no number in the payload schema (JSON Schema's "number"): before, True went
    as 1 and False as 0, silently."""
    layout = Layout.from_fields([field])
    for value in (True, False):
        with pytest.raises(EncodeError, match="n: expected a number, got bool"):
            layout.pack({"n": value})
    assert layout.unpack(layout.pack({"n": 1}))["n"] == pytest.approx(1, abs=1e-3)
