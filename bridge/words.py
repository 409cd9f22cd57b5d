"""Counts as zab prints them (command line, GUI, reports): "1 bit", "2 bits", never "1 bits"
or "bit(s)"."""

from __future__ import annotations


def counted(n: int, noun: str, plural: str | None = None) -> str:
    """``n`` and ``noun``, in the plural unless ``n`` is 1 (``plural``: when not noun + s)."""
    return f"{n} {noun if n == 1 else plural or noun + 's'}"
