"""Backend lookup by name."""

from __future__ import annotations

import pytest

from bridge.errors import BackendError
from bridge.modems.base import ModemBackend
from bridge.modems.registry import available_backends, load_backend
from bridge.modems.sim import SimBackend
from bridge.modems.udp import UdpBackend


def test_builtins_load() -> None:
    assert load_backend("sim") is SimBackend
    assert load_backend("udp") is UdpBackend
    assert issubclass(load_backend("sim"), ModemBackend)
    assert {"sim", "udp"} <= set(available_backends())


def test_unknown_backend_lists_known_names() -> None:
    with pytest.raises(BackendError, match=r"unknown modem backend 'nope'.*sim.*udp"):
        load_backend("nope")
