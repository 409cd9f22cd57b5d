"""Per-hop retransmission at a relay (bridge.core.custody), pure: what keeps a carried frame,
what releases it, when it goes again, and what bounds it; and where a relay can tell that its
next hop has a frame (bridge.core.routing.overhears)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from bridge.core.custody import HOP_COPIES, KEPT_MAX, Custody
from bridge.core.loaded import load_mission
from bridge.core.routing import overhears

MISSIONS = Path(__file__).resolve().parents[2] / "deploy" / "missions"
ANSWER_S, TRIP_S = 5.0, 36.0  # n2's answer can come 5 s after a copy; unheard, 36 s


@dataclass(eq=False)
class Frame:
    life_ends: float = math.inf

    def expires(self) -> float:
        return self.life_ends


def relay() -> Custody[Frame]:
    """n1 of a line head - n1 - n2 - tail."""
    return Custody({"n2": ANSWER_S, "head": ANSWER_S}, {"n2": TRIP_S, "head": TRIP_S})


def kept(custody: Custody[Frame], frame: Frame, seq: int = 7,
         entries: frozenset[tuple[int, int]] = frozenset({(1, 40)})) -> Frame:
    custody.keep(frame, "modem", "n2", "head", seq, {"tail": entries})
    return frame


def test_a_copy_goes_again_when_the_next_hop_spoke_without_carrying_it_on() -> None:
    custody = relay()
    frame = kept(custody, Frame())
    assert custody.due("modem", 100.0) == []  # queued, not sent yet: nothing to send again
    custody.sent(frame, 10.0)
    custody.heard("n2", 12.0)  # too soon: that frame of n2 left before the copy reached it
    assert custody.next_time("modem") == 10.0 + TRIP_S
    assert custody.due("modem", 13.0) == []
    custody.heard("n2", 16.0)  # n2's turn came, and it did not carry the frame on: lost
    assert custody.next_time("modem") == 16.0
    assert custody.due("modem", 20.0) == [frame]
    assert custody.due("modem", 20.0) == []  # queued again: once
    custody.sent(frame, 26.0)
    assert custody.resent == 1


def test_a_next_hop_never_heard_is_given_a_round_trip() -> None:
    custody = relay()
    frame = kept(custody, Frame())
    custody.sent(frame, 10.0)
    custody.heard("head", 30.0)  # another neighbour says nothing of n2
    assert custody.due("modem", 10.0 + TRIP_S - 1) == []
    assert custody.due("modem", 10.0 + TRIP_S) == [frame]


def test_the_next_hop_carrying_it_on_releases_it() -> None:
    custody = relay()
    frame = kept(custody, Frame(), seq=7)
    other = kept(custody, Frame(), seq=8)
    custody.sent(frame, 10.0)
    custody.sent(other, 10.0)
    custody.forwarded("head", "head", 7)  # not the next hop: proves nothing
    custody.forwarded("n2", "head", 7)
    custody.heard("n2", 16.0)
    assert custody.due("modem", 20.0) == [other]
    assert custody.released == 1


def test_the_destination_s_acknowledgement_releases_what_it_covers() -> None:
    custody = relay()
    frame = kept(custody, Frame(), entries=frozenset({(1, 40), (1, 41), (1, 43)}))
    custody.sent(frame, 10.0)
    custody.heard("n2", 16.0)
    custody.acked("tail", "head", 1, 41, 0b10)  # 40 (before the base) and 43 (bit 2) only
    custody.acked("tail", "head", 2, 50, 0)  # another stream of head's: not these
    custody.acked("n2", "head", 1, 50, 0)  # not the destination
    custody.acked("tail", "n2", 1, 50, 0)  # another origin's stream
    assert custody.due("modem", 20.0) == [frame]  # 41 is still owed
    custody.sent(frame, 26.0)
    custody.acked("tail", "head", 1, 42, 0)
    assert custody.kept["modem"] == [] and custody.released == 1


def test_copies_are_bounded_and_so_is_what_a_relay_keeps() -> None:
    custody = relay()
    frame = kept(custody, Frame())
    t = 0.0
    for _ in range(HOP_COPIES + 1):
        custody.sent(frame, t)
        t += 20.0
        custody.heard("n2", t - 10.0)
        got = custody.due("modem", t)
    assert got == []  # the first and HOP_COPIES more were sent: it is let go
    assert custody.kept["modem"] == [] and custody.resent == HOP_COPIES
    frames = [kept(custody, Frame(), seq=i) for i in range(KEPT_MAX + 3)]
    assert [k.frame for k in custody.kept["modem"]] == frames[3:]  # the oldest let go


def test_a_frame_past_its_life_or_dropped_from_the_queue_is_let_go() -> None:
    custody = relay()
    old = kept(custody, Frame(life_ends=50.0), seq=1)
    dropped = kept(custody, Frame(), seq=2)
    custody.sent(old, 10.0)
    custody.forget(dropped)  # (the queue was full, or it expired there)
    custody.heard("n2", 60.0)
    assert custody.due("modem", 60.0) == [] and custody.kept["modem"] == []


def test_nothing_is_kept_without_reliable_entries_for_a_destination() -> None:
    custody = relay()
    custody.keep(Frame(), "modem", "n2", "head", 3, {"tail": set()})
    assert custody.kept == {}


def test_custody_only_where_the_relay_hears_the_next_hop_s_answer() -> None:
    line = load_mission(MISSIONS / "acoustic_line.yaml").network
    assert overhears(line, "head", "head", "n1", ["tail"])  # n1 forwards on the one link
    assert overhears(line, "n1", "head", "n2", ["tail"])
    assert overhears(line, "n2", "head", "tail", ["tail"])  # tail's ack comes back via n2
    umci = load_mission(MISSIONS / "umci_relay.yaml").network
    # ROV1 reaches ROV2 over RF (preferred) and acoustics: the surface hears only the latter
    assert not overhears(umci, "surface", "surface", "rov1", ["rov2"])
    assert overhears(umci, "rov1", "surface", "rov2", ["rov2"])  # ROV2's ack goes via ROV1
