"""A small plug-in codec used by the plug-in tests (loaded by module path and entry point)."""

from __future__ import annotations

from typing import Any

from bridge.codec import FieldCodec, FieldSpec


class WrappedAngle(FieldCodec):
    """An angle in degrees wrapped into [0, 360), ``params.bits`` (default 8) bits."""

    def __init__(self, spec: FieldSpec) -> None:
        super().__init__(spec)
        self.bits = int(self.params.get("bits", 8))
        if not 1 <= self.bits <= 32:
            raise ValueError("bits must be 1..32")

    def encode(self, value: Any) -> int:
        x = self.real(value) % 360.0
        return round(x / 360.0 * (1 << self.bits)) % (1 << self.bits)

    def decode(self, n: int) -> float:
        return n * 360.0 / (1 << self.bits)

    def json_schema(self) -> dict[str, Any]:
        return {"type": "number"}

    def describe(self) -> str:
        return f"wrapped angle {self.bits} bit"


class Broken(FieldCodec):
    """Returns codes that do not fit, and fails to decode: the engine must contain it."""

    bits = 4

    def encode(self, value: Any) -> int:
        return 99

    def decode(self, n: int) -> Any:
        raise RuntimeError("boom")


NOT_A_CODEC = 42
