"""The DCCL part of ``zab check``: each DCCL element's bit budget, like ``dccl --analyze``."""

from __future__ import annotations

from typing import Any

from bridge.dccl.analyze import analyze
from bridge.dccl.layout import DcclLayout

__all__ = ["dccl_reports"]


def dccl_reports(table: Any) -> list[dict[str, Any]]:
    """One entry per channel element that carries a DCCL message, in channel order."""
    out = []
    for channel in table.channels:
        for i, element in enumerate(channel.elements):
            layout = element.layout
            if isinstance(layout, DcclLayout):
                m = layout.message
                out.append({"channel": channel.name, "element": i, "message": m.name,
                            "id": m.id, "min_bytes": m.min_bytes, "max_bytes": m.max_size,
                            "analysis": analyze(m)})
    return out
