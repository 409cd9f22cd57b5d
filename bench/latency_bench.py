"""Latency the bridge adds: put at one node → sample at another, against plain Zenoh.

Five paths are measured side by side in one run, each tick putting once on each, a fifth
of a tick apart and in rotating order (so load falls on all alike and they never overlap),
with the send time (CLOCK_MONOTONIC ns, shared by all processes) inside the payload:

- direct: an application puts on a Zenoh peer in another process, whose own subscriber
  samples it (one Zenoh hop);
- relayed: an application puts on that peer and another application, a client of the same
  peer, samples it (two Zenoh hops: the bridged path's Zenoh hops, without the water);
- bridged: an application puts on node ``a``'s endpoint; ``zab sim`` (another process) carries
  it over the ``udp`` backend with ``mac: none`` to node ``b``; an application at ``b`` samples
  (``udp`` is a direct backend: node ``a``'s Zenoh callback sends the frame, node ``b``'s
  reader thread publishes it; no event loop on the path, as in *floor (thread)*);
- floor (thread) and floor (asyncio): the bridged path with the least Python possible between
  its two Zenoh hops, in a process of its own that imports nothing of ours: a subscriber at
  peer ``a`` sends each payload as a UDP datagram, which is put at peer ``b``. *thread*: the
  Zenoh callback sends, a thread blocked on the socket puts (no event loop); *asyncio*: the
  callback hands the payload to an event loop (``call_soon_threadsafe``), which sends, and the
  loop's datagram callback puts. What a Python bridge of either shape cannot go below.

Compare paths within one run, never figures of runs at another ``--rate``: where the cores
idle between samples (a VM's vCPUs are descheduled), Python runs several times slower than
back to back. On the 2-core VM of issue #14, the core's whole path from one node to the other
took 35 µs back to back and ~360 µs when run every 10 ms, so what the bridge adds follows
how much Python a sample runs; at ``--rate 300`` every path here took about half as long as
at 60.

With ``--against DIR`` (another checkout with its own ``uv sync``ed ``.venv``, say today's
main in a worktree), a sixth path, *bridged (DIR)*, runs that checkout's ``zab sim`` beside
this one's in the same interleaved run, so the two bridges are compared under the same load.

Run: ``uv run python bench/latency_bench.py [--count 2000] [--rate 60] [--against DIR]``.
"""

from __future__ import annotations

import argparse
import asyncio
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
FLOORS = ("floor (thread)", "floor (asyncio)")
BASELINE = "bridged (other)"
"""The path of ``--against``'s checkout."""


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


def floor_process(kind: str, listen_a: str, listen_b: str) -> None:
    """Child: the least Python between two Zenoh hops (see the module's docstring)."""
    with zenoh.open(config("peer", [listen_a], [])) as a, \
            zenoh.open(config("peer", [listen_b], [])) as b, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as rx:
        rx.bind(("127.0.0.1", 0))
        target = rx.getsockname()
        publisher = b.declare_publisher("bench/floor",
                                        encoding=zenoh.Encoding("application/msgpack"))
        if kind == "thread":
            a.declare_subscriber("bench/floor", lambda s: tx.sendto(s.payload.to_bytes(), target))

            def carry() -> None:
                while True:
                    publisher.put(rx.recv(2048))

            threading.Thread(target=carry, daemon=True).start()
            print("ready", flush=True)
            sys.stdin.read()  # until the parent closes our stdin
            return

        class Put(asyncio.DatagramProtocol):
            def datagram_received(self, data: bytes, addr: object) -> None:
                publisher.put(data)

        async def serve() -> None:
            loop = asyncio.get_running_loop()
            a.declare_subscriber("bench/floor", lambda s: loop.call_soon_threadsafe(
                tx.sendto, s.payload.to_bytes(), target))
            await loop.create_datagram_endpoint(Put, sock=rx)
            print("ready", flush=True)
            await loop.run_in_executor(None, sys.stdin.read)

        asyncio.run(serve())


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


def put_in_rotation(paths: list[tuple[zenoh.Session, str]], count: int, rate: float) -> None:
    """``count`` ticks at ``rate`` per second, each putting the send time once on every path,
    1/n of a tick apart and in rotating order (so load falls on all alike, never overlapping)."""
    encoding = zenoh.Encoding("application/msgpack")
    n = len(paths)
    for i in range(count):
        for session, key in paths[i % n:] + paths[: i % n]:
            session.put(key, msgpack.packb({"t": time.monotonic_ns()}), encoding=encoding)
            time.sleep(1 / rate / n)


def run_paths(paths: list[tuple[zenoh.Session, str]], got: dict[str, Latencies], count: int,
              rate: float) -> None:
    """Let the links settle, put in rotation on ``paths``, then wait for every path's
    samples (10 s at most each)."""
    time.sleep(1.0)
    put_in_rotation(paths, count, rate)
    for latencies in got.values():
        latencies.done.wait(10)


def stop(sessions: list[zenoh.Session], fleets: list[subprocess.Popen],
         helpers: list[subprocess.Popen]) -> None:
    """Close the sessions, stop each ``zab sim``, and end the helper processes (stdin
    closed)."""
    for session in sessions:
        session.close()
    for fleet in fleets:
        fleet.terminate()
        fleet.wait(20)
    for process in helpers:
        process.communicate(timeout=20)


def start_fleet(tmp: Path, name: str, checkout: Path | None) -> tuple[subprocess.Popen, str, str]:
    """``zab sim`` of a two-node udp mission on free ports, from this checkout or from
    ``checkout`` (its own ``.venv``): the process and its nodes' endpoints."""
    ports = {n: free_port() for n in "ab"}
    udp = {n: free_port(socket.SOCK_DGRAM) for n in "ab"}
    path = tmp / f"{name}.yaml"
    path.write_text(yaml.safe_dump(bridge_mission(ports, udp)))
    python = sys.executable if checkout is None else str(checkout / ".venv" / "bin" / "python")
    fleet = subprocess.Popen(
        [python, "-m", "bridge", "sim", str(path), "--no-live"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=checkout,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    return fleet, f"tcp/127.0.0.1:{ports['a']}", f"tcp/127.0.0.1:{ports['b']}"


def measure(count: int, rate: float, against: Path | None = None) -> dict[str, list[float]]:
    """Latencies (µs) of every path, from one interleaved run (``against``: a second bridged
    path from that checkout)."""
    peer = f"tcp/127.0.0.1:{free_port()}"
    floors = {kind: [f"tcp/127.0.0.1:{free_port()}" for _ in "ab"] for kind in FLOORS}
    child = subprocess.Popen([sys.executable, __file__, "--child", peer, str(count)],
                             stdout=subprocess.PIPE, text=True)
    floor_children = [subprocess.Popen([sys.executable, __file__, "--floor", kind, *ends],
                                       stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
                      for kind, ends in floors.items()]
    for process in (child, *floor_children):
        assert process.stdout is not None
        assert process.stdout.readline().strip() == "ready"
    bridges = {"bridged": None, **({BASELINE: against} if against is not None else {})}
    got = {name: Latencies(count) for name in ("relayed", *bridges, *FLOORS)}
    with tempfile.TemporaryDirectory() as tmp:
        fleets = {name: start_fleet(Path(tmp), f"fleet{i}", checkout)
                  for i, (name, checkout) in enumerate(bridges.items())}
        sessions: list[zenoh.Session] = []
        try:
            deadline = time.time() + 20
            put_peer, get_peer = client(peer, deadline), client(peer, deadline)
            sessions = [put_peer, get_peer]
            get_peer.declare_subscriber("bench/relayed", got["relayed"])
            paths = [(put_peer, "bench/direct"), (put_peer, "bench/relayed")]
            for name, (_, end_a, end_b) in fleets.items():
                put_a, get_b = client(end_a, deadline), client(end_b, deadline)
                sessions += [put_a, get_b]
                get_b.declare_subscriber("bench/bridged", got[name])
                paths.append((put_a, "bench/bridged"))
            for kind, (end_a, end_b) in floors.items():
                put_f, get_f = client(end_a, deadline), client(end_b, deadline)
                sessions += [put_f, get_f]
                get_f.declare_subscriber("bench/floor", got[kind])
                paths.append((put_f, "bench/floor"))
            run_paths(paths, got, count, rate)
        finally:
            stop(sessions, [fleet for fleet, _, _ in fleets.values()], floor_children)
    out = child.stdout.readline()
    child.wait(30)
    return {"direct": json.loads(out), **{name: v.values for name, v in got.items()}}


def summary(name: str, values: list[float]) -> tuple[float, float]:
    med, p99 = statistics.median(values), percentile(values, 0.99)
    print(f"{name:<16} n={len(values):>5}  median {med:8.0f} µs   p99 {p99:8.0f} µs")
    return med, p99


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        peer_process(sys.argv[2], int(sys.argv[3]))
        return
    if len(sys.argv) > 1 and sys.argv[1] == "--floor":
        floor_process(sys.argv[2].split()[1].strip("()"), sys.argv[3], sys.argv[4])
        return
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=2000)
    parser.add_argument("--rate", type=float, default=60.0, help="puts per second per path")
    parser.add_argument("--against", type=Path, default=None,
                        help="another checkout (with its .venv) whose bridge runs beside")
    args = parser.parse_args()
    runs = measure(args.count, args.rate, args.against)
    figures = {name: summary(name, values) for name, values in runs.items()}
    bridges = ["bridged", *([BASELINE] if args.against is not None else [])]
    for name in bridges:
        if len(runs[name]) < args.count:
            print(f"{name} delivered {len(runs[name])} of {args.count}")
    for path in (*bridges, *FLOORS):
        med, p99 = figures[path]
        for base in ("direct", "relayed"):
            base_med, base_p99 = figures[base]
            goal = " (goal ≤ 1 ms at p99)" if path in bridges else ""
            print(f"{path:<16} added over {base:<8}: median {(med - base_med) / 1000:.2f} ms, "
                  f"p99 {(p99 - base_p99) / 1000:.2f} ms{goal}")


if __name__ == "__main__":
    main()
