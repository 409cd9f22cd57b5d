"""Compact Control Language (CCL, WHOI REMUS) encodings as field codecs (seed 003).

- ``ccl.latitude`` / ``ccl.longitude``: 24-bit two's complement, ±(2**23 - 1) over ±90° / ±180°
  (about 1.1 m / 2.4 m at the equator). The code 0x800000 (-2**23) is unused and invalid.
- ``ccl.depth``: sliding scale, 0.1 m below 100 m, 0.2 m to 200 m, 0.5 m to 1000 m, 1 m beyond,
  up to ``params.max`` (default 6000 m: 8101 levels, 13 bits).
- ``ccl.altitude``: 0.1 m steps from 0 to ``params.max`` (default 655 m: 13 bits; CCL used 16).
"""

from __future__ import annotations

import bisect
from typing import Any

from bridge.codec.bits import bits_for
from bridge.codec.fields import FieldCodec, FloatCodec, Namespace, _num
from bridge.mission.fields import FieldSpec

__all__ = ["CCL_CODECS", "CclAltitude", "CclDepth", "CclLatitude", "CclLongitude"]

_HALF = (1 << 23) - 1  # largest magnitude code: ±90° / ±180° map to ±_HALF
_MASK = (1 << 24) - 1
_UNUSED = 1 << 23  # -2**23 in two's complement


class _CclAngle(FieldCodec):
    """24-bit signed angle over ±``limit`` degrees."""

    trusted = True
    bits = 24
    limit = 90
    label = "ccl.latitude"

    def __init__(self, spec: FieldSpec) -> None:
        super().__init__(spec)
        if self.params:
            raise ValueError(f"{self.label} takes no params (got {sorted(self.params)})")
        self.scale = _HALF / self.limit

    def encode(self, value: Any) -> int:
        x = self.real(value)
        lim = float(self.limit)
        if x < -lim or x > lim:
            self.out_of_range(value, -self.limit, self.limit)
            x = -lim if x < -lim else lim
        return (int((x + lim) * self.scale + 0.5) - _HALF) & _MASK

    def decode(self, n: int) -> float:
        if n < 0 or n > _MASK or n == _UNUSED:
            raise self.bad_code(n)
        return (n - ((n & _UNUSED) << 1)) * self.limit / _HALF

    def json_schema(self) -> dict[str, Any]:
        return self.with_description(
            {"type": "number", "minimum": -self.limit, "maximum": self.limit}
        )

    @property
    def step(self) -> float:
        """Degrees between two codes (what a decoded angle is rounded to)."""
        return self.limit / _HALF

    def describe(self) -> str:
        return f"{self.label} 24 bit [{-self.limit}, {self.limit}] step {self.step:.3g}°"

    def inline_encode(self, v: str, k: str, ns: Namespace, tag: str) -> list[str] | None:
        lim = repr(float(self.limit))
        return [
            f"if -{lim} <= {v} <= {lim} and {v}.__class__ is not bool:",
            f"    {k} = (int(({v} + {lim}) * {self.scale!r} + 0.5) - {_HALF}) & {_MASK}",
            "else:",
            "    raise _F",
        ]

    def inline_decode(self, k: str, ns: Namespace, tag: str) -> tuple[list[str], str] | None:
        guard = [f"if {k} == {_UNUSED}: raise _F"]
        return guard, f"({k} - (({k} & {_UNUSED}) << 1)) * {self.limit} / {_HALF}"


class CclLatitude(_CclAngle):
    """CCL latitude: 24-bit signed over ±90°."""

    limit = 90
    label = "ccl.latitude"


class CclLongitude(_CclAngle):
    """CCL longitude: 24-bit signed over ±180°."""

    limit = 180
    label = "ccl.longitude"


# (start, end, step) in tenths of a metre; the last band runs to params.max.
_DEPTH_BANDS = ((0, 1000, 1), (1000, 2000, 2), (2000, 10000, 5), (10000, None, 10))


class CclDepth(FieldCodec):
    """CCL sliding-scale depth in metres: finer steps near the surface."""

    trusted = True

    def __init__(self, spec: FieldSpec) -> None:
        super().__init__(spec)
        unknown = set(self.params) - {"max"}
        if unknown:
            raise ValueError(f"ccl.depth takes only `max` (got {sorted(unknown)})")
        self.hi = float(self.params.get("max", 6000.0))
        hi_t = round(self.hi * 10)
        if not self.hi > 0 or abs(self.hi * 10 - hi_t) > 1e-6:
            raise ValueError(f"ccl.depth max must be > 0 in 0.1 m (got {self.hi})")
        # bands: (start_t, step_t, base code); codes run continuously from 0.
        self.bands: list[tuple[int, int, int]] = []
        base = 0
        for start, end, step in _DEPTH_BANDS:
            if hi_t <= start:
                break
            top = hi_t if end is None or hi_t <= end else end
            if (top - start) % step:
                raise ValueError(
                    f"ccl.depth max {self.hi} is not on the {step / 10} m grid above {start / 10} m"
                )
            self.bands.append((start, step, base))
            base += (top - start) // step
        self.kmax = base  # the code of `max` itself
        self.bits = bits_for(self.kmax + 1)
        self._bases = [b for _, _, b in self.bands]

    def encode(self, value: Any) -> int:
        x = self.real(value)
        if x < 0.0 or x > self.hi:
            self.out_of_range(value, 0, _num(self.hi))
            x = 0.0 if x < 0.0 else self.hi
        for i, (start, step, base) in enumerate(self.bands):
            last = i == len(self.bands) - 1
            if last or x < self.bands[i + 1][0] / 10:
                return min(base + int((x - start / 10) * (10 / step) + 0.5), self.kmax)
        raise AssertionError("unreachable")

    def decode(self, n: int) -> float:
        if n < 0 or n > self.kmax:
            raise self.bad_code(n)
        start, step, base = self.bands[bisect.bisect_right(self._bases, n) - 1]
        return (start + (n - base) * step) / 10

    def json_schema(self) -> dict[str, Any]:
        return self.with_description({"type": "number", "minimum": 0, "maximum": self.hi})

    def describe(self) -> str:
        steps = "/".join(f"{step / 10:g}" for _, step, _ in self.bands)
        return f"ccl.depth {self.bits} bit [0, {_num(self.hi)}] m, steps {steps} m"

    def inline_encode(self, v: str, k: str, ns: Namespace, tag: str) -> list[str] | None:
        lines = [f"if {v}.__class__ is bool: raise _F"]
        for i, (start, step, base) in enumerate(self.bands):
            lo = repr(start / 10)
            if i == len(self.bands) - 1:
                cond = f"{lo} <= {v} <= {self.hi!r}"
            else:
                cond = f"{lo} <= {v} < {self.bands[i + 1][0] / 10!r}"
            offset = v if start == 0 else f"({v} - {lo})"
            lines.append(f"{'if' if i == 0 else 'elif'} {cond}:")
            lines.append(f"    {k} = {base} + int({offset} * {10 / step!r} + 0.5)")
        lines += ["else:", "    raise _F", f"if {k} > {self.kmax}: {k} = {self.kmax}"]
        return lines

    def inline_decode(self, k: str, ns: Namespace, tag: str) -> tuple[list[str], str] | None:
        guard = [f"if {k} > {self.kmax}: raise _F"]
        parts = []
        for i, (start, step, base) in enumerate(self.bands):
            value = f"({start} + ({k} - {base}) * {step}) / 10"
            if i < len(self.bands) - 1:
                parts.append(f"{value} if {k} < {self.bands[i + 1][2]} else ")
            else:
                parts.append(value)
        expr = "".join(parts)
        return guard, f"({expr})"


class CclAltitude(FloatCodec):
    """CCL altitude: 0.1 m steps from 0 to ``params.max`` (default 655 m, 13 bits)."""

    def __init__(self, spec: FieldSpec) -> None:
        params = dict(spec.params)
        unknown = set(params) - {"max"}
        if unknown:
            raise ValueError(f"ccl.altitude takes only `max` (got {sorted(unknown)})")
        hi = float(params.get("max", 655.0))
        inner = FieldSpec(
            field=spec.field,
            type="float",
            min=0.0,
            max=hi,
            resolution=0.1,
            on_out_of_range=spec.on_out_of_range,
            description=spec.description,
        )
        super().__init__(inner)
        self.spec, self.params = spec, params

    def describe(self) -> str:
        return f"ccl.altitude {self.bits} bit [0, {_num(self.hi)}] m step 0.1 m"


CCL_CODECS: dict[str, type[FieldCodec]] = {
    "ccl.latitude": CclLatitude,
    "ccl.longitude": CclLongitude,
    "ccl.depth": CclDepth,
    "ccl.altitude": CclAltitude,
}
