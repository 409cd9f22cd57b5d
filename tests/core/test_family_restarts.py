"""A key family's sender restarted from its saved state keeps its learned names in their order
(a receiver that missed the names again published one member's value on another's key) and a
latching family's member values (sent again without a new put); what no longer fits the
mission is a counted drop."""

from __future__ import annotations

from typing import Any

import msgpack

from bridge.core.loaded import load_mission, parse_mission
from bridge.core.node import NodeCore
from bridge.runtime.virtual_fleet import FastFleet
from tests.conftest import MISSIONS

ZSPACE = MISSIONS / "zspace.yaml"
ALPHA, BRAVO = "auv1/contacts/alpha", "auv1/contacts/bravo"


def contacts(fleet: FastFleet, after: float) -> list[tuple[str, float]]:
    return [(p.key, p.value["range_m"]) for t, p in fleet.published("top")
            if t > after and "/contacts/" in p.key]


def test_a_restarted_sender_keeps_its_member_numbers_and_latched_members() -> None:
    """Seed 20 at 50 % loss: every frame with bravo's name after the restart was lost, and the
    surface published bravo's new value on alpha's key (member 0 before the restart)."""
    fleet = FastFleet(load_mission(ZSPACE), seed=20, loss=0.5)
    for node in fleet.cores:
        fleet.subscribe(node, "**")
    fleet.put("auv1", ALPHA, {"range_m": 100, "bearing_deg": 10}, at=1)
    fleet.put("auv1", BRAVO, {"range_m": 200, "bearing_deg": 20}, at=2)
    fleet.run_until(300)
    fleet.restart("auv1")
    fleet.put("auv1", BRAVO, {"range_m": 222, "bearing_deg": 22}, at=301)
    fleet.run_until(600)
    got = contacts(fleet, 300)
    assert (BRAVO, 222.0) in got
    assert (ALPHA, 222.0) not in got
    assert (ALPHA, 100.0) in got  # latched: sent again with no new put
    assert fleet.cores["auv1"].outbound.families.senders[
        next(iter(fleet.cores["auv1"].outbound.families.senders))].names == ["a", "b", "c"]


def unresumable(core: NodeCore) -> int:
    causes = core.snapshot(5.0)["payload_drop_causes"]
    return sum(c.get("unresumable", 0) for c in causes.values())


def saved_state(text: str) -> dict[str, Any]:
    auv = NodeCore(parse_mission(text, "zspace.yaml"), "auv1")
    auv.saved()
    for name, r in (("alpha", 100), ("bravo", 200)):
        auv.ingest(f"auv1/contacts/{name}", msgpack.packb({"range_m": r, "bearing_deg": 0}),
                   "application/msgpack", 1.0)
    assert auv.needs_save  # (a learned name asks for a save, as a latched value does)
    auv.ingest("auv1/sensors/a/temp", msgpack.packb({"celsius": 4.0}), "application/msgpack",
               1.0)
    state = auv.state()
    assert state["families"]["contacts"]["names"] == ["alpha", "bravo"]
    assert set(state["families"]["contacts"]["latched"]) == {"alpha", "bravo"}
    assert "temps" not in state["families"]  # listed members, not latching: nothing to keep
    return state


def test_names_and_values_resume_under_the_same_mission() -> None:
    text = ZSPACE.read_text()
    auv = NodeCore(parse_mission(text, "zspace.yaml"), "auv1", state=saved_state(text))
    sender = next(s for s in auv.outbound.families.senders.values()
                  if s.channel.name == "contacts")
    assert sender.names == ["alpha", "bravo"]
    before = NodeCore(parse_mission(text, "zspace.yaml"), "auv1")
    before.ingest("auv1/contacts/alpha", msgpack.packb({"range_m": 100, "bearing_deg": 0}),
                  "application/msgpack", 1.0)
    (alpha,) = next(s for s in before.outbound.families.senders.values()
                    if s.channel.name == "contacts").states.values()
    assert sender.states[0].packed == alpha.packed and sender.states[0].updated == [1.0]
    assert sender.states[1].packed != alpha.packed
    auv.tick(5.0)
    assert unresumable(auv) == 0


def test_what_no_longer_fits_is_a_counted_drop() -> None:
    text = ZSPACE.read_text()
    state = saved_state(text)
    smaller = text.replace("keys: {learn: 8, name_bytes: 8}", "keys: {learn: 8, name_bytes: 4}")
    auv = NodeCore(parse_mission(smaller, "zspace.yaml"), "auv1", state=state)
    auv.tick(5.0)
    sender = next(s for s in auv.outbound.families.senders.values()
                  if s.channel.name == "contacts")
    assert sender.names == []  # "alpha" and "bravo" no longer fit in 4 bytes
    assert unresumable(auv) == 3  # the names, and each of the two values


def test_an_unreadable_saved_family_is_a_counted_drop_never_a_crash() -> None:
    text = ZSPACE.read_text()
    for families in ("garbage", {"contacts": {"names": [1, 2]}},
                     {"contacts": {"latched": {"alpha": {"shape": "x"}}}},
                     {"contacts": {"names": ["alpha"], "latched": {"alpha": {"oops": 1}}}},
                     {"nosuch": {}}):
        state = saved_state(text) | {"families": families}
        auv = NodeCore(parse_mission(text, "zspace.yaml"), "auv1", state=state)
        auv.tick(5.0)
        assert unresumable(auv) >= 1, families
