"""The core keeps the shape issue #28 gave it: NodeCore a thin façade over parts that own
their state (its file at most 400 lines), and no class in ``bridge/core`` over 30 methods."""

from __future__ import annotations

import ast

from tests.conftest import REPO

CORE = REPO / "bridge" / "core"


def test_the_facade_stays_thin() -> None:
    lines = len((CORE / "node.py").read_text().splitlines())
    assert lines <= 400, f"bridge/core/node.py has {lines} lines: put new work in a part"


def test_no_class_of_the_core_does_everything() -> None:
    big = []
    for path in sorted(CORE.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ClassDef):
                methods = [n for n in node.body
                           if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef)]
                if len(methods) > 30:
                    big.append(f"{path.relative_to(REPO)}: {node.name} ({len(methods)})")
    assert not big, big
