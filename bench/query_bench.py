"""Query round trip across the water against the MAC's bound (issue 15).

The example mission ``deploy/missions/zspace.yaml`` (a surface node and two AUVs, 48-byte
frames, EvoLogics timing) runs on the virtual clock, with a queryable on each AUV answering
``<auv>/info``. The surface gets one of them at random instants, one at a time, under two MACs:
the mission's TDMA (1 s slots, cycle 3 s) and polled (the surface polls every ``ipg_s``; a
query rides on a poll, the answer on the reply to it). Printed per MAC: the round trip from
the ``get`` to its answer (in seconds and in slots / poll gaps), against the deadline
``zab check`` derives from the MAC (the query ends with an error there).

Under loss (``--loss``, frame loss shares, default 0, 0.2 and 0.4, all in one run): the share of
gets answered completely within the deadline and their round trip, with requests repeated
until every reply arrived against the baseline measured in the same run (each request sent
once, ``Queries.repeats`` false).

Run: ``uv run python bench/query_bench.py [--queries 200] [--loss 0,0.2,0.4] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import random
import statistics
from typing import Any

import yaml

from bridge.core.loaded import LoadedMission, parse_mission
from bridge.core.queries import deadline_s
from bridge.runtime.virtual_fleet import FastFleet
from tests.conftest import MISSIONS

SEED = 11


def mission(mac: dict[str, Any] | None) -> LoadedMission:
    data = yaml.safe_load((MISSIONS / "zspace.yaml").read_text())
    if mac is not None:
        data["mac"] = mac
    return parse_mission(yaml.safe_dump(data, sort_keys=False), "zspace.yaml")


def run(loaded: LoadedMission, queries: int, unit_s: float, loss: float = 0.0,
        repeats: bool = True) -> dict[str, Any]:
    fleet = FastFleet(loaded, seed=SEED, loss=loss)
    for core in fleet.cores.values():
        if core.queries is not None:
            core.queries.repeats = repeats
    for auv in ("auv1", "auv2"):
        fleet.queries.queryable(auv, f"{auv}/info", lambda p: [
            {"depth_m": 10.0, "state": "survey", "detail": int(p.get("detail", 0))}])
    rng = random.Random(SEED)
    fleet.run_until(20.0)
    trips: list[float] = []
    errors = 0
    spec = loaded.table.queries[0]
    bound = max(deadline_s(loaded.mission, spec, "top", s) for s in spec.servers)
    for _ in range(queries):
        fleet.run_until(fleet.now + rng.uniform(0.0, 10.0))
        server = rng.choice(spec.servers)
        result = fleet.queries.get("top", f"{server}/info", {"detail": rng.randrange(4)})
        while not result.done:
            fleet.run_until(fleet.now + 0.5)
        if result.error is None and result.replies:
            trips.append(result.replies[-1][2] - result.asked_at)
        else:
            errors += 1
    top = fleet.cores["top"].queries
    return {"queries": queries, "answered": len(trips), "errors": errors,
            "success": round(len(trips) / queries, 3),
            "mean_s": round(statistics.fmean(trips), 3), "p95_s": round(
                statistics.quantiles(trips, n=20)[-1], 3), "max_s": round(max(trips), 3),
            "unit_s": unit_s, "mean_units": round(statistics.fmean(trips) / unit_s, 2),
            "max_units": round(max(trips) / unit_s, 2), "bound_s": bound,
            "bound_units": round(bound / unit_s, 2),
            "repeated": top.repeated if top is not None else 0}


MACS: dict[str, tuple[dict[str, Any] | None, float]] = {
    "tdma": (None, 1.0), "polled": ({"type": "polled", "master": "top", "ipg_s": 1.5}, 1.5)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--queries", type=int, default=200)
    parser.add_argument("--loss", default="0,0.2,0.4",
                        help="frame loss shares to run, comma separated")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    losses = [float(x) for x in args.loss.split(",") if x.strip()]
    out: dict[str, Any] = {}
    for mac, (spec, unit) in MACS.items():
        loaded = mission(spec)
        for loss in losses:
            out[f"{mac}@{loss:g}"] = {
                "once": run(loaded, args.queries, unit, loss, repeats=False),
                "repeated": run(loaded, args.queries, unit, loss, repeats=True)}
    if args.json:
        print(json.dumps(out, indent=2))
        return
    print(f"query round trip, {args.queries} gets at the surface, seed {SEED}; "
          "once = each request sent once (baseline), repeated = until every reply arrived")
    print(f"{'mac':<8} {'loss':>5} {'mode':<9} {'success':>8} {'mean s':>7} {'p95 s':>6} "
          f"{'max s':>6} {'mean slots':>11} {'max slots':>10} {'bound slots':>12} "
          f"{'repeats':>8}")
    for name, pair in out.items():
        mac, loss = name.split("@")
        for mode, r in pair.items():
            print(f"{mac:<8} {float(loss):>5.0%} {mode:<9} {r['success']:>8.1%} "
                  f"{r['mean_s']:>7} {r['p95_s']:>6} {r['max_s']:>6} {r['mean_units']:>11} "
                  f"{r['max_units']:>10} {r['bound_units']:>12} {r['repeated']:>8}")
        ratio = pair["repeated"]["success"] / pair["once"]["success"]
        print(f"{'':<8} {'':>5} {'ratio':<9} {ratio:>7.2f}x")
    print("slots: TDMA slot_s (1 s; cycle 3 slots) or the polled ipg_s (1.5 s; cycle 2 polls)")

if __name__ == "__main__":
    main()
