"""Seed 001's ranging rounds, reserved inside ``none`` or ``aloha`` (``mac.ranging``): the
schedule that keeps them free, and how long one anchor's turn lasts (pure)."""

from __future__ import annotations

import math

from bridge.core.mac.base import Opportunity, OpportunityKind, Schedule
from bridge.core.mac.timing import max_distance_m, node_preset
from bridge.mission.model import Mission, RangingSlots
from bridge.ranging.twr import AnchorReplier, round_timeout, tmax

__all__ = ["SLOW_SOUND", "RangingSchedule", "ranging_tmax_s"]

SLOW_SOUND = 1400.0 / 1500.0
"""A ranging turn assumes sound this much slower than the preset's (seed 001 takes 1400 m/s,
the slowest speed it expects, against the nominal 1500 m/s)."""


class RangingSchedule(Schedule):
    """Seed 001's ranging rounds reserved inside another schedule (``none`` or ``aloha``).

    Every frame of the requester opens a round (it sends one at least every ``interval_s``);
    anchor ``i`` answers at once (``i == 0``) or right after hearing anchor ``i - 1``, and at
    the latest ``tmax`` after the previous anchor's turn (:class:`AnchorReplier`); until the
    round ends (all answers heard, or ``(n + 1)·tmax``) every other frame waits. Having heard a
    request, a node also keeps the next one's round free: no frame of its own starts from
    ``2·tmax`` before the next request is due until that round's longest end. An anchor's
    answer has an ``until`` (no transmission begins after its turn, ``tmax`` past when it is
    due: the next anchor's follows); requests and the inner MAC's frames have none.
    """

    def __init__(self, inner: Schedule, node: str, slots: RangingSlots, tmax_s: float) -> None:
        self.inner = inner
        self.node = node
        self.requester = slots.requester
        self.anchors = tuple(slots.anchors)
        self.interval_s = slots.interval_s
        self.tmax_s = tmax_s
        self.replier = (AnchorReplier(self.anchors.index(node), tmax_s)
                        if node in self.anchors else None)
        self._last_request: float | None = None
        self._quiet_until = -math.inf
        self._reserved = (math.inf, -math.inf)  # the next round, as expected by a listener
        self._answers = 0
        self._offered: OpportunityKind | None = None  # kind of the last opportunity offered
        self.rounds = 0

    def _round_over(self, end: float) -> None:
        self._quiet_until = min(self._quiet_until, end)

    def next_opportunity(self, now: float, due: float | None) -> Opportunity | None:
        opp = self._next(now, due)
        self._offered = None if opp is None else opp.kind
        return opp

    def _next(self, now: float, due: float | None) -> Opportunity | None:
        if self.replier is not None and self.replier.deadline is not None and not \
                self.replier.sent:
            deadline = self.replier.deadline
            if deadline + self.tmax_s >= now:
                turn_end = deadline + self.tmax_s  # then the next anchor's turn begins
                return Opportunity(deadline, turn_end, True, None,
                                   OpportunityKind.RANGING_REPLY, turn_end)
            self.replier.sent = True  # missed our turn: the round has moved on
        inner = self.inner.next_opportunity(now, due)
        if inner is not None:
            start = max(inner.start, self._quiet_until)
            if self._reserved[0] < max(start, now) < self._reserved[1]:
                start = self._reserved[1]
            if start != inner.start:
                inner = Opportunity(start, max(inner.latest, start), inner.must_send,
                                    inner.poll, inner.kind, inner.until)
        if self.node != self.requester:
            return inner
        request = (now if self._last_request is None
                   else max(self._last_request + self.interval_s, self._quiet_until))
        if inner is None or request <= inner.start + self.tmax_s:
            return Opportunity(request, math.inf, True, None, OpportunityKind.RANGING_REQUEST)
        return inner

    def on_sent(self, start: float, end: float) -> None:
        self.inner.on_sent(start, end)
        if self.replier is not None and self.replier.deadline is not None and \
                not self.replier.sent:
            self.replier.processing_time(start)
        if self.node == self.requester:
            self._last_request = start
            self._answers = 0
            self._quiet_until = end + round_timeout(len(self.anchors), self.tmax_s)
            self.rounds += 1

    def on_skipped(self, now: float) -> None:
        self.inner.on_skipped(now)
        if self._offered is OpportunityKind.RANGING_REPLY and self.replier is not None:
            self.replier.sent = True  # this round's turn is gone
        if self._offered is OpportunityKind.RANGING_REQUEST:  # refused (modem busy?): retry
            self._last_request = now

    def on_heard(self, src: str, polled_me: bool, end: float) -> None:
        self.inner.on_heard(src, polled_me, end)
        n = len(self.anchors)
        if src == self.requester:
            self._answers = 0
            if self.replier is not None:
                self.replier.on_request(end)
            # the last anchor's turn starts at most n - 1 turns after the request
            self._quiet_until = end + n * self.tmax_s
            expected = end + self.interval_s
            self._reserved = (expected - 2 * self.tmax_s, expected + (n + 1) * self.tmax_s)
        elif src in self.anchors:
            self._answers += 1
            if self.replier is not None:
                self.replier.on_reply_heard(self.anchors.index(src), end)
            if self.anchors.index(src) == n - 1 or self._answers >= n:
                self._round_over(end)


def ranging_tmax_s(mission: Mission, slots: RangingSlots) -> float | None:
    """One anchor's turn: given, or seed 001 eq. 6 (``dmax/c + l/R``, ``c`` the slowest expected
    sound speed) plus the modem's latency (intrinsic delay + 3 sigma jitter and fixed frame
    overhead) for the largest anchor frame."""
    if slots.tmax_s is not None:
        return slots.tmax_s
    turns = []
    for anchor in slots.anchors:
        preset = node_preset(mission, anchor)
        if preset is None:
            return None
        size = min(mission.node_modem(anchor).frame_bytes, preset.frame_bytes)
        latency = preset.intrinsic_delay_s + 3 * preset.jitter_s + preset.overhead_s
        slowest = preset.sound_speed_mps * SLOW_SOUND
        turns.append(tmax(max_distance_m(mission, preset), slowest, size,
                          8 / preset.byte_time_s, guard_s=latency))
    return max(turns)
