"""The polled MAC (seed 002's token passing, seed 003's polled uplinks) with a fake clock."""

from __future__ import annotations

import pytest

from bridge.core.mac import PolledSchedule, poll_sequence


def test_poll_sequence_from_order_weights_or_default() -> None:
    assert poll_sequence(["b", "a", "b"], None, ["a", "b"]) == ("b", "a", "b")
    assert poll_sequence(None, None, ["a", "b", "c"]) == ("a", "b", "c")
    assert poll_sequence(None, {"a": 2, "b": 1}, ["a", "b"]) == ("a", "b", "a")
    # interleaved, not bunched: the heavy slave never waits more than two polls
    cycle = poll_sequence(None, {"rov": 3, "auv": 1, "glider": 1}, [])
    assert cycle == ("rov", "auv", "rov", "glider", "rov")


def test_master_polls_every_ipg_in_turn_even_without_data() -> None:
    master = PolledSchedule("op", "op", ("rov1", "rov2"), 0.64)
    polls, now = [], 100.0
    for _ in range(5):
        opp = master.next_opportunity(now, None)
        assert opp is not None and opp.must_send and opp.kind == "poll"
        now = max(now, opp.start)
        polls.append((round(now, 6), opp.poll))
        master.on_sent(now, now + 0.15)
    assert polls == [(100.0, "rov1"), (100.64, "rov2"), (101.28, "rov1"), (101.92, "rov2"),
                     (102.56, "rov1")]


def test_master_stays_on_its_grid_when_late() -> None:
    master = PolledSchedule("op", "op", ("rov",), 1.0)
    first = master.next_opportunity(0.0, None)
    assert first is not None
    master.on_sent(0.0, 0.2)
    late = master.next_opportunity(3.4, None)  # the adapter was held up for 2.4 s
    assert late is not None and late.start == pytest.approx(3.0)
    master.on_sent(3.4, 3.6)
    assert master.next_opportunity(3.6, None).start == pytest.approx(4.0)  # type: ignore[union-attr]


def test_slave_replies_once_right_after_its_poll() -> None:
    rov = PolledSchedule("rov1", "op", ("rov1", "rov2"), 0.64)
    assert rov.next_opportunity(0.0, 0.0) is None  # data alone never opens the channel
    rov.on_heard("op", False, 0.15)  # a poll for someone else
    assert rov.next_opportunity(0.15, 0.0) is None
    rov.on_heard("rov2", True, 0.2)  # only the master polls
    assert rov.next_opportunity(0.2, 0.0) is None
    rov.on_heard("op", True, 0.79)
    opp = rov.next_opportunity(0.79, None)
    assert opp is not None and opp.start == 0.79 and opp.must_send and opp.kind == "reply"
    assert opp.latest == pytest.approx(0.79 + 0.16)
    rov.on_sent(0.79, 1.1)
    assert rov.next_opportunity(1.1, 0.0) is None


def test_a_reply_too_late_is_dropped_and_counted() -> None:
    rov = PolledSchedule("rov", "op", ("rov",), 0.64)
    rov.on_heard("op", True, 1.0)
    assert rov.next_opportunity(1.5, None) is None
    assert rov.missed_replies == 1


def test_worst_gap_and_rate_per_role() -> None:
    seq = ("a", "b", "a", "c")
    assert PolledSchedule("m", "m", seq, 0.5).worst_gap_s() == 0.5
    assert PolledSchedule("a", "m", seq, 0.5).worst_gap_s() == 1.0
    assert PolledSchedule("c", "m", seq, 0.5).worst_gap_s() == 2.0
    assert PolledSchedule("z", "m", seq, 0.5).worst_gap_s() is None
    assert PolledSchedule("a", "m", seq, 0.5).turns_per_s() == pytest.approx(1.0)
    with pytest.raises(ValueError):
        PolledSchedule("a", "m", seq, 0.0)
