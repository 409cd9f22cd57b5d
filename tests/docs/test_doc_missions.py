"""Every whole mission the documentation shows passes `zab check`, so the docs never drift from
what the bridge takes (the guide's first example named TDMA slot owners it never declared).

A YAML block of docs/ is a whole mission when a line of it starts with ``mission:``; the
fragments (a ``channels:`` or ``nodes:`` excerpt) are not checked here. Such a block is written
to a file of its own, in a folder named after its page and line, and checked as a user would
check it (``zab check --json --no-key``: no frame key on a design laptop).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

from bridge.cli.app import app
from tests.conftest import REPO

DOCS = REPO / "docs"
_BLOCK = re.compile(r"^```ya?ml[^\n]*\n(.*?)^```", re.M | re.S)
_WHOLE = re.compile(r"^mission:", re.M)


def doc_missions() -> list[tuple[str, str]]:
    """(``page:line``, text) of each YAML block of docs/ that is a whole mission."""
    found = []
    for page in sorted(DOCS.rglob("*.md")):
        text = page.read_text(encoding="utf-8")
        for block in _BLOCK.finditer(text):
            if _WHOLE.search(block.group(1)):
                line = text.count("\n", 0, block.start()) + 1
                found.append((f"{page.relative_to(REPO)}:{line}", block.group(1)))
    return found


MISSIONS = doc_missions()


def test_the_docs_show_whole_missions() -> None:
    """The extraction finds the guide's examples (a changed fence would check nothing)."""
    places = [place for place, _ in MISSIONS]
    assert len(places) >= 2, places
    assert all(place.startswith("docs/mission-file.md:") for place in places[:2]), places


@pytest.mark.parametrize(("place", "text"), MISSIONS, ids=[place for place, _ in MISSIONS])
def test_every_doc_mission_passes_zab_check(place: str, text: str, tmp_path: Path) -> None:
    path = tmp_path / (re.sub(r"\W+", "_", place) + ".yaml")
    path.write_text(text, encoding="utf-8")
    result = CliRunner().invoke(app, ["check", str(path), "--json", "--no-key"])
    data = json.loads(result.output)
    assert result.exit_code == 0 and data["ok"], (place, data["errors"])
