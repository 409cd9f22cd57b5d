"""Help-screen details typer gets wrong, fixed in one place.

Typer 0.29 prints a type placeholder for every option, flags included (``--json <bool>``),
which reads as if the flag took a value. A flag takes none, so it shows none.
"""

from __future__ import annotations

from typer import Context
from typer.core import TyperOption

_display_type_rich = TyperOption.display_type_rich


def _flag_shows_no_type(self: TyperOption, ctx: Context) -> str | None:
    if self.is_flag:
        return None
    return _display_type_rich(self, ctx)


def install() -> None:
    """Make option help show flags as flags (idempotent)."""
    TyperOption.display_type_rich = _flag_shows_no_type  # type: ignore[assignment]


HELP_OPTIONS = {"help_option_names": ["-h", "--help"]}
