"""Locate the data folders (``codecs/``, ``schemas/``) in a source checkout or an installed wheel.

The wheel carries them as ``bridge/_data/<name>``; a source checkout has them beside ``bridge/``.
"""

from __future__ import annotations

from pathlib import Path

_PACKAGE_DIR = Path(__file__).resolve().parent


def data_dir(name: str) -> Path:
    """Return the folder ``name`` (``"codecs"`` or ``"schemas"``), wherever it was installed."""
    for candidate in (_PACKAGE_DIR / "_data" / name, _PACKAGE_DIR.parent / name):
        if candidate.is_dir():
            return candidate
    raise FileNotFoundError(f"data folder {name!r} not found beside the bridge package")
