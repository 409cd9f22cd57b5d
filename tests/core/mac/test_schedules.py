"""TDMA, none and ALOHA behind the one Schedule interface, with a fake clock."""

from __future__ import annotations

import random

import pytest

from bridge.core.mac import LATE_S, AlohaSchedule, FreeSchedule, TdmaSchedule
from bridge.mission.model import AlohaMac, NoMac, TdmaMac

TDMA = TdmaMac(type="tdma", slot_s=2.0, guard_s=0.5, order=["a", "b", "a", "c"])


def take(schedule: TdmaSchedule | FreeSchedule | AlohaSchedule, now: float,
         due: float | None = 0.0, sent: bool = True) -> float:
    """The next opportunity's start, used (sent or skipped) at that moment."""
    opp = schedule.next_opportunity(now, due)
    assert opp is not None
    t = max(opp.start, now)
    if sent:
        schedule.on_sent(t, t + 0.1)
    else:
        schedule.on_skipped(t)
    return t


def test_tdma_opportunities_walk_the_owned_slots() -> None:
    a = TdmaSchedule(TDMA, "a", always=True)
    starts, now = [], 1000.0
    for sent in (True, False, True, False):
        opp = a.next_opportunity(now, None)
        assert opp is not None and opp.must_send and opp.kind == "slot"
        starts.append(take(a, now, None, sent))
        now = starts[-1]
    # cycle of 8 s from multiples of 8: 1000 starts slot 500, a's own
    assert starts == [1000.0, 1004.0, 1008.0, 1012.0]


def test_tdma_slot_stays_usable_briefly_for_a_late_wakeup() -> None:
    c = TdmaSchedule(TDMA, "c")
    opp = c.next_opportunity(1005.0, None)
    assert opp is not None and (opp.start, opp.must_send) == (1006.0, False)
    late = c.next_opportunity(1006.0 + LATE_S / 2, None)
    assert late == opp  # woke a little late: still this slot
    assert c.next_opportunity(1006.0 + 1.0, None).start == 1014.0  # type: ignore[union-attr]
    assert TdmaSchedule(TDMA, "z").next_opportunity(0.0, 0.0) is None


def test_tdma_legacy_next_slot_unchanged() -> None:
    a = TdmaSchedule(TDMA, "a")
    slot = a.next_slot(1000.0)
    assert slot is not None and (slot.start, slot.end) == (1004.0, 1005.5)
    assert a.worst_gap_s() == 4.0


def test_none_waits_for_data_and_keeps_the_gap() -> None:
    free = FreeSchedule(NoMac(type="none", min_gap_s=2.0))
    assert free.next_opportunity(10.0, None) is None
    assert take(free, 10.0, due=12.0) == 12.0
    opp = free.next_opportunity(12.5, 12.5)
    assert opp is not None and opp.start == 14.0 and not opp.must_send


def aloha(**kw: object) -> AlohaMac:
    return AlohaMac.model_validate({"type": "aloha", **kw})


def test_aloha_backoff_is_drawn_once_per_frame() -> None:
    sched = AlohaSchedule(aloha(backoff_s=3.0), None, random.Random(1))
    first = sched.next_opportunity(100.0, 99.0)
    assert first is not None and 100.0 <= first.start <= 103.0
    # asking again later (a reception woke the node) does not push the start back
    assert sched.next_opportunity(100.7, 99.0) == first
    sched.on_sent(first.start, first.start + 0.2)
    again = sched.next_opportunity(first.start + 0.2, 0.0)  # the next frame: a fresh draw
    assert again is not None
    assert first.start + 0.2 <= again.start <= first.start + 3.2
    assert again.start - (first.start + 0.2) != pytest.approx(first.start - 100.0)


def test_aloha_backoffs_spread_over_the_window() -> None:
    sched = AlohaSchedule(aloha(backoff_s=2.0), None, random.Random(7))
    waits = []
    now = 0.0
    for _ in range(400):
        opp = sched.next_opportunity(now, now)
        assert opp is not None
        waits.append(opp.start - now)
        sched.on_skipped(opp.start)
        now = opp.start
    assert min(waits) >= 0.0 and max(waits) <= 2.0
    assert 0.8 < sum(waits) / len(waits) < 1.2  # uniform on [0, 2]: mean 1


def test_slotted_aloha_starts_on_slot_boundaries_with_whole_slot_backoff() -> None:
    sched = AlohaSchedule(aloha(slotted=True, backoff_s=3.0), 0.5, random.Random(3))
    now = 10.1
    for _ in range(50):
        opp = sched.next_opportunity(now, now)
        assert opp is not None
        k = opp.start / 0.5
        assert k == pytest.approx(round(k)) and opp.start >= now
        assert opp.start - now <= 3.0 + 0.5
        sched.on_sent(opp.start, opp.start + 0.2)
        now = opp.start + 0.2
    with pytest.raises(ValueError, match="slot_s"):
        AlohaSchedule(aloha(slotted=True), None, random.Random())


def test_aloha_airtime_cap() -> None:
    sched = AlohaSchedule(aloha(max_airtime_share=0.25), None, random.Random(0))
    assert take(sched, 0.0) == 0.0  # the frame keeps the modem busy 0.1 s
    opp = sched.next_opportunity(0.1, 0.0)
    assert opp is not None and opp.start == pytest.approx(0.4)  # 0.1 s / 0.25
    assert sched.next_opportunity(0.0, None) is None
