"""Locate the data folders (``codecs/``, ``schemas/``, the example ``missions/``) in a source
checkout or an installed wheel.

The wheel carries them as ``bridge/_data/<name>``; a source checkout has them beside ``bridge/``
(the missions in ``deploy/missions/``).
"""

from __future__ import annotations

from pathlib import Path

_PACKAGE_DIR = Path(__file__).resolve().parent


def data_dir(name: str) -> Path:
    """Return the folder ``name`` (``"codecs"``, ``"schemas"`` or ``"missions"``), wherever it
    was installed."""
    for candidate in (_PACKAGE_DIR / "_data" / name, _PACKAGE_DIR.parent / name,
                      _PACKAGE_DIR.parent / "deploy" / name):
        if candidate.is_dir():
            return candidate
    raise FileNotFoundError(f"data folder {name!r} not found beside the bridge package")
