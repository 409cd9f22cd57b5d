"""Explicit two-way ranging and seed 001's scheduled anchor replies."""

from __future__ import annotations

import math

import pytest

from bridge.ranging.twr import (
    AnchorReplier,
    RangingRound,
    reply_slot,
    round_timeout,
    tmax,
    travel_time,
)

C = 1480.0


def test_travel_time_formula() -> None:
    # 30 m away, the responder took 0.25 s to answer
    tw = 30.0 / C
    assert travel_time(10.0, 10.0 + 2 * tw + 0.25, 0.25) == pytest.approx(tw)


def test_tmax_and_slots() -> None:
    # seed 001: 150 m, 1400 m/s, 15 B at 266 bit/s
    t = tmax(150.0, 1400.0, 15, 266.0)
    assert t == pytest.approx(150 / 1400 + 120 / 266)
    assert tmax(150.0, 1400.0, 15, 266.0, guard_s=0.5) == pytest.approx(t + 0.5)
    assert [reply_slot(i, 1.0) for i in range(3)] == [0.0, 1.0, 2.0]
    assert round_timeout(3, 1.0) == 4.0
    with pytest.raises(ValueError):
        tmax(150.0, 0.0, 15, 266.0)
    with pytest.raises(ValueError):
        reply_slot(-1, 1.0)


def simulate_round(
    anchors: list[tuple[float, float]], heard: set[tuple[int, int]], duration: float
) -> tuple[RangingRound, list[float]]:
    """A requester at the origin, anchors answering in order; ``heard`` (j, i): i hears j."""
    t_tmax = tmax(150.0, 1400.0, 15, 266.0)
    req = RangingRound(0.0, tuple(f"a{i}" for i in range(len(anchors))), t_tmax, 1.0)
    repliers = [AnchorReplier(i, t_tmax) for i in range(len(anchors))]
    starts: list[float] = []
    for i, (replier, pos) in enumerate(zip(repliers, anchors, strict=True)):
        replier.on_request(math.hypot(*pos) / C)
        for j in range(i):  # earlier replies, heard at their end
            if (j, i) in heard:
                end = starts[j] + duration + math.dist(anchors[j], pos) / C
                replier.on_reply_heard(j, end)
        assert replier.deadline is not None
        assert not replier.due(replier.deadline - 1e-6) and replier.due(replier.deadline)
        t_tx = replier.deadline
        tp = replier.processing_time(t_tx)
        starts.append(t_tx)
        req.on_reply(f"a{i}", t_tx + math.hypot(*pos) / C, tp)
    return req, starts


def test_anchors_answer_in_order_and_ranges_come_out() -> None:
    anchors = [(25.4, 19.3), (-17.4, 20.8), (5.0, -30.0)]
    everyone = {(j, i) for i in range(3) for j in range(i)}
    req, starts = simulate_round(anchors, everyone, duration=0.2)
    assert starts == sorted(starts)
    for i, pos in enumerate(anchors):
        assert req.ranges[f"a{i}"].range_m(C) == pytest.approx(math.hypot(*pos), abs=1e-9)
        assert req.ranges[f"a{i}"].method == "twr"
    assert req.done(starts[-1])
    # anchor 1 replied right after hearing anchor 0, long before its tmax deadline
    assert starts[1] - starts[0] < 0.3 < req.tmax_s


def test_deaf_anchor_waits_for_its_timeout() -> None:
    anchors = [(25.4, 19.3), (-17.4, 20.8), (5.0, -30.0)]
    req, starts = simulate_round(anchors, {(0, 1)}, duration=0.45)  # anchor 2 hears nobody
    request_at_2 = math.hypot(*anchors[2]) / C
    assert starts[2] == pytest.approx(request_at_2 + 2 * req.tmax_s)
    assert len(req.ranges) == 3


def test_round_rejects_strays_and_times_out() -> None:
    req = RangingRound(0.0, ("a0", "a1"), 1.0, max_travel_s=0.2)
    assert req.deadline == 3.0
    assert req.on_reply("zz", 0.5, 0.1) is None  # not an anchor of this round
    assert req.on_reply("a0", 0.3, 0.4) is None  # −0.05 s: impossible
    assert req.on_reply("a0", 3.5, 0.1) is None  # after the round
    assert req.on_reply("a0", 0.2, 0.1) is not None
    assert req.on_reply("a0", 0.2, 0.1) is None  # twice
    assert req.rejected == 4
    assert not req.done(2.9) and req.done(3.0)
    with pytest.raises(ValueError, match="no ranging request"):
        AnchorReplier(0, 1.0).processing_time(1.0)
