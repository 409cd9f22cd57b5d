"""Airtime saved by demand-driven sending on the MORPH mission (issue 15).

The MORPH fleet (``deploy/missions/morph.yaml``: five nodes, static TDMA, 64-byte frames) runs on
the virtual clock with synthetic applications publishing every input key (as ``zab sim --fast``
does), three ways, same seed:

- ``baseline``: the mission as it is: every channel is sent;
- ``demand_all``: ``demand`` on, every output subscribed at every receiver (the cost of the
  ``@want`` bitmaps alone);
- ``half_pairs``: ``demand`` on, half of the outputs subscribed: the (receiver, channel) pairs
  in mission order, every other one;
- ``half_channels``: ``demand`` on, the outputs of every other channel (0, 2, 4) subscribed at
  every receiver, the others at none.

The bridges' own inputs stay subscribed as in Zenoh (the anchors' ``gcv/nav`` keeps ``nav``
wanted). Both variants of MORPH run: as it is (DLBL delays in every frame) and without DLBL. A
slot whose node has nothing wanted still carries a frame when the link's heartbeat is due, so
the saving shows mostly in bytes and airtime, not in frames.

Printed per run: frames, bytes and airtime sent (the preset's airtime per frame), values
delivered, and the ratio against the baseline. A channel is wanted per receiver, not per sender:
a broadcast channel that one receiver wants still goes out.

Run: ``uv run python bench/demand_bench.py [--duration 1800] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import random
from typing import Any

import yaml

from bridge.cli.sim_fast import feed
from bridge.core.events import FrameSent
from bridge.core.interest import output_keys
from bridge.core.loaded import LoadedMission, parse_mission
from bridge.core.positioning import simulated_preset
from bridge.runtime.virtual_fleet import FastFleet, Timed
from bridge.wire.frame import FrameCodec
from tests.conftest import MISSIONS

SEED = 7


def morph(demand: bool, dlbl: bool = True) -> LoadedMission:
    data = yaml.safe_load((MISSIONS / "morph.yaml").read_text())
    data["wire"]["dlbl"] = dlbl
    if demand:
        data["demand"] = {"refresh_s": 60}
    return parse_mission(yaml.safe_dump(data, sort_keys=False), "morph.yaml")


def half_of_the_outputs(loaded: LoadedMission) -> dict[str, list[str]]:
    """Every other (receiver, channel) pair's output keys, in mission order."""
    pairs = [(node, index, keys) for node in loaded.mission.nodes
             for index, keys in sorted(output_keys(loaded.table, node).items())]
    subscribed: dict[str, list[str]] = {}
    for node, _, keys in pairs[::2]:
        subscribed.setdefault(node, []).extend(sorted(keys))
    return subscribed


def half_of_the_channels(loaded: LoadedMission) -> dict[str, list[str]]:
    """The outputs of every other channel (indices 0, 2, 4, …) at every receiver."""
    return {node: sorted(k for index, keys in output_keys(loaded.table, node).items()
                         if index % 2 == 0 for k in keys)
            for node in loaded.mission.nodes}


def run(loaded: LoadedMission, duration: float,
        subscriptions: dict[str, list[str]] | None) -> dict[str, Any]:
    preset = simulated_preset(loaded.mission)
    totals = {"frames": 0, "bytes": 0, "airtime_s": 0.0, "channel_bits": 0}
    cost = {c.name: FrameCodec(loaded.table).channel_cost_bits(c) for c in loaded.table.wire}

    def on_output(timed: Timed) -> None:
        out = timed.output
        if isinstance(out, FrameSent):
            totals["frames"] += 1
            totals["bytes"] += out.size
            totals["airtime_s"] += preset.airtime(out.size) if preset else 0.0
            totals["channel_bits"] += sum(cost[name] for name in out.channels)

    fleet = FastFleet(loaded, seed=SEED, on_output=on_output, keep_outputs=False)
    for node, keys in (subscriptions or {}).items():
        for key in keys:
            fleet.subscribe(node, key)
    feed(fleet, random.Random(f"feed/{SEED}"), duration)
    fleet.run_until(duration)
    cores = fleet.cores.values()
    sent = {c.name: sum(core.stats.sent_per_channel[c.name] for core in cores)
            for c in loaded.table.channels}
    return {**totals, "airtime_s": round(totals["airtime_s"], 1),
            "values_sent": sent,
            "values_delivered": sum(core.stats.values_published for core in cores)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=1800.0, help="virtual seconds")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    out: dict[str, Any] = {"duration_s": args.duration, "seed": SEED}
    for dlbl in (True, False):
        base = run(morph(False, dlbl), args.duration, None)
        demand = morph(True, dlbl)
        everything = {n: ["**"] for n in demand.mission.nodes}
        runs = {"baseline": base,
                "demand_all": run(demand, args.duration, everything),
                "half_pairs": run(demand, args.duration, half_of_the_outputs(demand)),
                "half_channels": run(demand, args.duration, half_of_the_channels(demand))}
        for r in runs.values():
            r["ratio_to_baseline"] = {k: round(r[k] / base[k], 3) if base[k] else None
                                      for k in ("frames", "bytes", "airtime_s", "channel_bits")}
        out["morph" if dlbl else "morph_without_dlbl"] = runs
    if args.json:
        print(json.dumps(out, indent=2))
        return
    keys = ("frames", "bytes", "airtime_s", "channel_bits")
    for variant in ("morph", "morph_without_dlbl"):
        runs = out[variant]
        print(f"{variant}: {args.duration:.0f} virtual s, seed {SEED}")
        print(f"  {'run':<14}" + "".join(f" {k:>12}" for k in keys)
              + "".join(f" {'× ' + k:>14}" for k in keys))
        for name, r in runs.items():
            print(f"  {name:<14}" + "".join(f" {r[k]:>12}" for k in keys)
                  + "".join(f" {r['ratio_to_baseline'][k]:>14}" for k in keys))
        print("  values sent: " + "; ".join(
            f"{c} " + "/".join(str(r["values_sent"][c]) for r in runs.values())
            for c in runs["baseline"]["values_sent"]) + " (" + "/".join(runs) + ")")


if __name__ == "__main__":
    main()
