"""What ``bridge`` imports is what an installation gets: the standard library, ``bridge``
itself, and the distributions ``pyproject.toml`` declares (not what the dev group happens to
bring in: typer 0.29 vendors click, so ``import click`` worked only beside mkdocs)."""

from __future__ import annotations

import ast
import re
import sys
import tomllib
from collections.abc import Callable
from importlib.metadata import packages_distributions
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def declared() -> set[str]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    names = (re.split(r"[<>=!~;\[ ]", spec, maxsplit=1)[0] for spec in project["dependencies"])
    return {name.lower().replace("_", "-") for name in names}


def _inside(node: ast.AST, parents: dict[ast.AST, ast.AST],
            encloses: Callable[[ast.AST], bool]) -> bool:
    """Whether some statement around ``node`` is one ``encloses`` accepts."""
    while node in parents:
        node = parents[node]
        if encloses(node):
            return True
    return False


def optional(node: ast.AST) -> bool:
    """``try: ... except ImportError`` (an optional extra)."""
    return isinstance(node, ast.Try) and any(
        isinstance(h.type, ast.Name) and h.type.id in {"ImportError", "ModuleNotFoundError"}
        for h in node.handlers)


def type_checking_only(node: ast.AST) -> bool:
    """``if TYPE_CHECKING:``."""
    return isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test)


def imported_roots() -> dict[str, str]:
    """Top-level module name -> a file importing it, for every import in ``bridge/``."""
    roots: dict[str, str] = {}
    for path in sorted((ROOT / "bridge").rglob("*.py")):
        tree = ast.parse(path.read_text(), str(path))
        parents = {child: node for node in ast.walk(tree) for child in ast.iter_child_nodes(node)}
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            if _inside(node, parents, optional) or _inside(node, parents, type_checking_only):
                continue
            for name in names:
                roots.setdefault(name.split(".")[0], str(path.relative_to(ROOT)))
    return roots


def test_every_import_is_the_standard_library_or_a_declared_dependency() -> None:
    allowed = declared()
    owners = packages_distributions()
    undeclared = {}
    for root, where in imported_roots().items():
        if root == "bridge" or root in sys.stdlib_module_names:
            continue
        dists = {d.lower().replace("_", "-") for d in owners.get(root, [])}
        if not dists & allowed:
            undeclared[root] = (where, sorted(dists))
    assert undeclared == {}, f"imported but not declared in pyproject.toml: {undeclared}"
