"""The documentation site builds with `mkdocs build --strict`, and its generated pages follow the
code: every mission model and key, every backend's options, the frame layout."""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from bridge.mission.model import Mission
from bridge.mission.reference import backend_reference, mission_reference, module_doc
from tests.conftest import REPO


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    if importlib.util.find_spec("mkdocs") is None:
        pytest.skip("needs MkDocs (the docs group: uv run pytest installs it)")
    out = tmp_path_factory.mktemp("site")
    done = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)],
        cwd=REPO, capture_output=True, text=True, timeout=300,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert done.returncode == 0, done.stdout + done.stderr
    return out


def _text(html: Path) -> str:
    return re.sub(r"<[^>]+>", " ", html.read_text(encoding="utf-8"))


def test_every_page_of_the_nav_is_built(site: Path) -> None:
    for page in ("concepts", "mission-file", "mission-reference", "wire-format", "dccl", "backends",
                 "ranging", "gui", "deploy", "mission-logs", "developers"):
        assert (site / page / "index.html").is_file(), page
    assert (site / "examples" / "rust" / "src" / "main.rs").is_file()
    assert (site / "examples" / "js" / "morph_client.mjs").is_file()


def test_reference_page_lists_every_model_and_key(site: Path) -> None:
    text = _text(site / "mission-reference" / "index.html")
    assert "zab:mission-reference" not in text
    schema = Mission.model_json_schema(by_alias=True)
    for name, definition in schema["$defs"].items():
        assert name in text, name
        for key in definition.get("properties", {}):
            assert key in text, (name, key)
    for key in schema["properties"]:
        assert f"`{key}`" in mission_reference()


def test_backend_and_frame_pages_carry_the_modules_own_docs(site: Path) -> None:
    backends = _text(site / "backends" / "index.html")
    for name in ("sim", "udp", "evologics", "micromodem"):
        first_line = backend_reference(name).splitlines()[0]
        words = re.sub(r"`", "", first_line).split(":", 1)[1].split()[:4]
        assert " ".join(words) in backends, name
    assert "device" in backends and "probe_retries" in backends
    wire = _text(site / "wire-format" / "index.html")
    assert "CRC-16/CCITT" in wire and "CRC-16/CCITT" in module_doc("bridge.wire.frame")
    with pytest.raises(ValueError):
        module_doc("os")


def test_readme_stays_short_and_links_the_docs() -> None:
    readme = (REPO / "README.md").read_text()
    assert "mkdocs" in readme and "docs/" in readme
    assert "## Wire format" not in readme and "## The mission file" not in readme


def test_each_readme_uv_run_has_what_it_runs_in_a_fresh_clone() -> None:
    """A fresh clone's `uv run` installs the project and the default groups only: a README
    command running a tool from another group names that group (`uv run --group docs ...`)."""
    import tomllib

    project = tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))
    groups = project["dependency-groups"]

    def names(requirements: list[str]) -> set[str]:
        return {re.split(r"[<>=!~\[; ]", r, maxsplit=1)[0].lower() for r in requirements
                if isinstance(r, str)}

    default = names(project["project"]["dependencies"])
    for group in project["tool"]["uv"]["default-groups"]:
        default |= names(groups[group])
    readme = (REPO / "README.md").read_text(encoding="utf-8")
    commands = re.findall(r"uv run((?: --group \S+)*) ([\w.-]+)", readme)
    assert commands
    for extra, tool in commands:
        if tool in ("zab", "python"):
            continue  # the project's own script; the venv's Python
        present = default.union(*(names(groups[g]) for g in re.findall(r"--group (\S+)", extra)))
        assert tool in present, f"`uv run {tool}` needs a group that brings it: {extra!r}"


def test_status_table_tells_what_peers_carry() -> None:
    """Every bridge puts `peers/<peer>` ({last_heard, meta}) on hearing a peer, and the table
    of keys one can subscribe to in docs/developers.md left it out."""
    code = (REPO / "bridge/core/inbound.py").read_text()
    published = re.search(r'status\(f"peers/\{src\}", \{"last_heard": now, "meta": ', code)
    assert published, "inbound.py no longer puts peers/<peer> as documented: update both"
    rows = [line for line in (REPO / "docs/developers.md").read_text().splitlines()
            if line.startswith("| `@zab/<mission>/<node>/peers/<peer>`")]
    assert len(rows) == 1
    assert "`{last_heard, meta}`" in rows[0] and "once a second" in rows[0]
