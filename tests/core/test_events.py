"""Typed events: in-process classes, and the maps they become on the wire (names unchanged)."""

from __future__ import annotations

from bridge.core.events import (
    Delivery,
    FrameDropped,
    FrameReceived,
    FrameSent,
    Link,
    Position,
    Range,
    notable,
)
from bridge.ranging.localise import NoFix


def test_the_wire_map_keeps_the_published_names_and_order() -> None:
    sent = FrameSent(1.0, 3, ["nav"], None, b"abc")
    assert (sent.kind, sent.to_dict()) == ("frame_sent", {
        "time": 1.0, "bytes": 3, "channels": ["nav"], "dest": None, "data": b"abc"})
    heard = FrameReceived(2.0, "a", 3, ["nav"], b"abc", {"snr": 9.0}, {"nav": [{"x": 1}]})
    assert list(heard.to_dict()) == ["time", "src", "bytes", "channels", "data", "meta", "values"]
    assert "members" in FrameReceived(2.0, "a", 3, [], b"", {}, {}, {"c": {}}).to_dict()
    rng = Range(5.0, "b", 50.0, 0.0333, 1500.0, "dlbl", "default")
    assert list(rng.to_dict()) == ["peer", "range_m", "time", "travel_time_s",
                                   "sound_speed_mps", "method", "sound_speed_source"]
    assert Position(6.0, NoFix("no_depth")).to_dict()["fix"] is False


def test_optional_fields_are_left_out_when_absent() -> None:
    assert FrameDropped(1.0, None, "unknown_source", data=b"x").to_dict() == {
        "time": 1.0, "src": None, "reason": "unknown_source", "data": b"x"}
    assert FrameDropped(1.0, "a", "malformed", "bad").to_dict() == {
        "time": 1.0, "src": "a", "reason": "malformed", "error": "bad"}


def test_notable_events_are_the_operator_facing_ones() -> None:
    assert notable(Link(1.0, "a", "down", None, None))
    assert not notable(FrameSent(1.0, 3, [], None, b""))
    assert notable(Delivery(1.0, "cmd", 4, "auv", "failed", "ttl"))
    assert not notable(Delivery(1.0, "cmd", 4, "auv", "delivered"))
