"""Restarts: reliable channels neither wedge nor repeat, whichever end is killed, and when.

The chaos runs are ``bench/chaos.py``'s virtual-clock one (deterministic by seed); its run with
the real processes killed with SIGKILL is in ``tests/runtime/test_reliable_processes.py``.
"""

from __future__ import annotations

import random
from pathlib import Path

import pytest

from bridge.core.events import Link, MissionMismatch, PeerRestarted
from bridge.core.loaded import parse_mission
from bridge.core.node import NodeCore, Status
from bridge.modems.base import Reception
from bridge.runtime.state_file import StateFile
from bridge.runtime.virtual_fleet import FastFleet
from tests.harness import bench_module

chaos = bench_module("chaos")

LOADED = parse_mission(chaos.mission_text(0.0), "chaos.yaml")


@pytest.mark.parametrize("loss", [0.3, 0.4])
def test_virtual_chaos_delivers_each_command_once_with_one_report(loss: float) -> None:
    result = chaos.run_virtual(2000, 20, loss, seed=5)
    assert result["sent"] > 1900
    assert chaos.goal_met(result), result
    assert result["reported_failed"] == {}  # no TTL set: nothing may fail at these losses
    assert result["delivered_once"] == result["reported_delivered"] == result["sent"]


def test_virtual_chaos_is_deterministic_by_seed() -> None:
    assert chaos.run_virtual(300, 5, 0.3, seed=9) == chaos.run_virtual(300, 5, 0.3, seed=9)


def test_a_receiver_restarting_without_its_state_never_wedges_the_channel() -> None:
    """The wedge of the issue: the sender believed the fresh receiver still held what it had
    acknowledged selectively. With epochs, every value still ends in a terminal report."""
    result = chaos.run_virtual(1500, 15, 0.4, seed=3, forgetful="auv")
    assert result["no_terminal_report"] == 0 and result["false_delivered"] == 0
    assert result["reported_delivered"] == result["sent"]
    assert result["terminal_twice"] == 0


# -- the core's epochs, state and mismatch detection -------------------------------------------


def frames_between(a: NodeCore, b: NodeCore, now: float) -> None:
    """``a`` sends one frame (if any) and ``b`` hears it."""
    out = a.outbound.build(now, now, always=True)
    assert out is not None
    a.outbound.sent(out, now)
    b.receive(Reception(out.data, LOADED.mission.address_of(a.node), now, {}), now)


def test_a_fresh_receiver_is_resent_what_it_acknowledged_selectively() -> None:
    ops, auv = NodeCore(LOADED, "ops"), NodeCore(LOADED, "auv", rng=random.Random(1))
    for n in range(3):
        ops.ingest("cmd", b'{"n": %d}' % n, "application/json", 0.0)
    first = ops.outbound.build(0.0, 0.0)
    assert first is not None
    ops.outbound.sent(first, 0.0)  # n=0..2 in flight; the frame is lost
    frames_between(auv, ops, 1.0)  # ops learns auv's epoch
    auv.take()
    fresh = NodeCore(LOADED, "auv", rng=random.Random(2))  # restarted without its state
    assert fresh.epoch != auv.epoch
    frames_between(fresh, ops, 2.0)
    assert any(isinstance(o, PeerRestarted) for o in ops.take())
    frames_between(ops, fresh, 3.0)  # everything outstanding goes again, at once
    published = [o.value["n"] for o in fresh.take() if getattr(o, "key", None) == "ops/cmd"]
    assert published == [0, 1, 2]


def test_a_receiver_restarted_from_its_state_file_publishes_nothing_twice(
        tmp_path: Path) -> None:
    ops, auv = NodeCore(LOADED, "ops"), NodeCore(LOADED, "auv")
    state = StateFile(tmp_path, "chaos", "auv")
    ops.ingest("cmd", b'{"n": 7}', "application/json", 0.0)
    out = ops.outbound.build(0.0, 0.0)
    assert out is not None
    ops.outbound.sent(out, 0.0)
    auv.receive(Reception(out.data, 1, 0.0, {}), 0.0)
    assert auv.needs_save
    state.save(auv.state())  # what the runtime does before publishing
    assert [o.value for o in auv.take() if getattr(o, "key", None) == "ops/cmd"] == [{"n": 7}]
    again = NodeCore(LOADED, "auv", state=state.load())  # kill -9, restart
    assert again.epoch == auv.epoch
    again.receive(Reception(out.data, 1, 5.0, {}), 5.0)  # the sender had no ack: it resends
    assert not [o for o in again.take() if getattr(o, "key", None) == "ops/cmd"]
    ack = again.outbound.build(6.0, 6.0)
    assert ack is not None and ack.acks
    ops.receive(Reception(ack.data, 2, 6.0, {}), 6.0)
    states = [o.payload["state"] for o in ops.take()
              if isinstance(o, Status) and o.topic == "delivery/command"]
    assert states == ["queued", "sent", "delivered"]


def test_a_sender_restarted_from_its_state_resumes_its_values(tmp_path: Path) -> None:
    ops = NodeCore(LOADED, "ops")
    ops.ingest("cmd", b'{"n": 1}', "application/json", 0.0, ref="one")
    state = StateFile(tmp_path, "chaos", "ops")
    state.save(ops.state())
    again = NodeCore(LOADED, "ops", state=state.load())
    out = again.outbound.build(1.0, 1.0)
    assert out is not None and out.streams
    auv = NodeCore(LOADED, "auv")
    auv.receive(Reception(out.data, 1, 1.0, {}), 1.0)
    assert [o.value for o in auv.take() if getattr(o, "key", None) == "ops/cmd"] == [{"n": 1}]


def test_a_state_file_of_another_mission_reports_its_values_failed(tmp_path: Path) -> None:
    ops = NodeCore(LOADED, "ops")
    ops.ingest("cmd", b'{"n": 1}', "application/json", 0.0, ref="one")
    state = ops.state()
    state["fingerprint"] = "00" * 8
    again = NodeCore(LOADED, "ops", state=state)
    assert again.needs_save  # (its state is gone: saved before the reports go out)
    again.tick(1_795_000_000.0)  # (the node's first tick: its clock's time)
    (failed,) = [o.payload for o in again.take()
                 if isinstance(o, Status) and o.topic == "delivery/command"]
    assert failed["state"] == "failed" and failed["ref"] == "one"
    assert "another mission file" in failed["reason"]
    assert failed["time"] == 1_795_000_000.0  # (found from outside: 0.0, 1970)
    again.tick(1_795_000_001.0)
    assert not [o for o in again.take() if isinstance(o, Status)]  # (once)


def test_a_corrupt_state_file_is_moved_aside(tmp_path: Path) -> None:
    state = StateFile(tmp_path, "chaos", "ops")
    state.path.write_bytes(b"\xc1 not msgpack")
    assert state.load() is None
    assert (tmp_path / "chaos.ops.state.corrupt").exists() and not state.path.exists()


def test_a_peer_with_another_mission_file_is_reported_once() -> None:
    other = parse_mission(chaos.mission_text(0.0).replace("max: 65535", "max: 1023"), "o.yaml")
    foreign, ours = NodeCore(other, "ops"), NodeCore(LOADED, "auv")
    for t in (1.0, 2.0, 3.0):
        out = foreign.outbound.build(t, t, always=True)
        assert out is not None
        ours.receive(Reception(out.data, 1, t, {}), t)
    dropped = ours.stats.frames_dropped
    assert dropped["check"] == 1 and dropped["mission_mismatch"] == 2
    events = [o for o in ours.take() if isinstance(o, MissionMismatch)]
    assert len(events) == 1 and events[0].peer == "ops"
    assert ours.snapshot(3.0)["mismatched_peers"] == {"ops": events[0].fingerprint}


def test_links_do_not_go_down_while_frames_keep_arriving_at_30_percent_loss() -> None:
    downs: list[float] = []

    def watch(timed) -> None:
        out = timed.output
        if isinstance(out, Link) and out.state == "down" \
                and timed.time > 30.0:
            downs.append(timed.time)

    fleet = FastFleet(parse_mission(chaos.mission_text(0.3)), seed=4, keep_outputs=False,
                      on_output=watch)
    fleet.run_until(3600.0)  # nobody publishes: only heartbeats keep the links alive
    assert fleet.cores["ops"].stats.frames_received > 500
    assert downs == []


def test_check_prints_each_streams_retries_ttl_and_bound() -> None:
    from bridge.core.reliable import stream_ttl_s
    from bridge.report.check import check_mission

    (limits,) = check_mission(LOADED).data["streams"]
    cycle = 4.0  # two 2 s TDMA slots
    assert limits["retry_s"] == cycle and limits["retries"] == 10 and limits["ttl_default"]
    assert limits["ttl_s"] == pytest.approx(stream_ttl_s(cycle, 10, 256))
    assert limits["report_within_s"] == pytest.approx(limits["ttl_s"] + 1.0)
    text = chaos.mission_text(0.0).replace("queue: 256", "queue: 256\n    ttl_s: 90")
    given = parse_mission(text, "ttl.yaml")
    (limits,) = check_mission(given).data["streams"]
    assert limits["ttl_s"] == 90 and not limits["ttl_default"]
