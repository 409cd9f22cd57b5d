"""Latency the bridge adds: put at one node → sample at another, against plain Zenoh.

Both paths are measured in the same run, with the send time (CLOCK_MONOTONIC ns, shared by all
processes) inside the payload:

- plain: an application puts on a Zenoh peer in another process, whose subscriber samples it;
- bridge: an application puts on node ``a``'s endpoint; ``zab sim`` (another process) carries
  it over the ``udp`` backend with ``mac: none`` to node ``b``; an application at ``b`` samples.

Run: ``uv run python bench/latency_bench.py [--count 500] [--rate 50]``.
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


def subscriber_process(endpoint: str, count: int) -> None:
    """Child: a plain peer that samples ``count`` values and prints their latencies (µs)."""
    latencies = Latencies(count)
    with zenoh.open(config("peer", [endpoint], [])) as session:
        session.declare_subscriber("bench/latency", latencies)
        print("ready", flush=True)
        latencies.done.wait(120)
    print(json.dumps(latencies.values), flush=True)


def send(session: zenoh.Session, key: str, count: int, rate: float) -> None:
    for _ in range(count):
        value = {"t": time.monotonic_ns()}
        session.put(key, msgpack.packb(value), encoding=zenoh.Encoding("application/msgpack"))
        time.sleep(1 / rate)


def plain(count: int, rate: float) -> list[float]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    child = subprocess.Popen([sys.executable, __file__, "--child", endpoint, str(count)],
                             stdout=subprocess.PIPE, text=True)
    assert child.stdout is not None
    assert child.stdout.readline().strip() == "ready"
    with zenoh.open(config("client", [], [endpoint])) as session:
        time.sleep(0.5)
        send(session, "bench/latency", count, rate)
    out = child.stdout.readline()
    child.wait(30)
    return json.loads(out)


def bridged(count: int, rate: float) -> list[float]:
    ports = {n: free_port() for n in "ab"}
    udp = {n: free_port(socket.SOCK_DGRAM) for n in "ab"}
    mission = {
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
            "elements": [{"in": "bench/latency", "out": "bench/latency",
                          "fields": [{"field": "t", "type": "int", "min": 0, "max": MAX_NS}]}],
        }],
    }
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "latency.yaml"
        path.write_text(yaml.safe_dump(mission))
        fleet = subprocess.Popen(
            [sys.executable, "-m", "bridge", "sim", str(path), "--no-live"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )
        latencies = Latencies(count)
        try:
            deadline = time.time() + 20
            while True:
                try:
                    app_a = zenoh.open(config("client", [], [f"tcp/127.0.0.1:{ports['a']}"]))
                    app_b = zenoh.open(config("client", [], [f"tcp/127.0.0.1:{ports['b']}"]))
                    break
                except zenoh.ZError:
                    if time.time() > deadline:
                        raise
                    time.sleep(0.2)
            try:
                app_b.declare_subscriber("bench/latency", latencies)
                time.sleep(0.5)
                send(app_a, "bench/latency", count, rate)
                latencies.done.wait(10)
            finally:
                app_a.close()
                app_b.close()
        finally:
            fleet.terminate()
            fleet.wait(20)
    return latencies.values


def summary(name: str, values: list[float]) -> tuple[float, float]:
    med, p99 = statistics.median(values), percentile(values, 0.99)
    print(f"{name:<8} n={len(values):>5}  median {med:8.0f} µs   p99 {p99:8.0f} µs")
    return med, p99


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        subscriber_process(sys.argv[2], int(sys.argv[3]))
        return
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=500)
    parser.add_argument("--rate", type=float, default=50.0, help="puts per second")
    args = parser.parse_args()
    base_med, base_p99 = summary("plain", plain(args.count, args.rate))
    values = bridged(args.count, args.rate)
    if len(values) < args.count:
        print(f"bridge delivered {len(values)} of {args.count}")
    med, p99 = summary("bridge", values)
    print(f"added by the bridge: median {(med - base_med) / 1000:.2f} ms, "
          f"p99 {(p99 - base_p99) / 1000:.2f} ms (target ≤ 1 ms at p99); "
          f"ratio bridge/plain median {med / base_med:.1f}×")


if __name__ == "__main__":
    main()
