"""``FieldSpec``: one field of a channel or layout, exactly as written in a mission or layout file.

The model validates each key on its own (so errors carry the key in ``loc``) and checks
missing combinations at the end. ``type`` is inferred when absent: ``values`` -> enum,
``bits``/``min``/``max``/``resolution`` -> float, ``codec``/``layout`` -> none.
"""

from __future__ import annotations

import re
from decimal import Decimal
from typing import Any, Literal

from pydantic import ConfigDict, Field, ValidationInfo, field_validator, model_validator
from pydantic_core import PydanticCustomError

from bridge.mission.base import MissionModel

__all__ = ["MAX_BITS", "MAX_BYTES", "MAX_COUNT", "FieldSpec", "FieldType", "OutOfRange"]

FieldType = Literal["float", "int", "bool", "enum", "string", "bytes"]
OutOfRange = Literal["clamp", "reject"]

#: Widest single numeric field; wider values belong in ``bytes`` or a custom codec.
MAX_BITS = 64
#: Longest ``string``/``bytes`` field; an acoustic frame is at most a few hundred bytes.
MAX_BYTES = 1 << 20  # one value of a string or bytes field; big ones travel fragmented
#: Longest fixed array (``count``).
MAX_COUNT = 1024

def bits_for(levels: int) -> int:
    """Bits needed to tell ``levels`` values apart: ``ceil(log2(levels))`` (0 for one level)."""
    if levels < 1:
        raise ValueError(f"levels must be >= 1, got {levels}")
    return (levels - 1).bit_length()



_PATH = re.compile(r"^([A-Za-z0-9_\-]+(\.[A-Za-z0-9_\-]+)*)?$")
_NUMERIC = {"float", "int"}
# Which keys each type uses; anything else set is an error naming the key.
_KEYS_OF: dict[str, set[str]] = {
    "float": {"min", "max", "bits", "resolution"},
    "int": {"min", "max", "resolution"},
    "bool": set(),
    "enum": {"values"},
    "string": {"length", "max_length"},
    "bytes": {"length", "max_length"},
}


def _err(message: str, **ctx: Any) -> PydanticCustomError:
    return PydanticCustomError("zab_field", message, ctx or None)


def _sibling_failed(info: ValidationInfo, *names: str) -> bool:
    """True if a field validated before this one failed: pydantic leaves it out of
    ``info.data`` (a field that was simply not given is there, as None)."""
    return any(name not in info.data for name in names)


def decimals_of(x: float) -> int:
    """Decimal places of ``x`` as written (0.1 -> 1, 0.25 -> 2, 5 -> 0, 1e-6 -> 6)."""
    exponent = Decimal(repr(float(x))).normalize().as_tuple().exponent
    return max(0, -exponent) if isinstance(exponent, int) else 0


def resolution_levels(lo: float, hi: float, resolution: float) -> int:
    """Levels of a ``resolution`` grid over [lo, hi]: ``round((hi - lo) / resolution) + 1``."""
    return round((hi - lo) / resolution) + 1


class FieldSpec(MissionModel):
    """One field: a dotted ``field`` path into the payload and how to encode the value there."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    field: str = Field("", description="Dotted path into the payload; empty = whole payload.")
    type: FieldType | None = Field(None, description="Value type; inferred when absent.")
    codec: str | None = Field(
        None, description="Named codec: registry name, 'package.module:Class' or entry point."
    )
    layout: str | None = Field(None, description="Reusable layout from codecs/, e.g. ccl/state.")
    params: dict[str, Any] = Field(default_factory=dict, description="Options for `codec`.")
    min: float | None = Field(None, description="Smallest value (float, int).")
    max: float | None = Field(None, description="Largest value (float, int).")
    resolution: float | None = Field(None, description="Step between values (float, int).")
    bits: int | None = Field(None, description="Bits of a bounded float (1..64).")
    values: list[str] | None = Field(None, description="Names of an enum, in code order.")
    length: int | None = Field(None, description="Fixed byte length (string, bytes).")
    max_length: int | None = Field(None, description="Maximum byte length (string, bytes).")
    count: int | None = Field(None, description="Fixed array of this many values.")
    units: str | None = Field(None, max_length=32, description="Units of the value (m, deg, "
                              "m/s...), for people and GUIs; not on the wire.")
    on_out_of_range: OutOfRange | None = Field(
        None, description="clamp (counted) or reject; default set per channel."
    )
    description: str | None = Field(None, description="Free text, copied to the JSON Schema.")

    @model_validator(mode="before")
    @classmethod
    def _infer_type(cls, data: Any) -> Any:
        if isinstance(data, dict) and data.get("type") is None:
            if data.get("codec") is not None or data.get("layout") is not None:
                return data
            if data.get("values") is not None:
                return {**data, "type": "enum"}
            if any(data.get(k) is not None for k in ("bits", "min", "max", "resolution")):
                return {**data, "type": "float"}
        return data

    @field_validator("field")
    @classmethod
    def _check_path(cls, v: str) -> str:
        if not _PATH.match(v):
            raise _err("`field` must be a dotted path like `vector.x` (got {path!r})", path=v)
        return v

    @field_validator("codec")
    @classmethod
    def _check_codec(cls, v: str | None, info: ValidationInfo) -> str | None:
        if v is None:
            return v
        if info.data.get("type") is not None:
            raise _err("`type` is not used with `codec`: the codec defines the value type")
        if not v.strip():
            raise _err("`codec` must not be empty")
        return v

    @field_validator("layout")
    @classmethod
    def _check_layout(cls, v: str | None, info: ValidationInfo) -> str | None:
        if v is None:
            return v
        if info.data.get("type") is not None or info.data.get("codec") is not None:
            raise _err("`layout` cannot be combined with `type` or `codec`")
        if not v or v.startswith("/") or ".." in v.split("/"):
            raise _err("`layout` must be a name under codecs/, like `ccl/bathymetry`")
        return v

    @field_validator("params")
    @classmethod
    def _check_params(cls, v: dict[str, Any], info: ValidationInfo) -> dict[str, Any]:
        if v and info.data.get("codec") is None:
            raise _err("`params` is only used with `codec`")
        return v

    @field_validator("min", "max", "resolution", "bits", "values", "length", "max_length")
    @classmethod
    def _check_used(cls, v: Any, info: ValidationInfo) -> Any:
        if v is None:
            return v
        name = info.field_name
        for other in ("codec", "layout"):
            if info.data.get(other) is not None:
                hint = " (pass codec options in `params`)" if other == "codec" else ""
                raise _err(f"`{name}` is not used with `{other}`{hint}")
        kind = info.data.get("type")
        if kind is not None and name not in _KEYS_OF[kind]:
            raise _err(f"`{name}` is not used with type {kind}")
        return v

    @field_validator("max")
    @classmethod
    def _check_max(cls, v: float | None, info: ValidationInfo) -> float | None:
        lo = info.data.get("min")
        if v is not None and lo is not None and not v > lo:
            raise _err("max must be > min (min={lo}, max={hi})", lo=lo, hi=v)
        return v

    @field_validator("resolution")
    @classmethod
    def _check_resolution(cls, v: float | None, info: ValidationInfo) -> float | None:
        if v is None:
            return v
        if not v > 0:
            raise _err("`resolution` must be > 0")
        if _sibling_failed(info, "min", "max"):
            return v  # min or max has its own error; nothing more to say here
        lo, hi = info.data.get("min"), info.data.get("max")
        if lo is None or hi is None:
            raise _err("`resolution` needs `min` and `max`")
        bits = bits_for(resolution_levels(lo, hi, v))
        if bits > MAX_BITS:
            raise _err(
                "`resolution` {res} over [{lo}, {hi}] needs {bits} bits; at most 64",
                res=v,
                lo=lo,
                hi=hi,
                bits=bits,
            )
        if info.data.get("type") == "int" and not float(v).is_integer():
            raise _err("an int `resolution` (step) must be a whole number")
        steps = (hi - lo) / v
        if abs(steps - round(steps)) > 1e-6 * max(1.0, steps):
            raise _err(
                "max {hi} is not a whole number of {res} steps from min {lo} (nearest max: {near})",
                hi=hi,
                res=v,
                lo=lo,
                near=lo + round(steps) * v,
            )
        return v

    @field_validator("bits")
    @classmethod
    def _check_bits(cls, v: int | None, info: ValidationInfo) -> int | None:
        if v is None:
            return v
        if not 1 <= v <= MAX_BITS:
            raise _err("bits must be 1..64 (got {bits})", bits=v)
        if _sibling_failed(info, "min", "max", "resolution"):
            return v  # a sibling has its own error; nothing more to say here
        if info.data.get("min") is None or info.data.get("max") is None:
            raise _err("`bits` needs `min` and `max`")
        if info.data.get("resolution") is not None:
            raise _err("give either `bits` or `resolution`, not both")
        return v

    @field_validator("values")
    @classmethod
    def _check_values(cls, v: list[str] | None) -> list[str] | None:
        if v is None:
            return v
        if not v:
            raise _err("`values` must name at least one value")
        seen: set[str] = set()
        for name in v:
            if not name:
                raise _err("enum value names must not be empty")
            if name in seen:
                raise _err("enum value {name!r} is listed twice", name=name)
            seen.add(name)
        return v

    @field_validator("length", "max_length")
    @classmethod
    def _check_length(cls, v: int | None, info: ValidationInfo) -> int | None:
        if v is None:
            return v
        if not 1 <= v <= MAX_BYTES:
            raise _err(f"`{info.field_name}` must be 1..{MAX_BYTES} bytes (got {v})")
        if info.field_name == "max_length" and info.data.get("length") is not None:
            raise _err("give either `length` or `max_length`, not both")
        return v

    @field_validator("count")
    @classmethod
    def _check_count(cls, v: int | None, info: ValidationInfo) -> int | None:
        if v is None:
            return v
        if not 1 <= v <= MAX_COUNT:
            raise _err(f"`count` must be 1..{MAX_COUNT} (got {v})")
        if info.data.get("layout") is not None:
            raise _err("`count` is not supported with `layout`")
        return v

    @model_validator(mode="after")
    def _check_complete(self) -> FieldSpec:
        kind = self.type
        if kind is None:
            if self.codec is None and self.layout is None:
                raise _err(
                    "cannot tell the field type: give `type`, `bits`/`min`/`max`, "
                    "`resolution`, `values`, `codec` or `layout`"
                )
            return self
        if kind in _NUMERIC and (self.min is None or self.max is None):
            missing = " and ".join(f"`{k}`" for k in ("min", "max") if getattr(self, k) is None)
            raise _err(f"a {kind} field needs {missing}")
        if kind == "float" and self.bits is None and self.resolution is None:
            raise _err("a float field needs `bits` or `resolution`")
        if kind == "int":
            for key in ("min", "max"):
                if not float(getattr(self, key)).is_integer():
                    raise _err(f"an int field needs a whole-number `{key}`")
            step = int(self.resolution or 1)
            if bits_for(int(self.max - self.min) // step + 1) > MAX_BITS:  # type: ignore[operator]
                raise _err("int range needs more than 64 bits")
        if kind == "enum" and not self.values:
            raise _err("an enum field needs `values`")
        if kind in ("string", "bytes") and self.length is None and self.max_length is None:
            raise _err(f"a {kind} field needs `length` or `max_length`")
        return self

    @property
    def path(self) -> tuple[str, ...]:
        """``field`` split at dots (empty tuple for the whole payload)."""
        return tuple(self.field.split(".")) if self.field else ()
