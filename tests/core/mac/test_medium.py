"""MACs taking turns in the pure simulated ocean on a fake clock: who sends when, what collides."""

from __future__ import annotations

import itertools
import random

import pytest

from bridge.core.mac import AlohaSchedule, FreeSchedule, PolledSchedule, RangingSchedule
from bridge.mission.model import AlohaMac, NoMac, RangingSlots
from bridge.mission.presets import get_preset
from tests.core.mac.medium import Medium

ACOUSTIC = get_preset("evologics-s2c-im")


def test_polled_fleet_never_collides_and_slaves_answer_their_polls() -> None:
    nodes = {"top": (1, (0.0, 0.0, 0.0)), "a": (2, (600.0, 0.0, 20.0)),
             "b": (3, (0.0, 900.0, 30.0))}
    frame = ACOUSTIC.airtime(40) + ACOUSTIC.propagation_s(1000.0)
    ipg = 2 * frame + 0.1
    seq = ("a", "b", "a")
    medium = Medium(ACOUSTIC, nodes,
                    {n: PolledSchedule(n, "top", seq, ipg) for n in nodes},
                    dict.fromkeys(nodes, 40), has_data={"a": True, "b": True})
    medium.run(120.0)
    polls = [s for s in medium.sent if s.node == "top"]
    assert len(polls) == pytest.approx(120.0 / ipg, abs=1)
    assert [p.poll for p in polls[:6]] == ["a", "b", "a", "a", "b", "a"]
    assert all(b.start - a.start == pytest.approx(ipg) for a, b in itertools.pairwise(polls))
    replies = [s for s in medium.sent if s.node != "top"]
    assert {s.kind for s in replies} == {"reply"}
    assert medium.collisions() == 0 and medium.refused == 0
    for reply in replies:  # each reply starts when that slave's poll ends, never unpolled
        poll = max((p for p in polls if p.start < reply.start), key=lambda p: p.start)
        assert poll.poll == reply.node
        distance = 600.0 if reply.node == "a" else 900.0
        assert reply.start == pytest.approx(poll.end + ACOUSTIC.propagation_s(distance), abs=0.01)
    a_replies = sum(1 for s in replies if s.node == "a")
    assert a_replies == pytest.approx(2 * len(replies) / 3, abs=1)


def test_ranging_rounds_answer_in_order_while_a_bystander_waits() -> None:
    preset = get_preset("hippocampus-266")
    slots = RangingSlots(requester="hippo", anchors=["a1", "a2", "a3"], interval_s=3.0)
    tmax_s = 40.0 / 1400 + preset.airtime(15)
    nodes = {"a1": (1, (0.0, 0.0, 0.3)), "a2": (2, (0.0, 30.0, 0.3)),
             "a3": (3, (25.0, 15.0, 0.3)), "hippo": (4, (12.0, 8.0, 1.0)),
             "logger": (5, (5.0, 5.0, 2.0))}
    schedules = {n: RangingSchedule(FreeSchedule(NoMac(type="none")), n, slots, tmax_s)
                 for n in nodes}
    bystander_mac = AlohaMac(type="aloha", backoff_s=1.0, max_airtime_share=0.3)
    schedules["logger"] = RangingSchedule(AlohaSchedule(bystander_mac, None, random.Random(2)),
                                          "logger", slots, tmax_s)
    medium = Medium(preset, nodes, schedules, {**dict.fromkeys(nodes, 12), "hippo": 15},
                    has_data={"logger": True})
    medium.run(60.0)
    requests = [s for s in medium.sent if s.node == "hippo"]
    assert [round(r.start, 6) for r in requests] == [3.0 * k for k in range(21)]  # 0 .. 60 s
    # the bystander may hit a round before it has heard one; never after
    first_heard = min(t for src, dst, t in medium.heard if (src, dst) == ("hippo", "logger"))
    assert not [lost for lost in medium.lost if lost[3] > first_heard + 3.0]
    for request in requests[:-1]:
        replies = [s for s in medium.sent if s.start > request.start
                   and s.start < request.start + 3.0 and s.node.startswith("a")]
        assert [r.node for r in replies] == ["a1", "a2", "a3"]
        assert {r.kind for r in replies} == {"ranging_reply"}
    logger = [s for s in medium.sent if s.node == "logger"]
    assert len(logger) >= 19  # the bystander still gets a frame through between two rounds


@pytest.mark.parametrize("slotted", [False, True])
def test_aloha_respects_its_airtime_cap_and_collides_sometimes(slotted: bool) -> None:
    preset = get_preset("s100-rf").replace(jitter_s=0.0)
    mac = AlohaMac(type="aloha", slotted=slotted, backoff_s=0.5, max_airtime_share=0.1)
    slot = preset.intrinsic_delay_s + preset.airtime(32) + 0.01
    nodes = {f"n{i}": (i + 1, (float(i), 0.0, 1.0)) for i in range(6)}
    schedules = {n: AlohaSchedule(mac, slot if slotted else None, random.Random(n))
                 for n in nodes}
    medium = Medium(preset, nodes, schedules, dict.fromkeys(nodes, 32),
                    has_data=dict.fromkeys(nodes, True))
    duration = 300.0
    medium.run(duration)
    for name in nodes:
        frames = [s for s in medium.sent if s.node == name]
        busy = sum(s.end - s.start for s in frames)
        assert busy / duration <= 0.1 + 1e-6
        assert busy / duration > 0.05  # the backoff costs some of the share, not most
    assert medium.refused == 0
    assert 0 < medium.collisions() < len(medium.sent) * len(nodes)
    if slotted:
        assert all(s.start / slot == pytest.approx(round(s.start / slot)) for s in medium.sent)
