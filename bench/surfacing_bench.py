"""Surfacing switch-over times, up and down (issue 15).

The example mission ``deploy/missions/zspace.yaml`` runs in ``zab sim`` form (real Zenoh
sessions, the simulated ocean), with the surface ``top`` and ``auv1`` as Zenoh routers, as the
deploy kit runs them. A plain Zenoh router stands for the surface WiFi: opening it joins the
two (the vehicle surfaced), closing it parts them (the dive). An application at ``auv1`` keeps
its latched ``status`` fresh, one at ``top`` subscribes ``auv1/status``. Measured per cycle:

- up: from the WiFi joining to both bridges having switched (liveliness token seen), and to the
  first full-fidelity copy at ``top``;
- down: from the WiFi closing to both bridges having switched back, and to the first acoustic
  (quantised) value at ``top``, in seconds and in TDMA cycles (3 s).

Run: ``uv run python bench/surfacing_bench.py [--cycles 5] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import threading
import time
from typing import Any

import msgpack
import yaml
import zenoh

from bridge.core.events import Event, Surfaced
from bridge.core.loaded import parse_mission
from bridge.runtime.surface_wifi import access_point
from tests.conftest import MISSIONS, free_port
from tests.harness import outside_session, running_fleet

CYCLE_S = 3.0



def wait_for(condition: Any, timeout: float) -> float | None:
    end = time.time() + timeout
    while time.time() < end:
        if (t := condition()) is not None:
            return t
        time.sleep(0.01)
    return None


def first(got: list[tuple[float, dict]], since: float, full: bool) -> Any:
    """A condition: the first value after ``since`` that is full fidelity (a fractional
    battery, as published) or quantised (whole percent, as the channel carries it)."""
    return lambda: next((t for t, v in list(got)
                         if t > since and bool(v["battery"] % 1) is full), None)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=5)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    data = yaml.safe_load((MISSIONS / "zspace.yaml").read_text())
    for name, node in data["nodes"].items():
        node["zenoh"] = {"listen": [f"tcp/127.0.0.1:{free_port()}"]}
        if name in ("top", "auv1"):
            node["zenoh"].update({"mode": "router", "scouting/gossip/enabled": False,
                                  "scouting/delay": 0})
    loaded = parse_mission(yaml.safe_dump(data, sort_keys=False), "zspace.yaml")
    switched: dict[tuple[str, bool], float] = {}
    lock = threading.Lock()

    def on_event(node: str, event: Event) -> None:
        if isinstance(event, Surfaced):
            with lock:
                switched[(node, event.ip)] = time.time()

    rows: list[dict[str, float | None]] = []
    with running_fleet(loaded, on_event=on_event):
        auv1, top = outside_session(loaded, "auv1"), outside_session(loaded, "top")
        got: list[tuple[float, dict]] = []
        top.declare_subscriber("auv1/status", lambda s: got.append(
            (time.time(), msgpack.unpackb(s.payload.to_bytes()))))
        stop = threading.Event()

        def publish() -> None:
            n = 0
            while not stop.is_set():
                n += 1
                auv1.put("auv1/status", msgpack.packb({"battery": 50 + (n % 40) + 0.3,
                                                  "mode": "survey"}),
                         encoding=zenoh.Encoding("application/msgpack"))
                stop.wait(0.5)

        feeder = threading.Thread(target=publish, daemon=True)
        feeder.start()
        try:
            wait_for(lambda: got[-1][0] if got else None, 15)
            for _ in range(args.cycles):
                switched.clear()
                joined = time.time()
                wifi = access_point(loaded.mission.nodes["top"].zenoh.listen
                              + loaded.mission.nodes["auv1"].zenoh.listen)
                both_up = wait_for(lambda: max(switched[(n, True)] for n in ("top", "auv1"))
                                   if all((n, True) in switched for n in ("top", "auv1"))
                                   else None, 15)
                full = wait_for(first(got, both_up or joined, full=True), 5)
                time.sleep(CYCLE_S)
                parted = time.time()
                wifi.close()
                both_down = wait_for(lambda: max(switched[(n, False)] for n in ("top", "auv1"))
                                     if all((n, False) in switched for n in ("top", "auv1"))
                                     else None, 15)
                acoustic = wait_for(first(got, parted, full=False), 20)
                rows.append({
                    "up_switch_s": None if both_up is None else both_up - joined,
                    "up_first_full_fidelity_s": None if full is None else full - joined,
                    "down_switch_s": None if both_down is None else both_down - parted,
                    "down_first_acoustic_s": None if acoustic is None else acoustic - parted,
                })
                time.sleep(CYCLE_S)
        finally:
            stop.set()
            feeder.join(2)
            auv1.close()
            top.close()

    def summary(key: str) -> dict[str, float | None]:
        values = [r[key] for r in rows if r[key] is not None]
        if not values:
            return {"mean_s": None, "max_s": None, "missing": len(rows)}
        return {"mean_s": round(statistics.fmean(values), 3), "max_s": round(max(values), 3),
                "max_cycles": round(max(values) / CYCLE_S, 2), "missing": len(rows) - len(values)}

    out = {key: summary(key) for key in rows[0]} if rows else {}
    if args.json:
        print(json.dumps({"cycles": args.cycles, "summary": out, "runs": rows}, indent=2))
        return
    print(f"surfacing switch-over, {args.cycles} surface/dive cycles (TDMA cycle {CYCLE_S} s)")
    for key, s in out.items():
        print(f"  {key:<26} mean {s['mean_s']} s, max {s['max_s']} s "
              f"({s.get('max_cycles')} cycles), missing {s['missing']}")


if __name__ == "__main__":
    main()
