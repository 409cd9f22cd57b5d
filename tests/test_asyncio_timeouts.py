"""The bridge bounds its waits with ``asyncio.timeout``, never ``asyncio.wait_for``.

On Python 3.11, ``wait_for`` returns the awaited result when it lands together with the
task's cancellation, and the cancellation is lost: a fleet stopped while its simulated modems
greeted the water hung for ever, deaf to Ctrl-C and SIGTERM (fd2d4bb).
"""

from __future__ import annotations

import ast
from pathlib import Path

BRIDGE = Path(__file__).resolve().parents[1] / "bridge"


def test_no_wait_for_in_the_bridge() -> None:
    found = [f"{path.relative_to(BRIDGE.parent)}:{node.lineno}"
             for path in sorted(BRIDGE.rglob("*.py"))
             for node in ast.walk(ast.parse(path.read_text()))
             if isinstance(node, ast.Call) and ast.unparse(node.func) == "asyncio.wait_for"]
    assert found == [], f"asyncio.wait_for can lose a cancellation on 3.11: {found}"
