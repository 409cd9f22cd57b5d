"""Polled and ALOHA fleets end to end in real time: Zenoh apps, bridges, the simulated water."""

from __future__ import annotations

import pytest

from tests.conftest import on_free_ports
from tests.harness import Inbox, outside_session, put, running_fleet

FLEET = """\
mission: rt
modem: {backend: sim, frame_bytes: 24, options: {preset: s100-rf, seed: 3}}
mac: MAC
nodes:
  top: {address: 1, role: surface, position: {x: 0, y: 0, depth: 0.5}}
  r1: {address: 2, position: {x: 1, y: 0, depth: 1}}
  r2: {address: 3, position: {x: 0, y: 1, depth: 1}}
channels:
  - name: command
    from: top
    to: "r[12]"
    elements: [{in: command, out: top/command, fields: [{field: v, type: int, min: 0, max: 1000}]}]
  - name: depth
    from: "r[12]"
    to: top
    elements: [{in: depth, out: "{src}/depth", fields: [{field: d, resolution: 0.01, min: 0,
                                                         max: 50}]}]
"""


@pytest.mark.parametrize("mac", [
    "{type: polled, master: top, ipg_s: 0.3}",
    "{type: aloha, backoff_s: 0.3, max_airtime_share: 0.5}",
])
def test_values_cross_both_ways(mac: str) -> None:
    loaded = on_free_ports(FLEET.replace("MAC", mac), "rt.yaml")
    with running_fleet(loaded) as fleet:
        top, r1, r2 = (outside_session(loaded, n) for n in ("top", "r1", "r2"))
        try:
            at_top, at_r2 = Inbox(), Inbox()
            top.declare_subscriber("*/depth", at_top)
            r2.declare_subscriber("top/command", at_r2)
            heard = []
            for step in range(6):  # a fresh value each way every 0.4 s
                put(top, "command", {"v": 100 + step})
                put(r1, "depth", {"d": 10.0 + step})
                put(r2, "depth", {"d": 20.0 + step})
                heard += at_top.drain(0.4)
            heard += at_top.drain(2.0)
            commands = [value["v"] for _, value, _ in at_r2.drain(0.5)]
        finally:
            for session in (top, r1, r2):
                session.close()
        stats = {name: node.stats for name, node in fleet.nodes.items()}
        unsent = {name: [state.channel.name for state in node.core.store.states.values()
                         if state.fresh] for name, node in fleet.nodes.items()}
    # newest value wins, so some are overwritten before a turn; the last one always goes, even
    # when it arrives while that node's own frame is in the air (nothing is left unsent).
    # Whether it is heard is the water's business: a frame can meet another or reach a node
    # while it transmits, and a plain channel does not repeat it.
    assert unsent == {"top": [], "r1": [], "r2": []}
    for rover in ("r1", "r2"):
        seen = [value["d"] for key, value, _ in heard if key == f"{rover}/depth"]
        assert len(seen) >= 3 and seen == sorted(seen)
    assert len(commands) >= 3 and commands == sorted(commands)
    assert stats["top"].received_per_channel["depth"] >= 6
    assert all(stats[n].frames_sent >= 3 for n in ("top", "r1", "r2"))
