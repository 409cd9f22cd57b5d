"""Shared test helpers: free loopback ports and missions rewritten to use them."""

from __future__ import annotations

import secrets
import socket
from pathlib import Path

import pytest
import yaml

from bridge.core.loaded import LoadedMission, parse_mission

REPO = Path(__file__).resolve().parent.parent
MISSIONS = REPO / "deploy" / "missions"


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    """A port that was free on 127.0.0.1 a moment ago."""
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def udp_ports(text: str) -> str:
    """``text`` with its ``PORT_A`` and ``PORT_B`` replaced by free loopback UDP ports."""
    for name in ("PORT_A", "PORT_B"):
        text = text.replace(name, str(free_port(socket.SOCK_DGRAM)))
    return text


def on_free_ports(text: str, name: str | Path = "test.yaml") -> LoadedMission:
    """Load mission ``text`` with every node listening on a fresh loopback port."""
    data = yaml.safe_load(text)
    for node in data["nodes"].values():
        node.setdefault("zenoh", {})["listen"] = [f"tcp/127.0.0.1:{free_port()}"]
    return parse_mission(yaml.safe_dump(data, sort_keys=False), name)


def mission_on_free_ports(path: Path) -> LoadedMission:
    """An example mission from ``deploy/missions`` on fresh loopback ports."""
    return on_free_ports(path.read_text(), path)


@pytest.fixture(autouse=True)
def _no_frame_key_from_outside(monkeypatch: pytest.MonkeyPatch) -> None:
    """Tests see no $ZAB_KEY unless they set one: a key in the shell running them would turn
    every mission without wire.auth into an error (and every test mission into a different
    one)."""
    monkeypatch.delenv("ZAB_KEY", raising=False)


@pytest.fixture
def mission_key(monkeypatch: pytest.MonkeyPatch) -> str:
    """A frame key in $ZAB_KEY for this test, as an operator sets it (zab check, run, doctor)."""
    key = secrets.token_hex(32)
    monkeypatch.setenv("ZAB_KEY", key)
    return key


@pytest.fixture
def morph_path() -> Path:
    return MISSIONS / "morph.yaml"
