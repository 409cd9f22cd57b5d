"""Acknowledgements through a relay, measured: umci_relay's gotos (surface -> ROV1 -> ROV2).

ROV2 hears the surface's acoustic frames directly and takes a goto from them; its
acknowledgement goes back through ROV1, which keeps the surface's frame (custody) until it
hears that acknowledgement. For 30 virtual minutes, a goto every ``--every`` seconds, alone
or with the mission's own traffic (each ROV's status every 10 s, grip every 2 s), over several
seeds: the *ack delay* (from ROV2 publishing the goto to the surface's ``delivered`` report:
median, 90th percentile, worst, how many over 15 s, the acoustic cycle, and over 30 s), gotos
failed, the copies ROV1 sent again (custody), ROV2's duplicate frames dropped, and frames
dropped by a full relay queue.

``--base DIR``: also run the same with the code in ``DIR`` (a tree of ``bridge``), as "before".

Run: ``uv run python bench/ack_bench.py [--base /tmp/ack-base] [--seeds 6] [--every 20]``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
RUN_S = 1800.0
LOADS = ("gotos", "mission")


def one(seed: int, every: float, load: str, loss: float | None) -> dict[str, Any]:
    """One run in the code importable now: per goto its ack delay, and the run's counters."""
    from bridge.core.events import Delivery
    from bridge.core.loaded import load_mission
    from bridge.runtime.virtual_fleet import FastFleet

    fleet = FastFleet(load_mission(ROOT / "deploy" / "missions" / "umci_relay.yaml"), seed=seed,
                      loss=loss)
    puts = int((RUN_S - 120.0) / every)
    for i in range(puts):
        fleet.put("surface", "rov2/goto", {"x": i, "depth": 10}, at=5.0 + i * every, ref=str(i))
    if load == "mission":
        for i in range(int(RUN_S / 2)):
            for node in ("rov1", "rov2"):
                fleet.put(node, f"{node}/grip", {"force": i % 50}, at=1.37 + 2 * i)
                if i % 5 == 0:
                    fleet.put(node, f"{node}/status", {"x": i, "depth": 10, "battery": 90},
                              at=1.37 + 2 * i)
    fleet.run_until(RUN_S)
    took: dict[int, float] = {}
    for t, publish in fleet.published("rov2", "rov2/goto"):
        took.setdefault(round(publish.value["x"]), t)
    ends = {int(d.ref): (d.state, d.time) for t in fleet.outputs if t.node == "surface"
            and isinstance(d := t.output, Delivery) and d.state in ("delivered", "failed")}
    delays = [ends[i][1] - took[i] for i in took if ends.get(i, ("",))[0] == "delivered"]
    cores = fleet.cores
    custody = cores["rov1"].network.routing.custody  # type: ignore[union-attr]
    return {"delays": delays, "failed": sum(s == "failed" for s, _ in ends.values()),
            "resent": custody.resent, "duplicates": cores["rov2"].stats.frames_dropped[
                "duplicate"],
            "relay_full": sum(c.stats.frames_dropped["relay_full"] for c in cores.values())}


def measure(seeds: int, every: float, loss: float | None) -> list[dict[str, Any]]:
    """Each load over ``seeds`` seeds: the delays pooled, the counters per seed (mean)."""
    rows = []
    for load in LOADS:
        runs = [one(seed, every, load, loss) for seed in range(1, seeds + 1)]
        delays = sorted(d for r in runs for d in r["delays"])
        rows.append({"load": load, "acked": len(delays),
                     "median_s": statistics.median(delays) if delays else None,
                     "p90_s": delays[int(0.9 * (len(delays) - 1))] if delays else None,
                     "max_s": delays[-1] if delays else None,
                     "over_15s": sum(d > 15 for d in delays),
                     "over_30s": sum(d > 30 for d in delays),
                     **{k: statistics.mean(r[k] for r in runs)
                        for k in ("failed", "resent", "duplicates", "relay_full")}})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=6)
    parser.add_argument("--every", type=float, default=20.0, help="seconds between gotos")
    parser.add_argument("--loss", type=float, help="loss on every link (default: the "
                        "modems' own)")
    parser.add_argument("--base", type=Path, help="the code before, to run beside")
    parser.add_argument("--rows", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.rows:
        print(json.dumps(measure(args.seeds, args.every, args.loss)))
        return
    runs = {}
    for name, root in (("before", args.base), ("after", ROOT)):
        if root is None:
            continue
        out = subprocess.run([sys.executable, str(ROOT / "bench" / "ack_bench.py"), "--rows",
                              "--seeds", str(args.seeds), "--every", str(args.every),
                              *(["--loss", str(args.loss)] if args.loss is not None else [])],
                             cwd=root, check=True, capture_output=True, text=True,
                             env={**os.environ, "PYTHONPATH": str(root)}).stdout
        runs[name] = json.loads(out)
    print(f"{'':8}{'load':>8}{'acked':>7}{'median s':>10}{'p90 s':>7}{'max s':>7}"
          f"{'>15 s':>7}{'>30 s':>7}{'failed':>8}{'resent':>8}{'dups':>7}{'full':>6}")
    for i, load in enumerate(LOADS):
        for name, rows in runs.items():
            r = rows[i]
            fmt = lambda v: "-" if v is None else f"{v:.1f}"  # noqa: E731
            print(f"{name:8}{load:>8}{r['acked']:>7}{fmt(r['median_s']):>10}"
                  f"{fmt(r['p90_s']):>7}{fmt(r['max_s']):>7}{r['over_15s']:>7}{r['over_30s']:>7}"
                  f"{r['failed']:>8.1f}{r['resent']:>8.1f}{r['duplicates']:>7.1f}"
                  f"{r['relay_full']:>6.1f}")


if __name__ == "__main__":
    main()
