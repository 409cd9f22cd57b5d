"""A node's keyspace (issue 32): puts nothing reads are counted, bounded and said once; gets
that map to nothing are told why."""

from __future__ import annotations

from bridge.core.events import UnmappedKey
from bridge.core.keyspace import MAX_KEYS, OTHER
from bridge.core.loaded import load_mission
from bridge.core.node import NodeCore
from tests.conftest import MISSIONS

ZSPACE = MISSIONS / "zspace.yaml"


def test_a_put_nothing_reads_is_counted_once_said_and_bounded() -> None:
    core = NodeCore(load_mission(ZSPACE), "auv1")
    keyspace = core.outbound.keyspace
    assert keyspace.expressions == ["auv1/**"]
    assert keyspace.maps("auv1/status") and keyspace.maps("auv1/sensors/b/temp")
    assert not keyspace.maps("auv1/statsu")
    for _ in range(3):
        keyspace.unmapped("auv1/statsu", 1.0)
    for n in range(MAX_KEYS + 5):
        keyspace.unmapped(f"auv1/k{n}", 2.0)
    counted = core.snapshot(3.0)["unmapped_keys"]
    assert counted["auv1/statsu"] == 3 and counted[OTHER] == 6 and len(counted) == MAX_KEYS + 1
    said = [o for o in core.take() if isinstance(o, UnmappedKey)]
    assert [e.key for e in said][:2] == ["auv1/statsu", "auv1/k0"] and len(said) == MAX_KEYS


def test_a_get_on_a_peers_keyspace_is_answered_or_told_why_not() -> None:
    keyspace = NodeCore(load_mission(ZSPACE), "top").outbound.keyspace
    assert keyspace.peer_keyspaces() == ["auv1/**", "auv2/**"]
    assert keyspace.unanswered("auv1/info") is None  # a query
    assert keyspace.unanswered("auv1/status") is None  # a latched channel's output
    assert keyspace.unanswered("auv1/**") is None
    assert "not latched" in (keyspace.unanswered("auv1/sensors/a/temp") or "")
    assert "nothing crosses the water" in (keyspace.unanswered("auv2/typo") or "")



def test_a_surfaced_node_leaves_gets_to_whoever_answers_over_ip() -> None:
    core = NodeCore(load_mission(ZSPACE), "top")
    keyspace = core.outbound.keyspace
    core.ip_reachable("auv1", True, 1.0)  # a peer's bridge or apps may answer now
    assert keyspace.unanswered("auv2/typo") is None
    core.ip_reachable("auv1", False, 2.0)
    assert "nothing crosses the water" in (keyspace.unanswered("auv2/typo") or "")
