"""Scale and cost: 16 nodes × 64 channels in one ``zab sim``, and an hour on the virtual clock.

A generated mission: ``--nodes`` vehicles on EvoLogics S2C timings (64-byte frames) within
a few hundred metres, static TDMA (one 1 s slot each), ``--channels`` channels spread over the
nodes (each node sends its share to every other node; a few fields, every slot or every few
seconds). Measured:

1. ``zab sim`` (the real command: every node's Zenoh peer, bridge and modem, plus the water,
   in one process) run as a subprocess; its CPU time and resident memory read from ``/proc``
   during an idle window (nobody publishes) and a loaded window (one application per node
   publishing each of its input keys ``--rate`` times a second). Per node = process / nodes;
   the marginal memory per node comes from the same run with 2 nodes. Frame rates come from
   the nodes' own ``@zab/<mission>/<node>/stats``.
2. The same mission for ``--hours`` on the virtual clock (``zab sim --fast``: every core over
   the pure ocean, synthetic inputs): how many times faster than real time, frames per wall
   second.

Targets: ≤ 80 MB resident and ≤ 2 % of one core per idle node; ≥ 50× real time.
The machine may be shared: the load average is printed with the results.

Run: ``uv run python bench/scale_bench.py [--nodes 16] [--channels 64] [--idle 20]
[--loaded 20] [--rate 1] [--hours 1]``.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgpack
import yaml
import zenoh

from bridge.cli.sim_fast import run_fast
from bridge.mission.loader import parse_mission

TICK = os.sysconf("SC_CLK_TCK")
SLOT_S = 1.0
TARGET_RSS_MB, TARGET_CPU_PCT, TARGET_SPEEDUP = 80.0, 2.0, 50.0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def node_name(i: int) -> str:
    return f"n{i:02d}"


def mission_data(nodes: int, channels: int) -> dict[str, Any]:
    """The generated mission (see the module docstring)."""
    names = [node_name(i) for i in range(nodes)]
    intervals = (0.0, 2.0, 5.0, 10.0)
    return {
        "mission": "scale",
        "modem": {"backend": "sim", "frame_bytes": 64,
                  "options": {"preset": "evologics-s2c-im", "seed": 1}},
        "mac": {"type": "tdma", "slot_s": SLOT_S, "guard_s": 0.05, "order": names},
        "link": {"heartbeat_s": 60},
        "nodes": {
            name: {"address": i + 1, "role": "surface" if i == 0 else "submerged",
                   "zenoh": {"listen": [f"tcp/127.0.0.1:{free_port()}"]},
                   "position": {"x": 40.0 * (i % 4), "y": 40.0 * (i // 4), "depth": 5.0 + i}}
            for i, name in enumerate(names)
        },
        "channels": [
            {"name": f"c{k:02d}", "from": names[k % nodes], "to": ".*",
             "interval_s": intervals[(k // nodes) % len(intervals)],
             "elements": [{"in": f"data/c{k:02d}", "out": f"{names[k % nodes]}/c{k:02d}",
                           "fields": [{"field": "x", "resolution": 0.1, "min": -500, "max": 500},
                                      {"field": "y", "resolution": 0.1, "min": -500, "max": 500},
                                      {"field": "ok", "type": "bool"}]}]}
            for k in range(channels)
        ],
    }


@dataclass
class Sample:
    """CPU seconds (user + system) and resident memory of a process at a wall time."""

    wall: float
    cpu_s: float
    rss_mb: float


def sample(pid: int) -> Sample:
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    cpu = (int(fields[11]) + int(fields[12])) / TICK  # utime, stime
    rss = 0.0
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                rss = int(line.split()[1]) / 1024
    return Sample(time.time(), cpu, rss)


class Stats:
    """The latest ``@zab/<mission>/<node>/stats`` of every node."""

    def __init__(self) -> None:
        self.latest: dict[str, dict[str, Any]] = {}

    def __call__(self, s: zenoh.Sample) -> None:
        value = msgpack.unpackb(s.payload.to_bytes())
        self.latest[value["node"]] = value

    def frames(self) -> tuple[int, int]:
        return (sum(v["frames_sent"] for v in self.latest.values()),
                sum(v["frames_received"] for v in self.latest.values()))


def client(endpoint: list[str]) -> zenoh.Session:
    config = zenoh.Config()
    config.insert_json5("mode", '"client"')
    config.insert_json5("connect/endpoints", json.dumps(endpoint))
    config.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(config)


def wait_listening(ports: list[int], proc: subprocess.Popen, timeout: float = 60.0) -> None:
    deadline = time.time() + timeout
    for port in ports:
        while True:
            if proc.poll() is not None:
                raise RuntimeError(f"zab sim ended early: {proc.stderr.read()}")  # type: ignore[union-attr]
            with socket.socket() as s:
                if s.connect_ex(("127.0.0.1", port)) == 0:
                    break
            if time.time() > deadline:
                raise RuntimeError("the fleet did not start")
            time.sleep(0.2)


def measure_zab_sim(data: dict[str, Any], idle_s: float, loaded_s: float,
                    rate: float) -> dict[str, Any]:
    """Run ``zab sim`` on the mission; CPU/RSS and frame rates while idle, then loaded."""
    names = list(data["nodes"])
    endpoints = {n: data["nodes"][n]["zenoh"]["listen"] for n in names}
    ports = [int(e[0].rsplit(":", 1)[1]) for e in endpoints.values()]
    keys = {n: [c["elements"][0]["in"] for c in data["channels"] if c["from"] == n]
            for n in names}
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "scale.yaml"
        path.write_text(yaml.safe_dump(data, sort_keys=False))
        total = idle_s + loaded_s + 10.0
        proc = subprocess.Popen(
            [sys.executable, "-m", "bridge", "sim", str(path), "--duration", str(total),
             "--no-live"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        sessions: list[zenoh.Session] = []
        try:
            started = time.time()
            wait_listening(ports, proc)
            startup_s = time.time() - started
            # one application per node (the nodes are separate Zenoh islands, as at sea);
            # it watches its node's stats all along and publishes only in the loaded window
            stats = Stats()
            apps = {n: client(endpoints[n]) for n in names}
            sessions.extend(apps.values())
            for n, app in apps.items():
                app.declare_subscriber(f"@zab/scale/{n}/stats", stats)
            time.sleep(3.0)  # let every session settle and report once
            a, frames_a = sample(proc.pid), stats.frames()
            time.sleep(idle_s)
            b, frames_b = sample(proc.pid), stats.frames()
            period, t_next, puts = 1.0 / rate, time.time(), 0
            end = time.time() + loaded_s
            rss_peak = b.rss_mb
            while time.time() < end:
                for n, app in apps.items():
                    for key in keys[n]:
                        value = {"x": (puts % 1000) / 10.0, "y": -1.5, "ok": puts % 2 == 0}
                        app.put(key, msgpack.packb(value),
                                encoding=zenoh.Encoding("application/msgpack"))
                        puts += 1
                t_next += period
                time.sleep(max(0.0, t_next - time.time()))
                rss_peak = max(rss_peak, sample(proc.pid).rss_mb)
            c, frames_c = sample(proc.pid), stats.frames()
        finally:
            for s in sessions:
                s.close()
            proc.terminate()
            proc.wait(30)
    n = len(names)

    def window(x: Sample, y: Sample, fx: tuple[int, int], fy: tuple[int, int]) -> dict:
        wall = y.wall - x.wall
        return {"seconds": round(wall, 1),
                "cpu_pct_per_node": round(100 * (y.cpu_s - x.cpu_s) / wall / n, 2),
                "rss_mb_per_node": round(y.rss_mb / n, 1),
                "rss_mb": round(y.rss_mb, 1),
                "frames_sent_per_s": round((fy[0] - fx[0]) / wall, 2),
                "frames_received_per_s": round((fy[1] - fx[1]) / wall, 2)}

    loaded = window(b, c, frames_b, frames_c)
    loaded["rss_mb_peak"] = round(rss_peak, 1)
    loaded["puts_per_s"] = round(puts / loaded_s, 1)
    return {"nodes": n, "startup_s": round(startup_s, 1),
            "idle": window(a, b, frames_a, frames_b), "loaded": loaded}


def measure_fast(data: dict[str, Any], hours: float) -> dict[str, Any]:
    loaded = parse_mission(yaml.safe_dump(data, sort_keys=False), "scale.yaml")
    report = asyncio.run(run_fast(loaded, duration=3600.0 * hours, seed=1))
    return {key: report[key] for key in ("duration_s", "wall_s", "speedup", "frames_sent",
                                         "frames_received", "frames_per_wall_s")}


def verdict(value: float, target: float, at_most: bool) -> str:
    ok = value <= target if at_most else value >= target
    return f"{'meets' if ok else 'MISSES'} {'≤' if at_most else '≥'} {target:g}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--nodes", type=int, default=16)
    parser.add_argument("--channels", type=int, default=64)
    parser.add_argument("--idle", type=float, default=20.0, help="idle window, seconds")
    parser.add_argument("--loaded", type=float, default=20.0, help="loaded window, seconds")
    parser.add_argument("--rate", type=float, default=1.0, help="puts per key per second")
    parser.add_argument("--hours", type=float, default=1.0, help="virtual-clock mission")
    args = parser.parse_args()
    data = mission_data(args.nodes, args.channels)
    print(f"{args.nodes} nodes × {args.channels} channels, TDMA {args.nodes} × {SLOT_S:g} s, "
          f"evologics-s2c-im; load average before: {os.getloadavg()[0]:.2f}")
    big = measure_zab_sim(data, args.idle, args.loaded, args.rate)
    small = measure_zab_sim(mission_data(2, 2 * args.channels // args.nodes), args.idle / 2,
                            1.0, args.rate)
    marginal = (big["idle"]["rss_mb"] - small["idle"]["rss_mb"]) / (args.nodes - 2)
    idle, loaded = big["idle"], big["loaded"]
    print(f"\nzab sim (one process, {args.nodes} Zenoh peers + bridges + water), "
          f"started in {big['startup_s']} s")
    print(f"{'window':<8} {'s':>5} {'CPU %/node':>11} {'RSS MB/node':>12} {'RSS MB':>8} "
          f"{'frames tx/s':>12} {'frames rx/s':>12}")
    for name, w in (("idle", idle), ("loaded", loaded)):
        print(f"{name:<8} {w['seconds']:5.1f} {w['cpu_pct_per_node']:11.2f} "
              f"{w['rss_mb_per_node']:12.1f} {w['rss_mb']:8.1f} {w['frames_sent_per_s']:12.2f} "
              f"{w['frames_received_per_s']:12.2f}")
    print(f"loaded: {loaded['puts_per_s']} application puts/s; peak RSS {loaded['rss_mb_peak']} MB")
    print(f"2-node run: {small['idle']['rss_mb']} MB → marginal RSS per extra node "
          f"{marginal:.1f} MB; idle CPU {small['idle']['cpu_pct_per_node']} %/node")
    print(f"idle node: CPU {idle['cpu_pct_per_node']} % of a core "
          f"({verdict(idle['cpu_pct_per_node'], TARGET_CPU_PCT, True)}), "
          f"RSS {idle['rss_mb_per_node']} MB per node, {marginal:.1f} MB marginal "
          f"({verdict(idle['rss_mb_per_node'], TARGET_RSS_MB, True)})")
    fast = measure_fast(data, args.hours)
    print(f"\nvirtual clock: {fast['duration_s']:g} s of mission in {fast['wall_s']} s wall = "
          f"{fast['speedup']:g}× real time ({verdict(fast['speedup'], TARGET_SPEEDUP, False)}); "
          f"{fast['frames_sent']} frames sent, {fast['frames_received']} received, "
          f"{fast['frames_per_wall_s']:g} frames handled per wall second")
    print(f"load average after: {os.getloadavg()[0]:.2f} (2 cores, shared)")


if __name__ == "__main__":
    main()
