"""``zab check``'s field steps: what each numeric field of a channel can tell apart, and a
warning for a float field whose bits (or resolution) leave it a step coarser than a quarter
of its range (1 bit over -1000..1000: a 0 arrives as 1000)."""

from __future__ import annotations

from typing import Any

from bridge.codec.fields import FloatCodec
from bridge.mission.fields import bits_for
from bridge.wire.channels import ChannelCodec

__all__ = ["COARSE", "FINE", "coarse_fields", "field_steps"]

COARSE = 4
"""A float field whose step is above 1/COARSE of its range is warned of (fewer than five
values: 2 bits or less)."""
FINE = 100
"""The share of its range the warning says how many bits reach (1/FINE)."""


def _codec(field: Any) -> Any:
    """An array's element codec, else the field's own."""
    return getattr(field, "element", field)


def _number(x: float) -> str:
    """Three significant digits, whole numbers from 1000 on (2000, not 2e+03)."""
    return f"{x:.3g}" if abs(x) < 1000 else f"{x:.0f}"


def field_steps(channel: ChannelCodec) -> list[dict[str, Any]]:
    """Each numeric field of ``channel``'s elements (key, path, bits, range and step): what
    a value of it arrives as, min + k·step (``zab check --json``)."""
    out = []
    for element in channel.elements:
        for field in element.layout.fields:
            codec = _codec(field)
            step = getattr(codec, "step", None)
            if isinstance(step, bool) or not isinstance(step, int | float):
                continue
            lo, hi = getattr(codec, "lo", None), getattr(codec, "hi", None)
            out.append({"key": element.in_key, "field": field.path, "bits": codec.bits,
                        "min": lo, "max": hi, "step": step})
    return out


def coarse_fields(channel: ChannelCodec) -> list[str]:
    """A warning for each float field of ``channel`` whose step is coarser than 1/:data:`COARSE`
    of its range, saying the step and the bits that give 1/:data:`FINE` of it."""
    found = []
    for element in channel.elements:
        for field in element.layout.fields:
            codec = _codec(field)
            if not isinstance(codec, FloatCodec) or codec.step * COARSE <= codec.hi - codec.lo:
                continue
            span, bits = codec.hi - codec.lo, bits_for(FINE + 1)
            given = f"resolution {codec.step:g}" if codec.resolution is not None \
                else f"{codec.bits} bit{'s' if codec.bits > 1 else ''}"
            found.append(
                f"channel {channel.name!r}: field {field.path or '(payload)'!r} (key "
                f"{element.in_key}): {given} over [{codec.lo:g}, {codec.hi:g}] is a step of "
                f"{_number(codec.step)}, only {codec.kmax + 1} values (a step over a quarter of "
                f"the range: a value arrives as the nearest of them); bits: {bits} give a step of "
                f"{_number(span / (2**bits - 1))}, under 1/{FINE} of the range")
    return found
