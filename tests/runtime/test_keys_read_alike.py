"""A peer that comes up over IP reading an input key as this node does: said once, in words
(zab check warns of the mission beforehand: tests/core/test_surfacing.py)."""

from __future__ import annotations

import logging

import pytest

from bridge.core.loaded import parse_mission
from bridge.runtime.zenoh_node import BridgeNode
from tests.conftest import MISSIONS

BARE = (MISSIONS / "zspace.yaml").read_text().replace('in: "{node}/status"', "in: status")


def test_a_peer_up_over_ip_reading_our_keys_is_told_once(caplog: pytest.LogCaptureFixture
                                                          ) -> None:
    node = BridgeNode(parse_mission(BARE, "z.yaml"), "auv1", lambda: None)  # (never started:
    node._flush = node._wake_all = lambda: None  # type: ignore[method-assign]  # no Zenoh here)
    with caplog.at_level(logging.WARNING, logger="zab.node"):
        node._ip_changed("top", True)  # reads none of auv1's inputs
        node._ip_changed("auv2", True)
        node._ip_changed("auv2", False)
        node._ip_changed("auv2", True)  # once per peer
    assert [r.getMessage() for r in caplog.records] == [
        "auv1: auv2 is reachable over IP and reads 'status' as this node does: their samples "
        "cannot be told apart from this vehicle's own, and are taken as its own (name the "
        "sender in the mission's input keys, e.g. '{node}/status')"]
    assert node.core.surfacing is not None and node.core.surfacing.reachable == {"top", "auv2"}
