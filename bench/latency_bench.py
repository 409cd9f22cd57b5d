"""Latency the bridge adds: put at one node → sample at another, against plain Zenoh.

Three paths are measured side by side in one run, each tick putting once on each, a third
of a tick apart and in rotating order (so load falls on all three alike and they never
overlap), with the send time (CLOCK_MONOTONIC ns, shared by all processes) inside the payload:

- direct: an application puts on a Zenoh peer in another process, whose own subscriber
  samples it (one Zenoh hop);
- relayed: an application puts on that peer and another application, a client of the same
  peer, samples it (two Zenoh hops: the bridged path's Zenoh hops, without the water);
- bridged: an application puts on node ``a``'s endpoint; ``zab sim`` (another process) carries
  it over the ``udp`` backend with ``mac: none`` to node ``b``; an application at ``b`` samples.

Run: ``uv run python bench/latency_bench.py [--count 2000] [--rate 100]``.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import msgpack
import yaml
import zenoh

MAX_NS = (1 << 62) - 1


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def config(mode: str, listen: list[str], connect: list[str]) -> zenoh.Config:
    c = zenoh.Config()
    c.insert_json5("mode", json.dumps(mode))
    c.insert_json5("listen/endpoints", json.dumps(listen))
    c.insert_json5("connect/endpoints", json.dumps(connect))
    c.insert_json5("scouting/multicast/enabled", "false")
    return c


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, round(q * (len(ordered) - 1)))]


class Latencies:
    """Subscriber callback: latency (µs) of each sample from the send time it carries."""

    def __init__(self, count: int) -> None:
        self.count = count
        self.values: list[float] = []
        self.done = threading.Event()

    def __call__(self, sample: zenoh.Sample) -> None:
        t = msgpack.unpackb(sample.payload.to_bytes())["t"]
        self.values.append((time.monotonic_ns() - t) / 1000)
        if len(self.values) >= self.count:
            self.done.set()


def peer_process(endpoint: str, count: int) -> None:
    """Child: a plain peer that samples ``count`` direct values, prints their latencies (µs);
    it also routes the relayed key between its clients."""
    latencies = Latencies(count)
    with zenoh.open(config("peer", [endpoint], [])) as session:
        session.declare_subscriber("bench/direct", latencies)
        print("ready", flush=True)
        latencies.done.wait(300)
        time.sleep(1.0)  # the relayed values still pass through
    print(json.dumps(latencies.values), flush=True)


def bridge_mission(ports: dict[str, int], udp: dict[str, int]) -> dict:
    """Two nodes over UDP, no MAC, one channel carrying the send time."""
    return {
        "mission": "latency",
        "modem": {"backend": "udp", "frame_bytes": 64},
        "mac": {"type": "none"},
        "nodes": {
            n: {"address": i + 1, "zenoh": {"listen": [f"tcp/127.0.0.1:{ports[n]}"]},
                "modem": {"options": {"port": udp[n]}}}
            for i, n in enumerate("ab")
        },
        "channels": [{
            "name": "stamp", "from": "a", "to": "b",
            "elements": [{"in": "bench/bridged", "out": "bench/bridged",
                          "fields": [{"field": "t", "type": "int", "min": 0, "max": MAX_NS}]}],
        }],
    }


def client(endpoint: str, deadline: float) -> zenoh.Session:
    """A client session, retried until its peer listens or ``deadline`` passes."""
    while True:
        try:
            return zenoh.open(config("client", [], [endpoint]))
        except zenoh.ZError:
            if time.time() > deadline:
                raise
            time.sleep(0.2)


def measure(count: int, rate: float) -> dict[str, list[float]]:
    """Latencies (µs) of the direct, relayed and bridged paths, from one interleaved run."""
    peer = f"tcp/127.0.0.1:{free_port()}"
    ports = {n: free_port() for n in "ab"}
    udp = {n: free_port(socket.SOCK_DGRAM) for n in "ab"}
    child = subprocess.Popen([sys.executable, __file__, "--child", peer, str(count)],
                             stdout=subprocess.PIPE, text=True)
    assert child.stdout is not None
    assert child.stdout.readline().strip() == "ready"
    relayed, bridged = Latencies(count), Latencies(count)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "latency.yaml"
        path.write_text(yaml.safe_dump(bridge_mission(ports, udp)))
        fleet = subprocess.Popen(
            [sys.executable, "-m", "bridge", "sim", str(path), "--no-live"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )
        sessions: list[zenoh.Session] = []
        try:
            deadline = time.time() + 20
            sessions = [client(e, deadline) for e in
                        (peer, peer, f"tcp/127.0.0.1:{ports['a']}",
                         f"tcp/127.0.0.1:{ports['b']}")]
            put_peer, get_peer, put_a, get_b = sessions
            get_peer.declare_subscriber("bench/relayed", relayed)
            get_b.declare_subscriber("bench/bridged", bridged)
            time.sleep(1.0)
            paths = [(put_peer, "bench/direct"), (put_peer, "bench/relayed"),
                     (put_a, "bench/bridged")]
            encoding = zenoh.Encoding("application/msgpack")
            for i in range(count):  # a third of a tick apart: the paths never overlap
                for session, key in paths[i % 3:] + paths[: i % 3]:
                    session.put(key, msgpack.packb({"t": time.monotonic_ns()}),
                                encoding=encoding)
                    time.sleep(1 / rate / len(paths))
            relayed.done.wait(10)
            bridged.done.wait(10)
        finally:
            for session in sessions:
                session.close()
            fleet.terminate()
            fleet.wait(20)
    out = child.stdout.readline()
    child.wait(30)
    return {"direct": json.loads(out), "relayed": relayed.values, "bridged": bridged.values}


def summary(name: str, values: list[float]) -> tuple[float, float]:
    med, p99 = statistics.median(values), percentile(values, 0.99)
    print(f"{name:<8} n={len(values):>5}  median {med:8.0f} µs   p99 {p99:8.0f} µs")
    return med, p99


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        peer_process(sys.argv[2], int(sys.argv[3]))
        return
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=2000)
    parser.add_argument("--rate", type=float, default=100.0, help="puts per second per path")
    args = parser.parse_args()
    runs = measure(args.count, args.rate)
    figures = {name: summary(name, values) for name, values in runs.items()}
    if len(runs["bridged"]) < args.count:
        print(f"bridge delivered {len(runs['bridged'])} of {args.count}")
    med, p99 = figures["bridged"]
    for base in ("direct", "relayed"):
        base_med, base_p99 = figures[base]
        print(f"added over {base:<8}: median {(med - base_med) / 1000:.2f} ms, "
              f"p99 {(p99 - base_p99) / 1000:.2f} ms (goal ≤ 0.5 ms at p99)")


if __name__ == "__main__":
    main()
