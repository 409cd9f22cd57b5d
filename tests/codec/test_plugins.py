"""Plug-in codecs: module path, entry point (through the real lookup), registration."""

from __future__ import annotations

from importlib import metadata

import pytest

from bridge.codec import FieldCodec, Layout, known_codecs, plugins, register_codec, resolve_codec
from bridge.errors import DecodeError, EncodeError, LayoutError
from tests.codec.sample_codec import WrappedAngle


def test_module_path_codec() -> None:
    layout = Layout.from_fields(
        [
            {
                "field": "hdg",
                "codec": "tests.codec.sample_codec:WrappedAngle",
                "params": {"bits": 10},
            },
            {"field": "ok", "type": "bool"},
        ]
    )
    assert layout.bits == 11
    assert isinstance(layout.fields[0], WrappedAngle)
    assert layout.unpack(layout.pack({"hdg": 370.0, "ok": True})) == {"hdg": 9.84375, "ok": True}
    assert layout.fields[0].describe() == "wrapped angle 10 bit"
    assert layout.unpack(layout.pack({"hdg": 90, "ok": 0})) == layout.unpack_reference(
        layout.pack_reference({"hdg": 90, "ok": 0})
    )
    with pytest.raises(EncodeError, match="hdg: expected a number"):
        layout.pack({"hdg": "north", "ok": True})


def test_bad_params_and_paths_are_layout_errors() -> None:
    with pytest.raises(LayoutError) as info:
        Layout.from_fields(
            [
                {
                    "field": "h",
                    "codec": "tests.codec.sample_codec:WrappedAngle",
                    "params": {"bits": 0},
                }
            ]
        )
    assert info.value.loc == (0, "params") and "bits must be 1..32" in str(info.value)
    for name, text in [
        ("tests.codec.sample_codec:Nope", "has no"),
        ("tests.codec.nope:X", "cannot import"),
        ("tests.codec.sample_codec:NOT_A_CODEC", "not a FieldCodec"),
    ]:
        with pytest.raises(LayoutError, match=text):
            Layout.from_fields([{"field": "h", "codec": name}])


def test_misbehaving_codec_is_contained() -> None:
    layout = Layout.from_fields(
        [{"field": "a", "type": "bool"}, {"field": "b", "codec": "tests.codec.sample_codec:Broken"}]
    )
    with pytest.raises(EncodeError, match="returned 99"):
        layout.pack({"a": True, "b": 1})
    with pytest.raises(DecodeError, match="boom"):
        layout.unpack(0)
    with pytest.raises(DecodeError):
        layout.decode(b"\x00")


def test_entry_point_codec(monkeypatch: pytest.MonkeyPatch) -> None:
    ep = metadata.EntryPoint(
        name="acme.angle",
        value="tests.codec.sample_codec:WrappedAngle",
        group=plugins.ENTRY_POINT_GROUP,
    )
    real = metadata.entry_points

    def fake(**kwargs: str) -> metadata.EntryPoints:
        if kwargs.get("group") == plugins.ENTRY_POINT_GROUP:
            return metadata.EntryPoints([ep])
        return real(**kwargs)

    monkeypatch.setattr(metadata, "entry_points", fake)
    assert "acme.angle" in known_codecs()
    assert resolve_codec("acme.angle") is WrappedAngle
    layout = Layout.from_fields([{"field": "h", "codec": "acme.angle"}])
    assert layout.bits == 8 and layout.unpack(layout.pack({"h": 180})) == {"h": 180.0}
    with pytest.raises(LayoutError, match=r"acme\.angle"):  # listed among known names
        resolve_codec("acme.other")


def test_register_codec() -> None:
    class Nibble(FieldCodec):
        bits = 4

        def encode(self, value: object) -> int:
            return int(value) & 15  # type: ignore[call-overload]

        def decode(self, n: int) -> int:
            return n

    register_codec("test.nibble", Nibble)
    register_codec("test.nibble", Nibble)  # same class again is fine
    with pytest.raises(ValueError, match="already registered"):
        register_codec("test.nibble", WrappedAngle)
    with pytest.raises(LayoutError):
        register_codec("test.bad", int)  # type: ignore[arg-type]
    layout = Layout.from_fields([{"field": "n", "codec": "test.nibble", "count": 2}])
    assert layout.bits == 8
    assert layout.unpack(layout.pack({"n": [1, 15]})) == {"n": [1, 15]}
