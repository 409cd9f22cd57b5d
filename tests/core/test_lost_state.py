"""A sender that lost its state is heard again within one MAC cycle, and replays stay refused
(authenticated missions, ``@mark``: docs/wire-format.md). On the virtual clock: two cores over
the simulated water, TDMA."""

from __future__ import annotations

import random
from pathlib import Path

from bridge.core.events import FrameDropped, FrameReceived, FrameSent
from bridge.core.loaded import parse_mission
from bridge.core.node import Publish
from bridge.core.reception import Reception
from bridge.runtime.state_file import StateFile
from bridge.runtime.virtual_fleet import FastFleet, Timed

KEY = b"a-mission-key-of-32-bytes-000000"
SLOT_S = 1.0
CYCLE_S = 2 * SLOT_S
MISSION = f"""\
mission: lost
modem: {{backend: sim, frame_bytes: 32, options: {{preset: evologics-s2c-im, loss: 0}}}}
mac: {{type: tdma, slot_s: {SLOT_S}, guard_s: 0.1, order: [s, r]}}
wire: {{auth: {{tag_bytes: 4}}}}
nodes:
  s: {{address: 1, position: {{x: 0, y: 0, depth: 5}}}}
  r: {{address: 2, position: {{x: 100, y: 0, depth: 5}}}}
channels:
  - name: nav
    from: s
    to: r
    elements: [{{in: nav, out: s/nav, fields: [{{field: n, type: int, min: 0, max: 100000}}]}}]
  - name: cmd
    from: s
    to: r
    reliable: true
    elements: [{{in: cmd, out: s/cmd, fields: [{{field: n, type: int, min: 0, max: 1000}}]}}]
"""


class Watch:
    """What the fleet's cores output, as far as this test looks."""

    def __init__(self) -> None:
        self.sent: list[tuple[float, bytes]] = []  # s's frames
        self.accepted: list[tuple[float, bytes]] = []  # r's receptions of s's frames
        self.refused: list[tuple[float, str]] = []
        self.published: list[tuple[float, str, int]] = []

    def __call__(self, timed: Timed) -> None:
        out = timed.output
        if timed.node == "s" and isinstance(out, FrameSent):
            self.sent.append((timed.time, out.data))
        elif timed.node == "r" and isinstance(out, FrameReceived) and out.src == "s":
            self.accepted.append((timed.time, out.data))
        elif timed.node == "r" and isinstance(out, FrameDropped) and out.src == "s":
            self.refused.append((timed.time, out.reason))
        elif timed.node == "r" and isinstance(out, Publish):
            self.published.append((timed.time, out.key, out.value["n"]))


def test_a_sender_whose_state_file_is_corrupt_is_heard_again_within_a_cycle(
        tmp_path: Path) -> None:
    watch = Watch()
    fleet = FastFleet(parse_mission(MISSION, "lost.yaml"), key=KEY, seed=3, keep_outputs=False,
                      kinds=(Publish, FrameSent, FrameReceived, FrameDropped), on_output=watch)
    t = 0.0
    while len(watch.sent) < 10_000:  # a long mission first: its counter is far from 0
        t += 10.0
        fleet.put("s", "nav", {"n": int(t)}, at=t)
        fleet.run_until(t)
    assert not watch.refused
    old = [data for _, data in watch.sent]

    # its state file is corrupt (as a crash mid-write of a broken disk could leave it): the
    # node warns, moves it aside and starts afresh
    state = StateFile(tmp_path, "lost", "s")
    state.save(fleet.saved["s"])
    state.path.write_bytes(b"\xc1 not msgpack")
    assert state.load() is None
    restarted = t + 0.1
    fleet.restart("s", keep_state=state.load() is not None)
    for k in range(40):  # it keeps publishing; one reliable command among the values
        fleet.put("s", "nav", {"n": 100_000 - k}, at=restarted + k * 0.1)
    fleet.put("s", "cmd", {"n": 7}, at=restarted + 0.2)
    fleet.run_until(restarted + 20 * CYCLE_S)

    new = {data: at for at, data in watch.sent if at >= restarted}
    first = min(new.values())
    heard = next(new[data] for _, data in watch.accepted if data in new)  # when it was sent
    assert heard - first <= CYCLE_S + 1e-6, (first, heard)
    refused_then = [reason for at, reason in watch.refused if at >= restarted]
    assert refused_then and set(refused_then) == {"replayed"}
    after = [(key, n) for at, key, n in watch.published if at >= restarted]
    assert ("s/cmd", 7) in after  # the new epoch's reliable value is delivered
    assert ("s/nav", 100_000 - 39) in after  # and the latest value

    # every frame of its former life replayed now, and the frames refused after the restart:
    # all refused, nothing published
    r = fleet.cores["r"]
    r.take()
    replays = random.Random(1).sample(old, 200) + old[-5:] + [
        data for at, data in watch.sent if restarted <= at < heard]
    before = r.stats.frames_dropped["replayed"]
    now = fleet.now
    for data in replays:
        r.receive(Reception(data, 1, now, {}), now)
    assert r.stats.frames_dropped["replayed"] - before == len(replays)
    assert not [o for o in r.take() if isinstance(o, Publish)]


def test_a_replayed_frame_is_answered_once_and_changes_nothing_for_its_sender() -> None:
    """A replayer repeating one old frame costs one ``@mark``; the genuine sender, past the
    mark already, keeps its counter."""
    watch = Watch()
    fleet = FastFleet(parse_mission(MISSION, "lost.yaml"), key=KEY, seed=4, keep_outputs=False,
                      kinds=(Publish, FrameSent, FrameReceived, FrameDropped), on_output=watch)
    fleet.put("s", "nav", {"n": 1}, at=0.0)
    fleet.run_until(20 * CYCLE_S)
    s, r = fleet.cores["s"], fleet.cores["r"]
    assert s.auth is not None and r.auth is not None
    counter = s.auth.counter
    old = watch.sent[2][1]
    for _ in range(50):
        r.receive(Reception(old, 1, fleet.now, {}), fleet.now)
    assert [mark for _, mark in r.auth.hints()] == [r.auth.seen[1]]
    fleet.run_until(fleet.now + 4 * CYCLE_S)
    assert not r.auth.owed  # told twice (a frame can be lost), then no more
    assert s.auth.counter >= counter and not [
        reason for at, reason in watch.refused if reason != "replayed"]
