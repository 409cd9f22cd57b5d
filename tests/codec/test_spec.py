"""FieldSpec validation: type inference and precise, field-level error messages."""

from __future__ import annotations

from typing import Any

import pytest
from pydantic import ValidationError

from bridge.codec import FieldSpec


def error(**data: Any) -> tuple[tuple[Any, ...], str]:
    with pytest.raises(ValidationError) as info:
        FieldSpec(**data)
    first = info.value.errors()[0]
    return tuple(first["loc"]), first["msg"]


def test_inference() -> None:
    assert FieldSpec(field="a", bits=8, min=0, max=1).type == "float"
    assert FieldSpec(field="a", min=0, max=1, resolution=0.1).type == "float"
    assert FieldSpec(field="a", values=["x", "y"]).type == "enum"
    assert FieldSpec(field="a", codec="ccl.depth").type is None
    assert FieldSpec(field="a", layout="ccl/state").type is None
    assert FieldSpec(field="a", type="bool").type == "bool"


@pytest.mark.parametrize(
    ("data", "loc", "text"),
    [
        ({"bits": 8, "min": 0}, ("bits",), "`bits` needs `min` and `max`"),
        ({"bits": 0, "min": 0, "max": 1}, ("bits",), "bits must be 1..64"),
        ({"bits": 65, "min": 0, "max": 1}, ("bits",), "bits must be 1..64"),
        ({"bits": 8, "min": 1, "max": 1}, ("max",), "max must be > min"),
        ({"min": 0, "max": 1, "resolution": 0.1, "bits": 3}, ("bits",), "not both"),
        ({"min": 0, "max": 1, "resolution": -1}, ("resolution",), "must be > 0"),
        ({"min": 0, "max": 1.05, "resolution": 0.1}, ("resolution",), "nearest max"),
        ({"type": "bool", "bits": 2}, ("bits",), "not used with type bool"),
        ({"codec": "ccl.depth", "max": 10}, ("max",), "pass codec options in `params`"),
        ({"type": "float", "codec": "ccl.depth"}, ("codec",), "`type` is not used with `codec`"),
        ({"bits": 8, "min": 0, "max": 1, "params": {"a": 1}}, ("params",), "only used with"),
        ({"values": []}, ("values",), "at least one"),
        ({"values": ["a", "a"]}, ("values",), "listed twice"),
        ({"type": "string", "length": 4, "max_length": 8}, ("max_length",), "not both"),
        ({"type": "string", "length": 0}, ("length",), "must be 1.."),
        ({"field": "a..b", "type": "bool"}, ("field",), "dotted path"),
        ({"layout": "../etc/passwd"}, ("layout",), "name under codecs/"),
        ({"layout": "ccl/state", "count": 2}, ("count",), "not supported with `layout`"),
        ({"bits": 8, "min": 0, "max": 1, "colour": "red"}, ("colour",), "Extra inputs"),
        ({"min": 0, "max": float("nan"), "bits": 4}, ("max",), "finite"),
    ],
)
def test_field_errors(data: dict[str, Any], loc: tuple[str, ...], text: str) -> None:
    got_loc, msg = error(**data)
    assert got_loc == loc
    assert text in msg
    assert not msg.startswith("Value error")


@pytest.mark.parametrize(
    ("data", "text"),
    [
        ({"type": "float", "min": 0, "max": 1}, "needs `bits` or `resolution`"),
        ({"type": "int", "min": 0}, "needs `max`"),
        ({"type": "int", "min": 0.5, "max": 4}, "whole-number `min`"),
        ({"type": "enum"}, "needs `values`"),
        ({"type": "bytes"}, "needs `length` or `max_length`"),
        ({"field": "x"}, "cannot tell the field type"),
    ],
)
def test_missing_combinations(data: dict[str, Any], text: str) -> None:
    loc, msg = error(**data)
    assert loc == ()
    assert text in msg


def test_mission_style_embedding_gives_item_locations() -> None:
    from pydantic import BaseModel

    class Channel(BaseModel):
        fields: list[FieldSpec]

    with pytest.raises(ValidationError) as info:
        Channel(fields=[{"field": "a", "type": "bool"}, {"field": "b", "bits": 8, "min": 0}])
    err = info.value.errors()[0]
    assert err["loc"] == ("fields", 1, "bits")
    assert err["msg"] == "`bits` needs `min` and `max`"
