"""Per-hop retransmission at relays, measured (bridge.core.custody).

acoustic_line with its reliable channel from the head to n1, n2 or tail (1, 2 or 3 hops), a
value every 15 s for 30 virtual minutes, then 20 more (``tests/core/reliable/test_relay_loss.py``'s
run), at 10 and 20 % loss a hop, over six seeds: values delivered (of 120, mean over seeds),
refused by a full queue, and the latency's median and 90th percentile (over every value of
every seed), with the relays' copies sent again.

``--base DIR``: also run the same with the code in ``DIR`` (a tree of ``bridge`` and
``tests``, e.g. ``git archive HEAD bridge tests | tar -x -C DIR``), as "before".

Run: ``uv run python bench/hop_bench.py [--base /tmp/hop-base] [--seeds 6]``.
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
CASES = [("n1", 0.1), ("n1", 0.2), ("n2", 0.1), ("n2", 0.2), ("tail", 0.1), ("tail", 0.2)]
HOPS = {"n1": 1, "n2": 2, "tail": 3}


def measure(seeds: int) -> list[dict[str, Any]]:
    """Every case in the code importable now (this process's ``sys.path``)."""
    from bridge.core.events import Delivery
    from bridge.runtime.virtual_fleet import FastFleet
    from tests.core.reliable.test_relay_loss import EVERY_S, PUTS, line_to

    rows = []
    for dest, loss in CASES:
        delivered, refused, resent, latency = [], 0, 0, []
        for seed in range(1, seeds + 1):
            fleet = FastFleet(line_to(dest), seed=seed, loss=loss)
            for i in range(PUTS):
                fleet.put("head", f"{dest}/abort", {"n": i}, at=5.0 + i * EVERY_S)
            fleet.run_until(5.0 + PUTS * EVERY_S + 1200.0)
            arrived: dict[int, float] = {}
            for t, publish in fleet.published(dest, f"{dest}/abort"):
                arrived.setdefault(publish.value["n"], t)
            delivered.append(len(arrived))
            latency += [t - (5.0 + i * EVERY_S) for i, t in arrived.items()]
            refused += sum(1 for t in fleet.outputs if isinstance(t.output, Delivery)
                           and t.output.state == "failed" and t.output.attempts == 0)
            for core in fleet.cores.values():
                custody = getattr(getattr(core.network, "routing", None), "custody", None)
                resent += custody.resent if custody is not None else 0
        latency.sort()
        rows.append({"hops": HOPS[dest], "loss": loss, "delivered": statistics.mean(delivered),
                     "worst_seed": min(delivered), "refused": refused / seeds,
                     "median_s": statistics.median(latency) if latency else None,
                     "p90_s": latency[int(0.9 * (len(latency) - 1))] if latency else None,
                     "resent": resent / seeds})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=6)
    parser.add_argument("--base", type=Path, help="the code before, to run beside")
    parser.add_argument("--rows", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.rows:
        print(json.dumps(measure(args.seeds)))
        return
    runs = {}
    for name, root in (("before", args.base), ("after", ROOT)):
        if root is None:
            continue
        out = subprocess.run([sys.executable, str(ROOT / "bench" / "hop_bench.py"), "--rows",
                              "--seeds", str(args.seeds)], cwd=root, check=True,
                             capture_output=True, text=True,
                             env={**os.environ, "PYTHONPATH": str(root)}).stdout
        runs[name] = json.loads(out)
    print(f"{'':8}{'hops':>5}{'loss':>6}{'delivered':>11}{'worst':>7}{'refused':>9}"
          f"{'median s':>10}{'p90 s':>8}{'resent':>8}")
    for i, (dest, loss) in enumerate(CASES):
        for name, rows in runs.items():
            r = rows[i]
            fmt = lambda v: "-" if v is None else f"{v:.0f}"  # noqa: E731
            print(f"{name:8}{HOPS[dest]:>5}{loss:>6.0%}{r['delivered']:>11.1f}"
                  f"{r['worst_seed']:>7}{r['refused']:>9.1f}{fmt(r['median_s']):>10}"
                  f"{fmt(r['p90_s']):>8}{r['resent']:>8.1f}")


if __name__ == "__main__":
    main()
