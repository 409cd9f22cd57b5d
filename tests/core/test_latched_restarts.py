"""A latching channel's value survives its sender's restart (virtual clock): put once, saved
with the node's state, sent again by the next run without a new put, its age counted from
when it was really taken; a value past its ``ttl_s`` is not resurrected, nor one whose
channel changed; a state from before (without latched values) or with unreadable ones still
loads. The same through the real processes: tests/runtime/test_latched_processes.py."""

from __future__ import annotations

from itertools import pairwise
from pathlib import Path
from typing import Any

import msgpack
import pytest

from bridge.core.latched import KEEP_LATCHED_S
from bridge.core.loaded import LoadedMission, parse_mission
from bridge.core.node import NodeCore, Publish
from bridge.core.reception import Reception
from bridge.runtime.state_file import StateFile

MISSION = """\
mission: latch
modem: {backend: sim, frame_bytes: 64, options: {preset: evologics-s2c-im, loss: 0}}
mac: {type: tdma, slot_s: 1.0, guard_s: 0.1, order: [ops, auv]}
nodes:
  ops: {address: 1, role: surface, position: {x: 0, y: 0, depth: 0}}
  auv: {address: 2, position: {x: 300, y: 0, depth: 20}}
channels:
  - name: status
    from: auv
    to: ops
    latching: true
    interval_s: 5
    age: {step_s: 0.5, max_s: 600}
    elements:
      - in: status
        out: auv/status
        fields: [{field: mode, type: int, min: 0, max: 15}]
  - name: order
    from: auv
    to: ops
    latching: true
    ttl_s: 30
    elements:
      - in: order
        out: auv/order
        fields: [{field: go, type: int, min: 0, max: 7}]
  - name: nav
    from: auv
    to: ops
    elements:
      - in: nav
        out: auv/nav
        fields: [{field: depth, type: int, min: 0, max: 100}]
"""
LOADED = parse_mission(MISSION, "latch.yaml")


def put(core: NodeCore, key: str, value: dict[str, Any], now: float) -> None:
    core.ingest(key, msgpack.packb(value), "application/msgpack", now)


def saved(core: NodeCore, tmp_path: Path) -> dict[str, Any] | None:
    """``core``'s state through its state file, as a ``kill -9`` leaves it for the next run."""
    state_file = StateFile(tmp_path, "latch", core.node)
    state_file.save(core.state())
    core.saved()
    return StateFile(tmp_path, "latch", core.node).load()


def heard(sender: NodeCore, now: float, loaded: LoadedMission = LOADED) -> dict[str, Publish]:
    """What a surface node publishes of the frame ``sender`` builds at ``now`` (by key)."""
    out = sender.outbound.build(now, now)
    if out is None:
        return {}
    sender.outbound.sent(out, now)
    ops = NodeCore(loaded, "ops")
    ops.receive(Reception(out.data, 2, now, {}), now)
    return {o.key: o for o in ops.take() if isinstance(o, Publish)}


def test_a_value_put_once_is_sent_again_by_the_next_run_without_a_new_put(
        tmp_path: Path) -> None:
    auv = NodeCore(LOADED, "auv")
    auv.saved()
    put(auv, "status", {"mode": 3}, 10.0)
    assert auv.needs_save  # (a latched value asks for a save at once)
    assert heard(auv, 11.0)["auv/status"].value == {"mode": 3}
    state = saved(auv, tmp_path)

    restarted = NodeCore(LOADED, "auv", state=state)  # killed; started again at t=100
    got = heard(restarted, 100.0)
    assert got["auv/status"].value == {"mode": 3}
    assert got["auv/status"].taken == pytest.approx(10.0, abs=0.5)  # its age: from t=10
    again = heard(restarted, 106.0)  # and again at its rate, as before the restart
    assert again["auv/status"].value == {"mode": 3}
    assert len(restarted.outbound.latched.resumed) == 1
    assert restarted.snapshot(106.0)["payload_drop_causes"] == {}


def test_without_the_saved_state_nothing_is_sent() -> None:
    """What the restart did before (and still does with its state lost)."""
    auv = NodeCore(LOADED, "auv")
    put(auv, "status", {"mode": 3}, 10.0)
    assert "auv/status" not in heard(NodeCore(LOADED, "auv"), 100.0)


def test_a_value_past_its_ttl_is_not_resurrected(tmp_path: Path) -> None:
    auv = NodeCore(LOADED, "auv")
    put(auv, "order", {"go": 5}, 10.0)
    state = saved(auv, tmp_path)
    assert heard(NodeCore(LOADED, "auv", state=state), 35.0)["auv/order"].value == {"go": 5}
    late = NodeCore(LOADED, "auv", state=state)
    assert "auv/order" not in heard(late, 41.0)  # 31 s after it arrived: past ttl_s 30
    assert late.next_due(41.0) is None or late.next_due(41.0) > 41.0


def test_the_restart_says_how_many_resumed_values_are_past_their_ttl(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """Found from outside: the log said a value past its ttl_s was resumed, as if it would be
    sent again; it is kept (a later mission edit needs it) but not sent."""
    auv = NodeCore(LOADED, "auv")
    put(auv, "status", {"mode": 3}, 10.0)
    put(auv, "order", {"go": 5}, 10.0)
    state = saved(auv, tmp_path)
    with caplog.at_level("INFO", logger="zab.core"):
        NodeCore(LOADED, "auv", state=state).tick(41.0)
        NodeCore(LOADED, "auv", state=state).tick(20.0)
    told = [r.getMessage() for r in caplog.records if "resumed" in r.getMessage()]
    assert told == [
        "auv: resumed the latched values of 2 channel(s) from its saved state "
        "(1 past their ttl_s, kept unsent)",
        "auv: resumed the latched values of 2 channel(s) from its saved state"]


def test_only_latching_channels_are_kept(tmp_path: Path) -> None:
    auv = NodeCore(LOADED, "auv")
    put(auv, "nav", {"depth": 20}, 10.0)
    state = saved(auv, tmp_path)
    assert state is not None and "latched" not in state
    assert heard(NodeCore(LOADED, "auv", state=state), 11.0) == {}


@pytest.mark.parametrize(("change", "why"), [
    (("fields: [{field: mode, type: int, min: 0, max: 15}]",
      "fields: [{field: mode, type: int, min: 0, max: 31}]"), "its fields changed"),
    (("  - name: status\n", "  - name: state\n"), "no such channel"),
    (("    latching: true\n    interval_s: 5", "    interval_s: 5"), "no longer latching"),
    (("    from: auv\n    to: ops\n    latching: true\n    interval_s: 5",
      "    from: ops\n    to: auv\n    latching: true\n    interval_s: 5"),
     "no longer sends"),
])
def test_a_value_whose_channel_changed_is_dropped_counted(
        tmp_path: Path, change: tuple[str, str], why: str,
        caplog: pytest.LogCaptureFixture) -> None:
    auv = NodeCore(LOADED, "auv")
    put(auv, "status", {"mode": 3}, 10.0)
    put(auv, "order", {"go": 5}, 10.0)
    state = saved(auv, tmp_path)
    assert change[0] in MISSION
    changed = parse_mission(MISSION.replace(change[0], change[1]), "latch.yaml")
    restarted = NodeCore(changed, "auv", state=state)
    restarted.tick(12.0)
    causes = restarted.snapshot(12.0)["payload_drop_causes"]
    assert causes == {"status": {"unresumable": 1}}
    assert why in caplog.text
    got = heard(restarted, 12.0, changed)
    assert "auv/status" not in got and "state" not in str(got)
    assert got["auv/order"].value == {"go": 5}  # its unchanged neighbour resumes


def test_a_state_saved_before_latched_values_were_kept_still_loads(tmp_path: Path) -> None:
    auv = NodeCore(LOADED, "auv")
    put(auv, "status", {"mode": 3}, 10.0)
    state = saved(auv, tmp_path)
    assert state is not None
    del state["latched"]  # (as the previous version wrote it)
    restarted = NodeCore(LOADED, "auv", state=state)
    assert restarted.epoch == auv.epoch  # resumed, not started afresh
    assert heard(restarted, 11.0) == {}
    restarted.tick(11.0)
    assert restarted.snapshot(11.0)["payload_drop_causes"] == {}


@pytest.mark.parametrize("latched", [
    "garbage", 7, {"status": None}, {"status": {"shape": 1}}, {3: {}},
    {"status": {"packed": [b"\x01"], "updated": [1.0], "taken": [1.0]}},
    {"status": {"shape": "x", "packed": "y", "updated": 1, "taken": None}},
    "the shape, values too long",  # (filled in below: a value over its bits)
    "the shape, a value without its time",
    "the shape, the time not a number",
])
def test_unreadable_latched_values_are_counted_drops_never_a_crash(
        tmp_path: Path, latched: Any) -> None:
    auv = NodeCore(LOADED, "auv")
    put(auv, "status", {"mode": 3}, 10.0)
    state = saved(auv, tmp_path)
    assert state is not None
    good = state["latched"]["status"]
    if latched == "the shape, values too long":
        latched = {"status": {**good, "packed": [b"\xff" * 9]}}
    elif latched == "the shape, a value without its time":
        latched = {"status": {**good, "updated": [None]}}
    elif latched == "the shape, the time not a number":
        latched = {"status": {**good, "taken": ["soon"]}}
    state["latched"] = latched
    restarted = NodeCore(LOADED, "auv", state=state)
    assert restarted.epoch == auv.epoch  # the rest of the state resumes
    assert heard(restarted, 11.0) == {}
    restarted.tick(11.0)
    drops = restarted.snapshot(11.0)["payload_drop_causes"]
    assert sum(c.get("unresumable", 0) for c in drops.values()) == 1


def test_a_latched_value_asks_for_a_save_at_most_once_a_second() -> None:
    auv = NodeCore(LOADED, "auv")
    auv.saved()
    asked = []
    for n in range(30):  # 10 Hz for 3 s: the first at once, then once a second
        now = 10.0 + n / 10
        put(auv, "status", {"mode": n % 16}, now)
        auv.tick(now)
        if auv.needs_save:
            asked.append(now)
            auv.saved()
    assert asked[0] == 10.0 and len(asked) == 3
    assert all(b - a >= KEEP_LATCHED_S - 1e-9 for a, b in pairwise(asked))
    auv.tick(13.5)  # the last value (t=12.9) is saved at the next tick past the second
    assert auv.needs_save
    assert auv.state()["latched"]["status"]["updated"] == [pytest.approx(12.9)]
    auv.saved()
    auv.tick(20.0)
    assert not auv.needs_save  # nothing changed since
    put(auv, "nav", {"depth": 3}, 21.0)
    assert not auv.needs_save  # a latest value that does not latch asks for nothing


def test_a_node_on_two_links_resumes_the_value_on_each(tmp_path: Path) -> None:
    from tests.two_links import two_links

    text = two_links(water_a=None, water_rf=None) + """\
  - {name: mode, from: rov1, to: [surface, rov2], latching: true, elements: [{in: mode,
      out: rov1/mode, fields: [{field: m, type: int, min: 0, max: 9}]}]}
"""
    loaded = parse_mission(text, "waters.yaml")
    rov1 = NodeCore(loaded, "rov1")
    put(rov1, "mode", {"m": 4}, 10.0)
    state_file = StateFile(tmp_path, "waters", "rov1")
    state_file.save(rov1.state())
    restarted = NodeCore(loaded, "rov1", state=state_file.load())
    assert len(restarted.outbound.stores) == 2
    for link in ("acoustic", "rf"):
        side = restarted.linkset.side(link)
        due = [c.channel.name for c in restarted.outbound.candidates(20.0, side)]
        assert "mode" in due, link
