"""The "peer runs another mission file" alarm in an authenticated mission needs frames a key
holder sealed: junk (even the same datagram twice) never raises it; a peer with another
mission file and the mission key does, and the alarm clears when it runs this file again."""

from __future__ import annotations

import os

from bridge.core.events import MissionMismatch
from bridge.core.loaded import parse_mission
from bridge.core.node import NodeCore, Status
from bridge.core.reception import Reception
from tests.conftest import MISSIONS

KEY = b"0123456789abcdef-mission-key"
TEXT = (MISSIONS / "morph.yaml").read_text()  # ships with auth: {tag_bytes: 4}
OURS = parse_mission(TEXT, "ours.yaml")
THEIRS = parse_mission(TEXT.replace("bits: 8,", "bits: 9,", 1), "theirs.yaml")
LSV = OURS.mission.address_of("lsv")


def heard(gcv: NodeCore, data: bytes, now: float) -> list[MissionMismatch]:
    gcv.receive(Reception(data, LSV, now, {}), now)
    return [o for o in gcv.take() if isinstance(o, MissionMismatch)]


def sealed(lsv: NodeCore, now: float) -> bytes:
    out = lsv.outbound.build(now, now, always=True)
    assert out is not None
    lsv.outbound.sent(out, now)
    return out.data


def test_identical_junk_datagrams_do_not_raise_the_alarm() -> None:
    assert OURS.table.fingerprint != THEIRS.table.fingerprint
    gcv = NodeCore(OURS, "gcv", key=KEY)
    junk = os.urandom(40)
    for t in range(5):  # the same foreign "fingerprint" frame after frame
        assert heard(gcv, junk, float(t)) == []
    assert gcv.mismatched == {} and gcv.stats.frames_dropped["check"] == 5
    assert "mission_mismatch" not in gcv.stats.frames_dropped


def test_a_key_holder_with_another_mission_file_raises_it_once_and_it_clears() -> None:
    gcv = NodeCore(OURS, "gcv", key=KEY)
    other = NodeCore(THEIRS, "lsv", key=KEY)
    [alarm] = heard(gcv, sealed(other, 1.0), 1.0)  # one sealed frame is proof enough
    assert alarm.peer == "lsv" and gcv.mismatched == {"lsv": alarm.fingerprint}
    assert heard(gcv, sealed(other, 2.0), 2.0) == []  # said once
    assert gcv.stats.frames_dropped["mission_mismatch"] == 2
    forger = NodeCore(THEIRS, "lsv", key=b"not-the-mission-key-but-as-long")
    assert heard(NodeCore(OURS, "gcv", key=KEY), sealed(forger, 3.0), 3.0) == []

    back = NodeCore(OURS, "lsv", key=KEY)  # lsv runs this mission file again
    gcv.receive(Reception(sealed(back, 4.0), LSV, 4.0, {}), 4.0)
    statuses = [o for o in gcv.take() if isinstance(o, Status) and o.topic == "mismatch/lsv"]
    assert gcv.mismatched == {} and gcv.snapshot(4.0)["mismatched_peers"] == {}
    assert statuses and statuses[-1].payload["fingerprint"] is None
