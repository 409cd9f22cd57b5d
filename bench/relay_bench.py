"""Relays and link failover, measured (issue 29).

Three parts, each printed as a table and as JSON lines (``--json``):

1. **hops**: a line of ``hops + 1`` vehicles 2 km apart on one acoustic link (EvoLogics S2C,
   3.5 km: each hears its neighbours only), TDMA, static routes. The far end sends ``pose``
   every 30 s to the head; the head sends a reliable ``command`` every 60 s to the far end.
   For 1 to 4 hops at 0, 10 and 30 % loss per hop, on the virtual clock (FastFleet, the one
   core): the delivery ratio of ``pose`` (distinct values published / values put), its age of
   information at the head (mean and worst of the sawtooth) against the bound ``zab check``
   prints (interval + every hop's worst turn and frame), the reliable commands delivered and
   failed, and the airtime the relays spent on what they carried against the airtime of the
   far end's own frames (a paired ratio: relaying costs that many times the origin's sends).
2. **failover**: ``deploy/missions/umci_relay.yaml`` (ROV2 drifting out of RF range and back
   on a 221 s loop): per crossing, the time from ROV2 leaving the 5 m RF range (from its path)
   to its traffic to the surface failing over to acoustics, and from its return to the
   failback, against the RF link's down_after_s and failback_s.
3. **reroute**: a diamond, the surface and a far vehicle 4 km apart on one acoustic link, two
   relays between them, each route listing both (``routes: {far: [r1, r2]}``); r1 killed for
   200 s and restarted, again and again, at 0, 10 and 30 % loss: per kill, the time until the
   surface's and far's traffic moved to r2 (against down_after_s) and back to r1 after the
   restart (against failback_s), and the reliable commands delivered once or reported failed.
4. **chaos**: seed 002's relay (surface -> ROV1 acoustic -> ROV2 RF) with 30 % loss per hop,
   reliable commands from the surface to ROV2, and ROV1 (the relay) killed and restarted again
   and again, as ``bench/chaos.py`` does: every command delivered once or reported failed,
   none twice, none without a report. ``--real`` runs the real processes (``zab water``, one
   ``zab run`` per node) with SIGKILL of the relay.

Run: ``uv run python bench/relay_bench.py [--duration 3600] [--json] [--real]``.
"""

from __future__ import annotations

import argparse
import json
import random
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

import chaos  # noqa: E402  (bench/chaos.py: its tally and process helpers)

from bridge.core.bounds import route_s  # noqa: E402
from bridge.core.events import (  # noqa: E402
    FrameRelayed,
    FrameSent,
    LinkSwitched,
    RouteSwitched,
)
from bridge.core.loaded import load_mission, parse_mission  # noqa: E402
from bridge.core.node import Publish, Status  # noqa: E402
from bridge.mission.path import Path as Route  # noqa: E402
from bridge.mission.presets import get_preset  # noqa: E402
from bridge.report.age import AgeOfInformation  # noqa: E402
from bridge.report.check import check_mission  # noqa: E402
from bridge.runtime.virtual_fleet import FastFleet, Timed  # noqa: E402

SPACING_M = 2000.0
POSE_S = 30.0
COMMAND_S = 60.0
COMMAND_TTL_S = 1200.0
CHAOS_EVERY_S = 5.0
"""A command this often through the relay: what two lossy hops (30 % each) and a relay down
now and then carry (every 2 s, the reliable queue overflows: reported failed, still once)."""
ROUND_TURN_S = 20.0  # a hop's worst case on the line: a TDMA turn (4 s x nodes) and a frame


def line_mission(hops: int, loss: float) -> str:
    """A line of ``hops + 1`` nodes, ``n0`` the head; each routes through its neighbours.
    Commands are retried after a one-way worst case (half the default round trip, which
    doubles up to four times) and end by their TTL at the latest."""
    retry_s = hops * ROUND_TURN_S
    names = [f"n{i}" for i in range(hops + 1)]
    nodes = []
    for i, name in enumerate(names):
        routes = {d: names[i - 1] if j < i else names[i + 1]
                  for j, d in enumerate(names) if abs(j - i) > 1}
        nodes.append(f"  {name}: {{address: {i + 1}, position: {{x: {i * SPACING_M}, y: 0, "
                     f"depth: 50}}, routes: {json.dumps(routes)}}}")
    far = names[-1]
    return f"""\
mission: line{hops}
wire: {{auth: off}}
max_hops: {max(hops, 1)}
modem: {{backend: sim, frame_bytes: 64, options: {{preset: evologics-s2c-im, loss: {loss}}}}}
mac: {{type: tdma, slot_s: 4.0, guard_s: 0.5, order: [{", ".join(names)}]}}
nodes:
{chr(10).join(nodes)}
channels:
  - name: pose
    from: {far}
    to: n0
    elements:
      - in: pose
        out: far/pose
        fields: [{{field: n, type: int, min: 0, max: 65535}}]
  - name: command
    from: n0
    to: {far}
    reliable: true
    retry_s: {retry_s:g}
    retries: 8
    ttl_s: {COMMAND_TTL_S:g}
    elements:
      - in: command
        out: head/command
        fields: [{{field: n, type: int, min: 0, max: 65535}}]
"""


def hops_run(hops: int, loss: float, duration: float, seed: int) -> dict[str, Any]:
    """One line on the virtual clock: delivery, age against the bound, relay airtime."""
    loaded = parse_mission(line_mission(hops, loss), f"line{hops}.yaml")
    far = f"n{hops}"
    network = check_mission(loaded).data.get("network")  # (one hop: no routes to print)
    bound = next(a["age_bound_s"] for a in network["age_bounds"] if a["channel"] == "pose") \
        if network else round(route_s(loaded.network, far, "n0"), 3)  # (interval 0)
    ages = AgeOfInformation()
    poses: list[int] = []
    latency: list[float] = []  # each value's age when it arrives: publication - put
    reports: Counter[str] = Counter()
    preset = get_preset(loaded.mission.modem.options["preset"])
    relay_s, own_s = 0.0, 0.0

    def seen(timed: Timed) -> None:
        nonlocal relay_s, own_s
        out = timed.output
        if isinstance(out, Publish) and out.key == "far/pose":
            poses.append(int(out.value["n"]))
            latency.append(timed.time - (1.0 + poses[-1] * POSE_S))
            ages.arrived("pose", timed.node, timed.time)
        elif isinstance(out, Status) and out.topic == "delivery/command" \
                and out.payload["state"] in ("delivered", "failed"):
            reports[out.payload["state"]] += 1
        elif isinstance(out, FrameRelayed):  # (each as if alone: bundles share a preamble)
            relay_s += preset.airtime(out.size + loaded.table.net_header_bytes)
        elif isinstance(out, FrameSent) and timed.node == far:
            own_s += preset.airtime(out.size)

    fleet = FastFleet(loaded, seed=seed, keep_outputs=False, on_output=seen)
    puts = int(duration // POSE_S)
    for i in range(puts):
        fleet.put(far, "pose", {"n": i}, at=1.0 + i * POSE_S)
    commands = int(duration // COMMAND_S)
    for i in range(commands):
        fleet.put("n0", "command", {"n": i}, at=5.0 + i * COMMAND_S, ref=str(i))
    started = time.perf_counter()
    fleet.run_until(duration + COMMAND_TTL_S + 60.0)  # every command's terminal report
    summary = ages.summary(duration).get("pose", {"mean_s": None, "max_s": None})
    return {
        "part": "hops", "hops": hops, "loss": loss,
        "delivery": round(len(set(poses)) / puts, 3),
        "value_age_mean_s": round(sum(latency) / len(latency), 1) if latency else None,
        "value_age_max_s": round(max(latency), 1) if latency else None,
        "bound_s": bound,
        "max_over_bound": round(max(latency) / bound, 2) if latency and bound else None,
        "aoi_mean_s": summary["mean_s"], "aoi_max_s": summary["max_s"],
        "commands": commands, "delivered": reports["delivered"], "failed": reports["failed"],
        "relay_airtime_s": round(relay_s, 1), "origin_airtime_s": round(own_s, 1),
        "relay_over_origin": round(relay_s / own_s, 2) if own_s else None,
        "wall_s": round(time.perf_counter() - started, 2),
    }


def failover_run(duration: float, seed: int) -> list[dict[str, Any]]:
    """umci_relay: per RF loss and return, how long until ROV2's traffic moved."""
    loaded = load_mission(ROOT / "deploy" / "missions" / "umci_relay.yaml")
    mission = loaded.mission
    rov1 = mission.nodes["rov1"].position
    spec = mission.nodes["rov2"].path
    assert rov1 is not None and spec is not None
    route = Route.from_spec(spec)
    rf = loaded.network.link("rf")
    limit = 5.0  # the S100's range
    switches: list[tuple[float, str]] = []

    def seen(timed: Timed) -> None:
        out = timed.output
        if isinstance(out, LinkSwitched) and timed.node == "rov2" and out.peer == "surface":
            switches.append((timed.time, out.reason))

    fleet = FastFleet(loaded, seed=seed, keep_outputs=False, on_output=seen,
                      kinds=(LinkSwitched,))
    fleet.run_until(duration)
    crossings = []
    step, t, was_in = 0.05, 0.0, True
    while t < duration:
        x, y, depth = route.position_at(t)
        inside = ((x - rov1.x) ** 2 + (y - rov1.y) ** 2 + (depth - rov1.depth) ** 2) ** 0.5 \
            <= limit
        if inside != was_in:
            crossings.append((t, "failback" if inside else "failover"))
            was_in = inside
        t += step
    health = rf.view.link
    out = []
    for at, kind in crossings:
        moved = next((s for s, r in switches if r == kind and s >= at), None)
        out.append({"part": "failover", "crossing_s": round(at, 1), "switch": kind,
                    "after_s": None if moved is None else round(moved - at, 1),
                    "down_after_s": health.down_after_s, "failback_s": health.failback_s})
    return out


def diamond_mission(loss: float) -> str:
    """Surface and far 4 km apart (the S2C's 3.5 km), r1 and r2 2.2 km from both."""
    modem = {"backend": "sim", "frame_bytes": 64,
             "options": {"preset": "evologics-s2c-im", "loss": loss}}
    spots = {"surface": (0, 0), "r1": (2000, 1000), "r2": (2000, -1000), "far": (4000, 0)}
    nodes: dict[str, Any] = {
        name: {"address": i + 1, "position": {"x": x, "y": y, "depth": 20}}
        for i, (name, (x, y)) in enumerate(spots.items())}
    nodes["surface"]["routes"] = {"far": ["r1", "r2"]}
    nodes["far"]["routes"] = {"surface": ["r1", "r2"]}
    return yaml.safe_dump({
        "mission": "diamond", "wire": {"auth": "off"}, "modem": modem,
        "mac": {"type": "tdma", "slot_s": 3.0, "guard_s": 1.6, "order": list(spots)},
        "link": {"degraded_after_s": 30, "down_after_s": 45, "failback_s": 45},
        "nodes": nodes,
        "channels": [{"name": "command", "from": "surface", "to": "far", "reliable": True,
                      "ttl_s": COMMAND_TTL_S, "elements": [
                          {"in": "cmd", "out": "far/cmd",
                           "fields": [{"field": "n", "type": "int", "min": 0,
                                       "max": 65535}]}]}]}, sort_keys=False)


def reroute_run(loss: float, kills: int, seed: int) -> dict[str, Any]:
    """The diamond with r1 killed ``kills`` times: failover and failback delays per kill."""
    loaded = parse_mission(diamond_mission(loss), "diamond.yaml")
    tally = chaos.Tally()
    switches: list[tuple[float, str, str]] = []

    def collect(timed: Timed) -> None:
        out = timed.output
        if isinstance(out, RouteSwitched):
            switches.append((timed.time, timed.node, out.reason))
        elif isinstance(out, Publish) and timed.node == "far" and out.key == "far/cmd":
            tally.published.append(int(out.value["n"]))
        elif isinstance(out, Status) and out.topic == "delivery/command":
            tally.add_report(out.payload)

    fleet = FastFleet(loaded, seed=seed, keep_outputs=False, on_output=collect)
    cycle = 600.0  # killed at 100 s into each, restarted 200 s later
    commands = int(kills * cycle / 20.0)
    for i in range(commands):
        fleet.put("surface", "cmd", {"n": i}, at=1.0 + 20.0 * i, ref=str(i))
    tally.offered = commands
    for k in range(kills):
        fleet.call_at(k * cycle + 100.0, lambda: fleet.stop("r1"))
        fleet.call_at(k * cycle + 300.0, lambda: fleet.restart("r1"))
    fleet.run_until(kills * cycle + COMMAND_TTL_S)
    over, back = [], []
    for k in range(kills):
        for node in ("surface", "far"):
            moved = [t for t, n, r in switches if n == node and r == "failover"
                     and k * cycle + 100.0 <= t < k * cycle + 300.0]
            returned = [t for t, n, r in switches if n == node and r == "failback"
                        and k * cycle + 300.0 <= t < (k + 1) * cycle + 100.0]
            over += [moved[0] - k * cycle - 100.0] if moved else []
            back += [returned[0] - k * cycle - 300.0] if returned else []
    link = loaded.mission.link
    return {"part": "reroute", "loss": loss, "kills": kills, "failovers": len(over),
            "failover_s": _spread(over), "failbacks": len(back), "failback_s": _spread(back),
            "switches": len(switches), "down_after_s": link.down_after_s,
            "failback_after_s": link.failback_s, **tally.summary()}


def _spread(values: list[float]) -> list[float] | None:
    """[min, mean, max] of ``values`` (None: none)."""
    if not values:
        return None
    return [round(min(values), 1), round(sum(values) / len(values), 1), round(max(values), 1)]


CHAOS = """\
mission: relay_chaos
wire: {auth: off}
links:
  acoustic:
    modem: {backend: sim, frame_bytes: 64, options: {preset: evologics-s2c-im, loss: @LOSS@,
            water: "127.0.0.1:@W1@"}}
    mac: {type: tdma, slot_s: 2.0, guard_s: 0.2, order: [surface, rov1]}
    nodes: [surface, rov1]
  rf:
    kind: rf
    modem: {backend: sim, frame_bytes: 64, options: {preset: s100-rf, loss: @LOSS@,
            water: "127.0.0.1:@W2@"}}
    mac: {type: polled, master: rov1, ipg_s: 1.0}
    nodes: [rov1, rov2]
    link: {degraded_after_s: 3, down_after_s: 6}
nodes:
  surface: {address: 1, role: surface, position: {x: 0, y: 0, depth: 0}, routes: {rov2: rov1},
            zenoh: {listen: ["tcp/127.0.0.1:@SURFACE@"]}}
  rov1: {address: 2, position: {x: 300, y: 0, depth: 20},
         zenoh: {listen: ["tcp/127.0.0.1:@ROV1@"]}}
  rov2: {address: 3, position: {x: 303, y: 0, depth: 20}, routes: {surface: rov1},
         zenoh: {listen: ["tcp/127.0.0.1:@ROV2@"]}}
channels:
  - name: command
    from: surface
    to: rov2
    reliable: true
    queue: 256
    elements:
      - in: cmd
        out: ops/cmd
        fields: [{field: n, type: int, min: 0, max: 65535}]
"""


def chaos_text(loss: float, ports: dict[str, int] | None = None) -> str:
    ports = ports or {"W1": 7640, "W2": 7641, "SURFACE": 7642, "ROV1": 7643, "ROV2": 7644}
    return chaos.mission_text(loss, ports, template=CHAOS)


def chaos_virtual(commands: int, restarts: int, loss: float, seed: int) -> dict[str, Any]:
    """Reliable commands through a relay killed ``restarts`` times (state kept, as a kill -9
    leaves it on disk; its carried frames lost)."""
    tally = chaos.Tally()

    def collect(timed: Timed) -> None:
        out = timed.output
        if isinstance(out, Publish) and timed.node == "rov2" and out.key == "ops/cmd":
            tally.published.append(int(out.value["n"]))
        elif isinstance(out, Status) and out.topic == "delivery/command":
            tally.add_report(out.payload)

    fleet = FastFleet(parse_mission(chaos_text(loss), "relay_chaos.yaml"), seed=seed,
                      keep_outputs=False, on_output=collect)
    rng = random.Random(seed)
    end = 1.0 + commands * CHAOS_EVERY_S
    for i in range(commands):
        fleet.put("surface", "cmd", {"n": i}, at=1.0 + i * CHAOS_EVERY_S, ref=str(i))
    tally.offered = commands
    for t in sorted(rng.uniform(5.0, end) for _ in range(restarts)):
        fleet.call_at(t, lambda: fleet.stop("rov1"))
        fleet.call_at(t + rng.uniform(1.0, 8.0), lambda: fleet.restart("rov1"))
    fleet.run_until(end + 3600.0)
    return {"part": "chaos", "mode": "virtual", "loss": loss, "restarts": restarts,
            **tally.summary()}


def chaos_real(commands: int, loss: float, seed: int, kill_every_s: float = 20.0,
               interval_s: float = CHAOS_EVERY_S, settle_s: float = 900.0) -> dict[str, Any]:
    """The real processes: ``zab water`` (both links' waters) and a ``zab run`` per node; the
    relay killed with SIGKILL every ``kill_every_s`` and started again (bench/chaos.py)."""
    ports = {n: chaos.free_port() for n in ("W1", "W2", "SURFACE", "ROV1", "ROV2")}
    with tempfile.TemporaryDirectory(prefix="zab-relay-chaos-") as tmp:
        mission = Path(tmp) / "relay_chaos.yaml"
        mission.write_text(chaos_text(loss, ports))
        tally = chaos.drive_real(mission, ["water", "surface", "rov1", "rov2"],
                                 ports["SURFACE"], ports["ROV2"],
                                 "@zab/relay_chaos/surface/delivery/command", ["rov1"],
                                 commands, seed, kill_every_s, interval_s, settle_s)
    return {"part": "chaos", "mode": "real", "loss": loss, **tally.summary()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=3600.0)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--commands", type=int, default=2000)
    parser.add_argument("--restarts", type=int, default=60)
    parser.add_argument("--real", action="store_true", help="chaos with real processes")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    rows: list[dict[str, Any]] = []
    for hops in (1, 2, 3, 4):
        for loss in (0.0, 0.1, 0.3):
            rows.append(hops_run(hops, loss, args.duration, args.seed))
    rows += failover_run(min(args.duration, 1200.0), args.seed)
    rows += [reroute_run(loss, max(1, int(args.duration // 600)), args.seed)
             for loss in (0.0, 0.1, 0.3)]
    chaos_row = chaos_real(args.commands // 10, 0.3, args.seed) if args.real \
        else chaos_virtual(args.commands, args.restarts, 0.3, args.seed)
    rows.append(chaos_row)
    if args.json:
        for row in rows:
            print(json.dumps(row))
    else:
        print_tables(rows)
    print("chaos goal met" if chaos.goal_met(chaos_row) else "CHAOS GOAL NOT MET")


def print_tables(rows: list[dict[str, Any]]) -> None:
    print(f"{'hops':>4} {'loss':>5} {'delivery':>8} {'age mean':>9} {'age max':>8} "
          f"{'bound':>7} {'max/bound':>9} {'AoI mean':>9} {'commands d/f':>12} "
          f"{'relay/origin':>12}")
    for r in (r for r in rows if r["part"] == "hops"):
        print(f"{r['hops']:>4} {r['loss']:>5.0%} {r['delivery']:>8.1%} "
              f"{r['value_age_mean_s'] or 0:>8.1f}s {r['value_age_max_s'] or 0:>7.1f}s "
              f"{r['bound_s']:>6.1f}s {r['max_over_bound'] or 0:>9.2f} "
              f"{r['aoi_mean_s'] or 0:>8.1f}s {r['delivered']:>5}/{r['failed']:<6} "
              f"{r['relay_over_origin'] or 0:>12.2f}")
    print()
    print(f"{'crossing':>9} {'switch':>9} {'after':>7} {'down_after_s':>12} {'failback_s':>10}")
    for r in (r for r in rows if r["part"] == "failover"):
        after = "—" if r["after_s"] is None else f"{r['after_s']:.1f}s"
        print(f"{r['crossing_s']:>8.1f}s {r['switch']:>9} {after:>7} "
              f"{r['down_after_s']:>11g}s {r['failback_s']:>9g}s")
    print()
    print(f"{'loss':>5} {'kills':>5} {'failover min/mean/max':>22} {'failback min/mean/max':>22} "
          f"{'switches':>8} {'commands d/f/twice':>18} {'goal':>5}")
    for r in (r for r in rows if r["part"] == "reroute"):
        failed = sum(r["reported_failed"].values())
        print(f"{r['loss']:>5.0%} {r['kills']:>5} "
              f"{_spread_text(r['failover_s'], r['failovers']):>22} "
              f"{_spread_text(r['failback_s'], r['failbacks']):>22} {r['switches']:>8} "
              f"{r['reported_delivered']:>8}/{failed}/{r['duplicates']:<7} "
              f"{'met' if chaos.goal_met(r) else 'NOT':>5}")
    print("(failover from the kill, against down_after_s 45 s; failback from the restart, "
          "against failback_s 45 s)")
    print()
    print(json.dumps(next(r for r in rows if r["part"] == "chaos")))


def _spread_text(spread: list[float] | None, count: int) -> str:
    return "—" if spread is None else f"{'/'.join(f'{v:g}' for v in spread)} s ({count})"


if __name__ == "__main__":
    main()
