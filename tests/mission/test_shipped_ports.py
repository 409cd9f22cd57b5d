"""Each shipped mission listens on ports of its own, so any two examples run side by side
(``zab demo`` beside ``zab sim`` of another mission): its nodes' Zenoh endpoints and its
simulated waters."""

from __future__ import annotations

import re
from collections import defaultdict
from typing import Any

import yaml

from tests.conftest import MISSIONS


def listened(tree: Any, under: str = "") -> set[int]:
    """The ports of ``listen`` endpoints and ``water`` addresses anywhere in ``tree``."""
    found: set[int] = set()
    if isinstance(tree, dict):
        for key, value in tree.items():
            found |= listened(value, str(key))
    elif isinstance(tree, list):
        for value in tree:
            found |= listened(value, under)
    elif isinstance(tree, str) and under in ("listen", "water"):
        found |= {int(p) for p in re.findall(r"127\.0\.0\.1:(\d+)", tree)}
    return found


def test_no_two_shipped_missions_listen_on_the_same_port() -> None:
    owners: dict[int, list[str]] = defaultdict(list)
    for path in sorted(MISSIONS.glob("*.yaml")):
        ports = listened(yaml.safe_load(path.read_text()))
        assert ports, path.name
        for port in ports:
            owners[port].append(path.name)
    shared = {port: names for port, names in owners.items() if len(names) > 1}
    assert shared == {}, shared
