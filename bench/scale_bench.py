"""Scale and cost: many nodes × many channels, in ``zab sim`` and on the virtual clock.

A generated mission: ``--nodes`` vehicles on EvoLogics S2C timings (64-byte frames) within
a few hundred metres, static TDMA (one 1 s slot each), ``--channels`` channels spread over the
nodes (each node sends its share to every other node; a few fields, every slot or every few
seconds). Acoustic addresses stop at 254, so at most 254 nodes. Measured:

1. The virtual clock, as a sweep over every ``--nodes`` × ``--channels``: the whole
   ``zab sim MISSION --fast --duration D`` process (start-up, simulation, printed report) run
   ``--repeat`` times; printed: the median wall time, the speed-up (virtual seconds per wall
   second, whole process and simulation alone as the report gives it), CPU seconds, and µs
   of simulation per received frame, which should stay flat as the fleet grows.
   ``--against DIR [DIR ...]`` also runs source trees of other versions (e.g. ``git archive``
   of an older commit) on the same missions, interleaved run by run, so all see the same load.
   Each tree's compiled modules are cached outside it (``PYTHONPYCACHEPREFIX``) by an untimed
   run first, as an installed package has them: with ``PYTHONDONTWRITEBYTECODE`` set (as on the
   shared VM) every run would otherwise compile the package again (~0.75 s CPU of each
   process); ``--compile-every-run`` measures that way.
2. With ``--zenoh`` (one node count): ``zab sim`` (the real command: every node's Zenoh peer,
   bridge and modem, plus the water, in one process) run as a subprocess; its CPU time and
   resident memory read from ``/proc`` during an idle window (nobody publishes) and a loaded
   window (one application per node publishing each of its input keys ``--rate`` times a
   second). Per node = process / nodes; the marginal memory per node comes from the same run
   with 2 nodes. Frame rates come from the nodes' own ``@zab/<mission>/<node>/stats``.

Targets: virtual clock ≥ 500× real time at 64 × 64 (simulation) and ≥ 100× at 250 × 64
(whole process);
≤ 80 MB resident and ≤ 2 % of one core per idle node. The machine may be shared: the load
average is printed with the results, and medians are quoted.

Run: ``uv run python bench/scale_bench.py [--nodes 16 32 64 250] [--channels 64]
[--duration 600] [--repeat 3] [--against DIR ...] [--zenoh [--idle 20] [--loaded 20] [--rate 1]]``.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import socket
import statistics
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

TICK = os.sysconf("SC_CLK_TCK")
SLOT_S = 1.0
TARGET_RSS_MB, TARGET_CPU_PCT = 80.0, 2.0
TARGET_SPEEDUP = {(64, 64): ("sim_speedup", 500.0), (250, 64): ("speedup", 100.0)}
"""(nodes, channels): (which speed-up, × real time): the simulation's own at 64 × 64 (as in
issue #14's 452× / 202× / 130× at 16 / 32 / 64 nodes), the whole process at 250 × 64."""


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


@dataclass
class FastRun:
    """One whole ``zab sim --fast`` process and what its closing line says."""

    wall_s: float
    cpu_s: float
    sim_s: float  # the simulation alone, as the command reports it
    received: int


CLOSING = re.compile(r"simulated in ([0-9.]+) s wall .*?(\d+) frames sent, (\d+) received")


def run_fast_process(mission: Path, duration: float, tree: Path | None,
                     pycache: Path | None = None) -> FastRun:
    """``zab sim MISSION --fast --duration D`` as a subprocess (from source tree ``tree``, or
    this one), timed whole; simulation time and frames from its closing line. ``pycache``:
    compiled modules are kept there (``PYTHONPYCACHEPREFIX``, the trees untouched) and read
    back by later runs, as an installed package's are."""
    env = dict(os.environ)
    if tree is not None:
        env["PYTHONPATH"] = str(tree)
    if pycache is not None:
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        env["PYTHONPYCACHEPREFIX"] = str(pycache)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "bridge", "sim", str(mission), "--fast",
                           "--duration", str(duration)], check=True, env=env,
                          cwd=tree or Path.cwd(), capture_output=True, text=True)
    wall = time.perf_counter() - started
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    closing = CLOSING.search(" ".join(done.stdout.split()))
    if closing is None:
        raise RuntimeError(f"no closing line from zab sim --fast:\n{done.stdout[-2000:]}")
    return FastRun(wall, cpu, float(closing.group(1)), int(closing.group(3)))


def summarize(runs: list[FastRun], duration: float) -> dict[str, float]:
    """Medians over the runs: whole-process wall, CPU and speed-up, the simulation's own
    speed-up, and µs of simulation per received frame."""
    wall = statistics.median(r.wall_s for r in runs)
    sim = statistics.median(r.sim_s for r in runs)
    received = runs[0].received
    return {"wall_s": wall, "cpu_s": statistics.median(r.cpu_s for r in runs),
            "speedup": duration / wall, "sim_speedup": duration / sim,
            "us_per_rx": 1e6 * sim / received if received else float("nan"),
            "received": received}


def sweep(nodes: list[int], channels: list[int], duration: float, repeat: int,
          against: list[Path], cached: bool = True) -> None:
    """The virtual-clock sweep (see the module docstring), printed as one table. ``cached``:
    every tree's compiled modules are cached (outside the trees) by one run before those
    timed, as an installed package's are; else whatever the environment does."""
    trees: list[tuple[str, Path | None]] = [("this", None)]
    trees += [(tree.name, tree.resolve()) for tree in against]
    print(f"virtual clock: zab sim MISSION --fast --duration {duration:g}, whole process, "
          f"median of {repeat}; load average before: {os.getloadavg()[0]:.2f} (2 cores, shared)")
    if cached:
        print("compiled modules cached outside the trees (PYTHONPYCACHEPREFIX) by an untimed "
              "run of each tree first, as an installed package has them; "
              "--compile-every-run: as the environment says")
    elif os.environ.get("PYTHONDONTWRITEBYTECODE"):
        print("PYTHONDONTWRITEBYTECODE is set: modules without a cached .pyc are compiled at "
              "every run (up to ~0.4 s of start-up that an installed package does not pay)")
    print(f"{'tree':<10} {'nodes':>5} {'chan':>5} {'wall s':>7} {'cpu s':>6} {'× real':>7} "
          f"{'× (sim)':>8} {'µs/rx':>6} {'rx':>8}  target")
    with tempfile.TemporaryDirectory() as tmp:
        pycache = Path(tmp) / "pycache" if cached else None
        warm: set[str] = set()
        for n in nodes:
            for c in channels:
                mission = Path(tmp) / f"scale-{n}x{c}.yaml"
                mission.write_text(yaml.safe_dump(mission_data(n, c), sort_keys=False))
                runs: dict[str, list[FastRun]] = {name: [] for name, _ in trees}
                for name, tree in trees:  # (the first run of a tree compiles its modules)
                    if pycache is not None and name not in warm:
                        warm.add(name)
                        run_fast_process(mission, 1.0, tree, pycache / name)
                for _ in range(repeat):  # interleaved: every tree sees the same load
                    for name, tree in trees:
                        runs[name].append(run_fast_process(
                            mission, duration, tree, None if pycache is None else pycache / name))
                for name, _ in trees:
                    m = summarize(runs[name], duration)
                    target = TARGET_SPEEDUP.get((n, c))
                    goal = "" if target is None else \
                        f"{target[0]} {verdict(m[target[0]], target[1], False)}"
                    print(f"{name:<10} {n:5d} {c:5d} {m['wall_s']:7.2f} {m['cpu_s']:6.2f} "
                          f"{m['speedup']:7.1f} {m['sim_speedup']:8.1f} {m['us_per_rx']:6.1f} "
                          f"{m['received']:8d}  {goal}", flush=True)
    print(f"load average after: {os.getloadavg()[0]:.2f}")


def verdict(value: float, target: float, at_most: bool) -> str:
    ok = value <= target if at_most else value >= target
    return f"{'meets' if ok else 'MISSES'} {'≤' if at_most else '≥'} {target:g}"


def zenoh_part(nodes: int, channels: int, idle_s: float, loaded_s: float, rate: float) -> None:
    """``zab sim`` with Zenoh: CPU and memory per node, idle and loaded (module docstring)."""
    data = mission_data(nodes, channels)
    print(f"{nodes} nodes × {channels} channels, TDMA {nodes} × {SLOT_S:g} s, "
          f"evologics-s2c-im; load average before: {os.getloadavg()[0]:.2f}")
    big = measure_zab_sim(data, idle_s, loaded_s, rate)
    small = measure_zab_sim(mission_data(2, 2 * channels // nodes), idle_s / 2, 1.0, rate)
    marginal = (big["idle"]["rss_mb"] - small["idle"]["rss_mb"]) / (nodes - 2)
    idle, loaded = big["idle"], big["loaded"]
    print(f"\nzab sim (one process, {nodes} Zenoh peers + bridges + water), "
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
          f"({verdict(idle['rss_mb_per_node'], TARGET_RSS_MB, True)})\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--nodes", type=int, nargs="+", default=[16, 32, 64, 250],
                        help="fleet sizes to sweep (2..254)")
    parser.add_argument("--channels", type=int, nargs="+", default=[64])
    parser.add_argument("--duration", type=float, default=600.0,
                        help="virtual seconds per run")
    parser.add_argument("--repeat", type=int, default=3, help="runs per point (median)")
    parser.add_argument("--against", type=Path, nargs="+", default=[],
                        help="other source trees to run side by side (e.g. git archive)")
    parser.add_argument("--compile-every-run", action="store_true",
                        help="no bytecode cache: with PYTHONDONTWRITEBYTECODE set, each run "
                             "compiles every module of the tree again")
    parser.add_argument("--zenoh", action="store_true",
                        help="also measure zab sim with Zenoh (first --nodes value)")
    parser.add_argument("--idle", type=float, default=20.0, help="idle window, seconds")
    parser.add_argument("--loaded", type=float, default=20.0, help="loaded window, seconds")
    parser.add_argument("--rate", type=float, default=1.0, help="puts per key per second")
    args = parser.parse_args()
    if not all(2 <= n <= 254 for n in args.nodes):
        parser.error("--nodes: 2..254 (acoustic addresses stop at 254)")
    if args.zenoh:
        zenoh_part(args.nodes[0], args.channels[0], args.idle, args.loaded, args.rate)
    sweep(args.nodes, args.channels, args.duration, args.repeat, args.against,
          cached=not args.compile_every_run)


if __name__ == "__main__":
    main()
