"""Numbers printed to the step a channel quantised them to (``zab listen``, ``zab demo``).

A value that crossed the water is ``min + k·step``: 3.25242824 at a 0.0246 step says no more
than 3.252, and the extra digits read as precision the channel never carried.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import zenoh

from bridge.core.loaded import LoadedMission


def decimals(step: float) -> int:
    """Decimals that show a value quantised at ``step`` (one more than the step's own, unless
    the step is a power of ten: 0.1 → 1, 0.0246 → 3, 0.05 → 3, 5 → 0)."""
    exponent = math.log10(step)
    return max(0, -math.floor(exponent) + (0 if exponent.is_integer() else 1))


def number(value: float, step: float | None) -> str:
    """``value`` with as many decimals as its quantisation ``step`` warrants (no float noise:
    9.536743164062498e-08 prints as 0.0000 at a 0.0001 step)."""
    if isinstance(value, int) and (step is None or float(step).is_integer()):
        return str(value)
    if step is None or step <= 0 or not math.isfinite(step):
        return f"{value:.6g}"
    return f"{value:.{decimals(step)}f}"


def significant(value: float, digits: int = 3) -> str:
    """``value`` to ``digits`` significant digits, never in exponent form (a step of
    1.07e-05 prints as 0.0000107)."""
    if value == 0 or not math.isfinite(value):
        return f"{value:g}"
    decimals = max(0, digits - 1 - math.floor(math.log10(abs(value))))
    text = f"{value:.{decimals}f}"
    return text.rstrip("0").rstrip(".") if "." in text else text


def to_step(value: Any, steps: Mapping[str, float], path: str = "") -> Any:
    """``value`` (decoded data) with each float at a field path in ``steps`` rounded to its
    step's decimals; anything else as it was."""
    if isinstance(value, dict):
        return {k: to_step(v, steps, f"{path}.{k}" if path else str(k)) for k, v in value.items()}
    step = steps.get(path)
    if isinstance(value, float) and step and step > 0 and math.isfinite(value):
        rounded = round(value, decimals(step))
        return int(rounded) if float(step).is_integer() and rounded.is_integer() else rounded
    return value


class Steps:
    """Each output key's field steps in a mission: what a listener at any node hears."""

    def __init__(self, loaded: LoadedMission) -> None:
        self.exact: dict[str, dict[str, float]] = {}
        self.patterns: list[tuple[zenoh.KeyExpr, dict[str, float]]] = []
        for channel in loaded.table.channels:
            for element in channel.elements:
                steps = {f.path: float(step) for f in element.layout.fields
                         if isinstance(step := getattr(f, "step", None), int | float)}
                if not steps:
                    continue
                for src in channel.senders:
                    for dst in channel.destinations(src):
                        key = element.output_key(src, dst)
                        if "*" in key:
                            self.patterns.append((zenoh.KeyExpr(key), steps))
                        else:
                            self.exact[key] = steps

    def of(self, key: str) -> Mapping[str, float]:
        """The field steps of values published on ``key`` (empty: not a bridged key)."""
        found = self.exact.get(key)
        if found is not None:
            return found
        expr = zenoh.KeyExpr(key)
        return next((steps for pattern, steps in self.patterns if pattern.intersects(expr)), {})
