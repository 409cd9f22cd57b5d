"""The CLI's styled lines. Its consoles read no rich markup or emoji in what they print (a
user's or an exception's text, ``[/]`` or ``:100:``, prints as it is): its own styles come as
:class:`~rich.text.Text` made here."""

from __future__ import annotations

from rich.text import Text


def said(*parts: str | tuple[str, str]) -> Text:
    """One line of parts: a str as it is, a (text, style) pair in that style."""
    return Text.assemble(*parts)
