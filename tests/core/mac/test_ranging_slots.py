"""Seed 001's ranging rounds reserved inside a random-access MAC, with a fake clock."""

from __future__ import annotations

import pytest

from bridge.core.mac import FreeSchedule, RangingSchedule
from bridge.mission.model import NoMac, RangingSlots

SLOTS = RangingSlots(requester="hippo", anchors=["a1", "a2", "a3"], interval_s=3.0)
TMAX = 0.6


def ranging(node: str) -> RangingSchedule:
    return RangingSchedule(FreeSchedule(NoMac(type="none")), node, SLOTS, TMAX)


def test_requester_sends_a_request_every_interval_and_data_rides_on_it() -> None:
    hippo = ranging("hippo")
    first = hippo.next_opportunity(0.0, None)
    assert first is not None and (first.start, first.kind) == (0.0, "ranging_request")
    assert first.must_send
    hippo.on_sent(0.0, 0.45)
    # data due at 0.5 waits for the round ((n + 1)·tmax after the request) and then rides on
    # the next request, due at 3.0, less than one turn after the round ends at 2.85
    nxt = hippo.next_opportunity(0.5, 0.5)
    assert nxt is not None and nxt.kind == "ranging_request" and nxt.start == pytest.approx(3.0)
    assert hippo.rounds == 1


def test_round_ends_when_the_last_anchor_answers() -> None:
    hippo = ranging("hippo")
    hippo.next_opportunity(0.0, None)
    hippo.on_sent(0.0, 0.45)
    for anchor, end in (("a1", 1.0), ("a2", 1.5), ("a3", 2.0)):
        hippo.on_heard(anchor, False, end)
    # urgent data may go once every answer is in: that frame is itself a request
    opp = hippo.next_opportunity(2.0, 1.0)
    assert opp is not None and opp.start == 2.0 and opp.kind == "due"


def test_anchors_answer_in_order_each_after_the_previous_or_a_timeout() -> None:
    a1, a2, a3 = ranging("a1"), ranging("a2"), ranging("a3")
    for anchor in (a1, a2, a3):
        anchor.on_heard("hippo", False, 1.0)
    opp = a1.next_opportunity(1.0, None)
    assert opp is not None and (opp.start, opp.kind, opp.must_send) == (1.0, "ranging_reply",
                                                                        True)
    assert a2.next_opportunity(1.0, None).start == pytest.approx(1.6)  # type: ignore[union-attr]
    a1.on_sent(1.0, 1.45)
    for anchor in (a2, a3):  # a1's answer heard: a2 answers at once, a3 in one turn at most
        anchor.on_heard("a1", False, 1.45)
    assert a2.next_opportunity(1.45, None).start == pytest.approx(1.45)  # type: ignore[union-attr]
    assert a3.next_opportunity(1.45, None).start == pytest.approx(2.05)  # type: ignore[union-attr]
    a2.on_sent(1.45, 1.9)
    assert a2.next_opportunity(1.9, None) is None  # one answer per round
    a3.on_heard("a2", False, 1.9)
    assert a3.next_opportunity(1.9, None).start == pytest.approx(1.9)  # type: ignore[union-attr]


def test_an_anchor_that_missed_its_turn_stays_silent() -> None:
    a2 = ranging("a2")
    a2.on_heard("hippo", False, 1.0)
    assert a2.next_opportunity(2.3, None) is None  # its turn was 1.6 .. 2.2


def test_bystanders_and_anchor_data_wait_for_the_round() -> None:
    other, a1 = ranging("other"), ranging("a1")
    for node in (other, a1):
        node.on_heard("hippo", False, 1.0)
    opp = other.next_opportunity(1.2, 1.2)
    assert opp is not None and opp.start == pytest.approx(1.0 + 3 * TMAX)
    reply = a1.next_opportunity(1.0, 0.0)
    assert reply is not None and reply.kind == "ranging_reply"  # its answer before its data
    a1.on_sent(1.0, 1.45)
    data = a1.next_opportunity(1.45, 0.0)
    assert data is not None and data.start == pytest.approx(2.8)
    for node in (other, a1):
        node.on_heard("a3", False, 2.1)
    assert other.next_opportunity(2.1, 1.2).start == 2.1  # type: ignore[union-attr]


def test_listeners_keep_the_next_round_free() -> None:
    other = ranging("other")
    other.on_heard("hippo", False, 1.0)  # the request started between 0.4 and 1.0
    other.on_heard("a3", False, 2.1)
    assert other.next_opportunity(2.1, 2.1).start == 2.1  # type: ignore[union-attr]
    # a frame (at most one turn long) starting after 2.8 could meet the next request, due
    # from 3.4; so it waits until that round is surely over: 4.0 + (n + 1)·tmax
    late = other.next_opportunity(3.0, 3.0)
    assert late is not None and late.start == pytest.approx(4.0 + 4 * TMAX)


def test_a_refused_request_waits_one_interval() -> None:
    hippo = ranging("hippo")
    assert hippo.next_opportunity(0.0, None).kind == "ranging_request"  # type: ignore[union-attr]
    hippo.on_skipped(0.0)  # the modem refused it (busy, or the frame too long)
    again = hippo.next_opportunity(0.0, None)
    assert again is not None and again.start == 3.0
