"""The bounded hand-off from Zenoh's threads to the loop, and the rate of what goes out on
``…/events`` (bridge.runtime.intake, bridge.runtime.gate)."""

from __future__ import annotations

import asyncio
import threading
from itertools import pairwise

import zenoh

from bridge.core.events import FrameDropped, Link
from bridge.runtime.gate import EVERY_S, EventGate
from bridge.runtime.intake import HANDOFF, Intake


def test_the_hand_off_keeps_the_newest_calls_per_key_and_counts_the_rest() -> None:
    loop = asyncio.new_event_loop()
    try:
        intake = Intake(None, loop, "a")  # type: ignore[arg-type]  (to_loop needs no session)
        ran: list[tuple[str, int]] = []
        for n in range(100):
            intake.to_loop("flooded", lambda n=n: ran.append(("flooded", n)))
        intake.to_loop("quiet", lambda: ran.append(("quiet", 0)))
        intake.to_loop("broken", lambda: 1 / 0)
        loop.run_until_complete(asyncio.sleep(0))  # the one wake-up runs every batch
    finally:
        loop.close()
    assert [n for key, n in ran if key == "flooded"] == list(range(100 - HANDOFF, 100))
    assert ("quiet", 0) in ran  # a flood on one key never pushes out another's
    assert intake.overflow == {"flooded": 100 - HANDOFF}
    assert intake.errors == {"broken": 1}


def test_frame_drops_go_out_once_per_reason_a_second_saying_how_many_were_held() -> None:
    gate = EventGate()
    out = []
    for i in range(2500):  # 1000 junk frames a second for 2.5 s, two reasons
        now = i / 1000
        event = FrameDropped(now, "b", "check" if i % 2 else "malformed")
        if (held := gate.admit(event, now)) is not None:
            out.append((now, event.reason, held))
        assert gate.admit(Link(now, "b", "up", now, 0.0), now) == 0  # rare events: always
    for reason in ("check", "malformed"):
        times = [t for t, r, _ in out if r == reason]
        assert len(times) == 3 and all(b - a >= EVERY_S for a, b in pairwise(times))
    assert gate.held_back == 2500 - 6  # each held back is said by the next that goes out
    assert sum(held for _, _, held in out) + sum(gate._held.values()) == gate.held_back


def _quiet_session() -> zenoh.Session:
    config = zenoh.Config()
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("listen/endpoints", "[]")
    return zenoh.open(config)


def test_a_reliable_keys_lane_waits_for_room_and_close_lets_a_waiting_thread_go() -> None:
    loop = asyncio.new_event_loop()
    session = _quiet_session()
    try:
        intake = Intake(session, loop, "a")
        intake.subscribe("cmd", lambda sample: None, fifo=True)
        ran: list[int] = []
        sent = threading.Event()

        def burst() -> None:  # the subscription's thread, faster than the loop
            for n in range(5 * HANDOFF):
                intake.to_loop("cmd", lambda n=n: ran.append(n))
            sent.set()

        thread = threading.Thread(target=burst)
        thread.start()
        while not sent.is_set():
            loop.run_until_complete(asyncio.sleep(0.01))
        loop.run_until_complete(asyncio.sleep(0))
        thread.join(5)
        assert ran == list(range(5 * HANDOFF))  # none dropped, in order
        assert intake.overflow == {}

        for _ in range(HANDOFF):  # a full lane the loop no longer runs
            intake.to_loop("cmd", lambda: None)
        stuck = threading.Thread(target=intake.to_loop, args=("cmd", lambda: None))
        stuck.start()
        stuck.join(0.3)
        assert stuck.is_alive()  # waiting for room
        intake.close()
        stuck.join(5)
        assert not stuck.is_alive()
    finally:
        session.close()
        loop.close()
        intake.join()
