"""Shared test helpers: free loopback ports and missions rewritten to use them."""

from __future__ import annotations

import socket
from pathlib import Path
from typing import Any

import pytest
import yaml

from bridge.mission_loader import LoadedMission, parse_mission

REPO = Path(__file__).resolve().parent.parent
MISSIONS = REPO / "deploy" / "missions"


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    """A port that was free on 127.0.0.1 a moment ago."""
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def mission_on_free_ports(path: Path, **changes: Any) -> tuple[LoadedMission, dict[str, Any]]:
    """Load an example mission with every node listening on a fresh loopback port.

    ``changes`` replace top-level sections (e.g. ``mac={"type": "none"}``).
    """
    data = yaml.safe_load(path.read_text())
    for node in data["nodes"].values():
        node.setdefault("zenoh", {})["listen"] = [f"tcp/127.0.0.1:{free_port()}"]
    data.update(changes)
    return parse_mission(yaml.safe_dump(data, sort_keys=False), path), data


@pytest.fixture
def morph_path() -> Path:
    return MISSIONS / "morph.yaml"
