"""A frame carries the end of the MAC turn it was granted (``SendFrame.until``, on the core's
clock), which the runtime hands to the modem: under TDMA the slot's end (less its guard), so a
modem whose send stalls never retries into the next node's slot (found from outside with a
Micro-Modem: one try's timeout, 19.4 s, outlasts a 14 s slot). Fake clock, pure."""

from __future__ import annotations

import math

import msgpack

from bridge.core.loaded import parse_mission
from bridge.core.mac import OpportunityKind, PolledSchedule
from bridge.core.node import NodeCore, SendFrame

MISSION = """\
mission: slots
wire: {auth: off}
modem: {backend: sim, frame_bytes: 32, options: {preset: micromodem-rate0}}
mac: MAC
nodes:
  a: {address: 1, position: {x: 0, y: 0, depth: 5}}
  b: {address: 2, position: {x: 500, y: 0, depth: 5}}
channels:
  - name: depth
    from: a
    to: b
    elements:
      - {in: a/d, out: a/d, fields: [{field: d, type: int, min: 0, max: 255}]}
"""

TDMA = "{type: tdma, slot_s: 14, guard_s: 1.0, order: [a, b]}"


def core_under(mac: str) -> NodeCore:
    return NodeCore(parse_mission(MISSION.replace("MAC", mac), "slots.yaml"), "a")


def send_at_next_turn(core: NodeCore, now: float, value: int) -> tuple[SendFrame, float]:
    core.ingest("a/d", msgpack.packb({"d": value}), "application/msgpack", now)
    wake = core.wake_at(now)
    assert wake is not None
    action = core.act(wake, wake)
    assert isinstance(action, SendFrame)
    return action, wake


def test_tdma_frames_carry_their_slots_end() -> None:
    core = core_under(TDMA)
    # the cycle is 28 s from the epoch: a owns [28k, 28k + 14), silent from 28k + 13
    action, start = send_at_next_turn(core, 1000.0, 1)
    assert start == 1008.0  # slot 72 (even: a's)
    assert action.until == 1008.0 + 14 - 1.0
    core.done(action, start, start + 3.0)
    action, start = send_at_next_turn(core, start + 3.0, 2)  # the next of a's slots
    assert (start, action.until) == (1036.0, 1036.0 + 13.0)
    core.done(action, start, start + 3.0)
    # a loop that woke a little late still acts in the slot: the same end
    core.ingest("a/d", msgpack.packb({"d": 3}), "application/msgpack", start + 5.0)
    wake = core.wake_at(start + 5.0)
    assert wake == 1064.0
    late = core.act(wake + 0.04, wake)
    assert isinstance(late, SendFrame) and late.until == 1064.0 + 13.0


def test_without_slots_a_frame_has_no_end() -> None:
    action, _ = send_at_next_turn(core_under("{type: none}"), 1000.0, 1)
    assert math.isinf(action.until)


def test_polled_turns_end_at_the_next_poll_or_the_reply_window() -> None:
    master = PolledSchedule("m", "m", ("s",), ipg_s=8.0)
    poll = master.next_opportunity(100.0, None)
    assert poll is not None and poll.kind is OpportunityKind.POLL
    assert poll.until == 108.0  # the next poll
    slave = PolledSchedule("s", "m", ("s",), ipg_s=8.0)
    slave.on_heard("m", True, 101.5)  # the poll ended at 101.5
    reply = slave.next_opportunity(101.5, None)
    assert reply is not None and reply.kind is OpportunityKind.REPLY
    assert reply.until == 101.5 + 8.0 / 4  # its reply window
