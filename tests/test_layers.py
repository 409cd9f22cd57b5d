"""The package's layers are a DAG the folders show: each package imports only from the
packages below it in the order ``docs/architecture.md`` writes (its "Layers" list), and no
files import each other, however indirectly (imports under ``TYPE_CHECKING`` and inside
functions count too)."""

from __future__ import annotations

import ast
import re
from collections.abc import Iterator
from pathlib import Path

from tests.conftest import REPO

PACKAGE = REPO / "bridge"
ARCHITECTURE = REPO / "docs" / "architecture.md"


def layers() -> dict[str, int]:
    """Each room (a package under ``bridge/``, or a module beside them) and its floor, from
    the numbered list under ``## Layers`` in docs/architecture.md (1 = the bottom)."""
    text = ARCHITECTURE.read_text()
    section = text.split("## Layers", 1)[1].split("\n## ", 1)[0]
    floors: dict[str, int] = {}
    for line in section.splitlines():
        found = re.match(r"^(\d+)\. (.*)$", line)
        if found:
            for name in re.findall(r"`bridge/([a-z_0-9]+)(?:/|\.py)`", found.group(2)):
                floors[name] = int(found.group(1))
    return floors


def modules(package: Path = PACKAGE) -> dict[str, Path]:
    """Every module of ``package`` by dotted name."""
    out = {}
    for path in package.rglob("*.py"):
        parts = path.relative_to(package.parent).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def imports(name: str, path: Path, known: dict[str, Path]) -> Iterator[tuple[str, int]]:
    """The package's modules that ``name`` (at ``path``) imports, with the line."""
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[:len(anchor) - node.level + 1]
                base = ".".join([*anchor, *([base] if base else [])])
            # ``from bridge.core import node`` names a module; ``from bridge.core.node
            # import NodeCore`` a name in one
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base
                       for a in node.names]
        for target in targets:
            while target and target not in known:  # ``import bridge.x.y`` of a package
                target = target.rpartition(".")[0]
            if target.startswith("bridge") and target != name:
                yield target, node.lineno


def room(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def test_the_layers_are_written_down_for_every_room() -> None:
    floors = layers()
    rooms = {room(m) for m in modules()} - {"__init__", "__main__"}
    assert rooms <= set(floors), f"not in docs/architecture.md's Layers: {rooms - set(floors)}"


def upward(package: Path, floors: dict[str, int]) -> list[str]:
    """Every import in ``package`` from a room on a higher floor than the importer's."""
    known = modules(package)
    top = max(floors.values()) + 1
    found = []
    for name, path in known.items():
        here = floors.get(room(name), top)
        for target, line in imports(name, path, known):
            there = floors.get(room(target), top)
            if there > here:
                found.append(f"{path.relative_to(package.parent)}:{line} imports {target} "
                             f"(floor {here} -> {there})")
    return found


def circles(package: Path) -> list[list[str]]:
    """Groups of modules of ``package`` that import each other, however indirectly."""
    known = modules(package)
    graph = {name: {t for t, _ in imports(name, path, known)} for name, path in known.items()}
    return [sorted(c) for c in strongly_connected(graph) if len(c) > 1]


def test_no_import_runs_back_up() -> None:
    found = upward(PACKAGE, layers())
    assert not found, "\n".join(found)


def test_no_files_import_each_other() -> None:
    found = circles(PACKAGE)
    assert not found, "\n".join(" <-> ".join(c) for c in found)


def strongly_connected(graph: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's strongly connected components, iteratively."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    counter = 0
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            for child in children:
                if child not in graph:
                    continue
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = []
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.append(member)
                        if member == node:
                            break
                    found.append(component)
    return found


def test_the_checks_find_an_upward_import_and_a_circle(tmp_path: Path) -> None:
    """The walk itself, on a planted package: an upward import (a type-only one, inside
    ``TYPE_CHECKING``) and a circle through a relative import are both caught."""
    package = tmp_path / "bridge"
    for room_name in ("low", "high"):
        (package / room_name).mkdir(parents=True)
        (package / room_name / "__init__.py").write_text("")
    (package / "__init__.py").write_text("")
    (package / "low" / "a.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from bridge.high.b import B\n")
    (package / "high" / "b.py").write_text("from .c import C\nB = 1\n")
    (package / "high" / "c.py").write_text("def f():\n    from bridge.high import b\nC = 2\n")
    assert upward(package, {"low": 1, "high": 2}) == [
        "bridge/low/a.py:3 imports bridge.high.b (floor 1 -> 2)"]
    assert circles(package) == [["bridge.high.b", "bridge.high.c"]]
    assert upward(package, {"low": 2, "high": 1}) == []
