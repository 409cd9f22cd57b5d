"""Reliable commands and large payloads across a lossy ocean, end to end.

The 30 %-loss runs use the virtual-clock fleet (same cores, pure ocean), so a run of an hour of
mission takes a second; one run goes through real Zenoh sessions to check the keys."""

from __future__ import annotations

import os
from collections import Counter

from bridge.core.loaded import parse_mission
from bridge.core.node import Publish, Status
from bridge.runtime.virtual_fleet import FastFleet

MISSION = """\
mission: lossy
modem: {backend: sim, frame_bytes: 64, options: {preset: evologics-s2c-im}}
mac: {type: tdma, slot_s: 2.0, guard_s: 0.2, order: [ops, auv]}
nodes:
  ops: {address: 1, role: surface, position: {x: 0, y: 0, depth: 0}}
  auv: {address: 2, position: {x: 300, y: 0, depth: 20}}
channels:
  - name: command
    from: ops
    to: auv
    reliable: true
    queue: 1000
    elements:
      - in: cmd
        out: ops/cmd
        fields: [{field: n, type: int, min: 0, max: 1023}, {field: go, type: bool}]
  - name: image
    from: auv
    to: ops
    reliable: true
    elements:
      - in: image
        out: auv/image
        fields: [{field: jpeg, type: bytes, max_length: 20000}]
  - name: nav
    from: auv
    to: ops
    elements:
      - in: nav
        out: auv/nav
        fields: [{field: depth, type: float, min: 0, max: 100, bits: 10}]
"""


def final_reports(fleet: FastFleet, channel: str) -> dict[int, dict]:
    out: dict[int, dict] = {}
    for timed in fleet.outputs:
        output = timed.output
        if isinstance(output, Status) and output.topic == f"delivery/{channel}":
            out[output.payload["id"]] = output.payload
    return out


def test_thousand_commands_and_a_20kB_image_at_30_percent_loss() -> None:
    fleet = FastFleet(parse_mission(MISSION), seed=7, loss=0.3)
    for i in range(1000):
        fleet.put("ops", "cmd", {"n": i, "go": i % 2 == 0}, at=1.0 + i * 0.5)
    image = os.urandom(20_000)
    fleet.put("auv", "image", {"jpeg": image}, at=5.0)
    for i in range(1500):
        fleet.put("auv", "nav", {"depth": i % 100}, at=i * 4.0)
    fleet.run_until(6000.0)

    got = [p.value["n"] for _, p in fleet.published("auv", "ops/cmd")]
    reports = final_reports(fleet, "command")
    states = Counter(r["state"] for r in reports.values())
    delivered = sorted(i for i, r in reports.items() if r["state"] == "delivered")
    images = fleet.published("ops", "auv/image")
    lost = fleet.ocean.link_stats(1, 2).as_dict()
    last = max(r["time"] for r in reports.values())
    whole = bool(images) and images[0][1].value["jpeg"] == image
    print(f"\n1000 commands at 30 % loss: {len(got)} published, {len(set(got))} distinct, "
          f"reports {dict(states)}; last delivered at t={last:.0f} s; link ops→auv {lost}")
    print(f"20 kB image: {len(images)} published, whole={whole}, "
          f"at t={images[0][0] if images else float('nan'):.0f} s; nav published "
          f"{len(fleet.published('ops', 'auv/nav'))}/1500 (latest-wins, lossy)")
    assert got == sorted(got) and len(got) == len(set(got)), "in order, exactly once"
    assert set(got) == set(delivered), "delivered means published, failed means not"
    assert states["delivered"] + states["failed"] == 1000
    assert states["delivered"] >= 990
    assert len(images) == 1 and images[0][1].value["jpeg"] == image
    done = final_reports(fleet, "image")[0]
    assert done["state"] == "delivered"


def test_ttl_fails_commands_to_a_silent_vehicle_and_they_are_never_published() -> None:
    text = MISSION.replace("    queue: 1000\n", "    queue: 1000\n    ttl_s: 30\n", 1)
    fleet = FastFleet(parse_mission(text), seed=1)
    fleet.stop("auv")
    for i in range(5):
        fleet.put("ops", "cmd", {"n": i, "go": True}, at=1.0 + i)
    fleet.run_until(40.0)  # every command is older than its TTL before the vehicle returns
    fleet.resume("auv")
    fleet.run_until(100.0)
    reports = final_reports(fleet, "command")
    assert [r["state"] for r in reports.values()] == ["failed"] * 5
    assert all("ttl_s=30" in r["reason"] for r in reports.values())
    assert fleet.published("auv", "ops/cmd") == []


def test_a_newer_value_cancels_an_unfinished_latest_wins_transfer() -> None:
    text = MISSION.replace("  - name: image\n    from: auv\n    to: ops\n    reliable: true\n",
                           "  - name: image\n    from: auv\n    to: ops\n")
    fleet = FastFleet(parse_mission(text), seed=2)
    first, second = os.urandom(3000), os.urandom(3000)
    fleet.put("auv", "image", {"jpeg": first}, at=1.0)
    fleet.put("auv", "image", {"jpeg": second}, at=30.0)
    fleet.run_until(1500.0)
    images = [p.value["jpeg"] for _, p in fleet.published("ops", "auv/image")]
    assert images == [second]
    reports = final_reports(fleet, "image")
    assert reports[0]["state"] == "failed" and "cancelled" in reports[0]["reason"]
    assert reports[1]["state"] == "delivered"
    progress = [o.output.payload for o in fleet.outputs if isinstance(o.output, Status)
                and o.output.topic == "transfer/image" and o.node == "ops"]
    assert progress[-1]["state"] == "complete"
    assert progress[-1]["fragments_done"] == progress[-1]["fragments_total"]


def test_publications_are_plain_values() -> None:
    fleet = FastFleet(parse_mission(MISSION), seed=3)
    fleet.put("ops", "cmd", {"n": 7, "go": True}, at=1.0)
    fleet.run_until(30.0)
    [(_, publish)] = fleet.published("auv", "ops/cmd")
    assert isinstance(publish, Publish) and publish.value == {"n": 7, "go": True}
