"""An input flood against a real `zab run` node: memory, what it says, and legitimate latency.

Run: ``uv run python bench/flood.py [--publishers 8] [--seconds 15] [--after 30] [--auth]``
(the issue's run: ``--publishers 20 --seconds 75``); huge puts instead:
``uv run python bench/flood.py --huge 20,50,100``.

Two `zab run` processes (``a`` and ``b``, udp backend on loopback, TDMA with a 1 s cycle). A
plain Zenoh application (zenoh and msgpack only) puts a numbered navigation value on ``a`` every
0.5 s and another one at ``b`` times its arrival on ``a/nav``. Then ``--publishers`` processes,
each a plain Zenoh client of ``a``, put as fast as they can, for ``--seconds``, a mix of bad
payloads on ``a``'s other input keys and on keys nobody bridges: random bytes, wrong types,
1 MB values, nesting 10 000 deep, maps whose keys are maps, NaN keys; twice, with ``--after``
seconds of quiet after each round.

Printed: ``a``'s resident memory (idle, the most during each round, at the end of each quiet
spell), the events it published on ``…/events`` (most in one second, per kind and cause), the
lines it logged (per key and cause), the navigation latency (median and 90th percentile) before
and during the floods, and the goals of issue 35: RSS after <= idle + 20 MB, during <= idle +
60 MB, events <= 1 per cause per second, log lines <= 1 per key and cause per minute, median
latency during <= idle + one MAC cycle.

``--huge`` puts one payload of each size (MB) on ``a``'s input ``cmd`` (capped at a few KB: each
is dropped as too large), ``--settle`` seconds apart, then one of 1 MB, and prints ``a``'s RSS
before, the most after each put and at its end. A put Zenoh dropped fragments of (its queue
full) stays in ``a``'s Zenoh, partly reassembled, until the next message in fragments: the 1 MB
put. After it ``a`` should be back within 20 MB of idle: ``--huge 20,50,100`` left it at 171 MB
from 69 before the intake let go of its last sample and the bridge trimmed the C heap
(bridge.runtime.heap), at 69 since.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import random
import re
import secrets
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any

import msgpack
import zenoh

REPO = Path(__file__).resolve().parent.parent
CYCLE_S = 1.0
MISSION = """\
mission: flood
wire: {auth: @AUTH@}
modem: {backend: udp, frame_bytes: 48}
mac: {type: tdma, slot_s: 0.5, guard_s: 0.05, order: [a, b]}
nodes:
  a: {address: 1, modem: {options: {port: @UA@}}, zenoh: {listen: ["tcp/127.0.0.1:@ZA@"]}}
  b: {address: 2, modem: {options: {port: @UB@}}, zenoh: {listen: ["tcp/127.0.0.1:@ZB@"]}}
channels:
  - name: nav
    from: a
    to: b
    elements: [{in: nav, out: a/nav, fields: [{field: n, type: int, min: 0, max: 65535},
                                              {field: x, min: -1000, max: 1000, bits: 16}]}]
  - name: cmd
    from: a
    to: b
    reliable: true
    elements: [{in: cmd, out: a/cmd, fields: [{field: n, type: int, min: 0, max: 255}]}]
  - name: note
    from: a
    to: b
    elements: [{in: note, out: a/note, fields: [{field: s, type: string, max_length: 8}]}]
"""
FLOODED_KEYS = ("cmd", "note", "junk/a", "junk/b")  # a's other inputs, and keys nobody bridges


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def client(endpoint: str) -> zenoh.Session:
    config = zenoh.Config()
    config.insert_json5("mode", '"client"')
    config.insert_json5("connect/endpoints", json.dumps([endpoint]))
    config.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(config)


def bad_payloads(rng: random.Random) -> list[tuple[bytes, str]]:
    """The flood's mix: (payload, encoding)."""
    mp, js = "application/msgpack", "application/json"
    return [
        (rng.randbytes(200), "zenoh/bytes"),
        (rng.randbytes(2000), mp),
        (msgpack.packb({"n": "not a number", "s": 12}), mp),
        (msgpack.packb({"n": [1, 2, 3], "s": {"x": 1}}), mp),
        (msgpack.packb({"s": "x" * 1_000_000}), mp),  # 1 MB
        (b"\x91" * 10_000 + b"\x01", mp),  # nested 10 000 deep
        (b"[" * 10_000 + b"]" * 10_000, js),
        (b"\x81\x81\xa1x\x01\x02", mp),  # a map whose key is a map
        (b"\x81\x91\x01\x02", mp),  # a map whose key is an array
        (b"\x81\xcb\x7f\xf8\x00\x00\x00\x00\x00\x00\x01", mp),  # a NaN key
        (json.dumps({"n": 1e400}).encode(), js),
    ]


def flooder(endpoint: str, seconds: float, seed: int) -> None:
    """One flooding publisher (a subprocess): prints how many puts it made."""
    rng = random.Random(seed)
    payloads = bad_payloads(rng)
    session = client(endpoint)
    puts = 0
    try:
        publishers = {key: session.declare_publisher(key) for key in FLOODED_KEYS}
        end = time.monotonic() + seconds
        keys = list(publishers)
        while time.monotonic() < end:
            data, encoding = payloads[puts % len(payloads)]
            publishers[keys[puts % len(keys)]].put(data, encoding=zenoh.Encoding(encoding))
            puts += 1
    finally:
        session.close()
    print(puts)


def rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as status:
        for line in status:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return math.nan


class Node:
    """One `zab run` process, its stderr in a file."""

    def __init__(self, mission: Path, name: str, state: Path, log: Path, env: dict) -> None:
        self.log = log
        self.stream = open(log, "w")  # noqa: SIM115 (closed in stop)
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "bridge", "run", str(mission), "--node", name,
             "--state-dir", str(state)], cwd=REPO, stdout=self.stream, stderr=self.stream,
            env={**os.environ, **env, "COLUMNS": "200"})

    def wait_running(self) -> None:
        end = time.time() + 60
        while "bridge running" not in self.log.read_text():
            if self.proc.poll() is not None or time.time() > end:
                raise SystemExit(f"the node did not start:\n{self.log.read_text()}")
            time.sleep(0.2)

    def lines(self) -> list[str]:
        return self.log.read_text().splitlines()

    def stop(self) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(20)
        except subprocess.TimeoutExpired:
            self.proc.kill()
        self.stream.close()


class Watch:
    """Navigation sent and received, events published, memory sampled, all by phase."""

    def __init__(self) -> None:
        self.phase = "idle"
        self.sent: dict[int, tuple[float, str]] = {}
        self.latency: dict[str, list[float]] = defaultdict(list)
        self.events: Counter[tuple[str, str, int]] = Counter()  # (phase, kind+cause, second)
        self.event_total: Counter[str] = Counter()
        self.rss: dict[str, list[float]] = defaultdict(list)
        self.puts: dict[str, int] = {}  # bad payloads put, per round
        self.lock = threading.Lock()

    def arrived(self, sample: zenoh.Sample) -> None:
        n = msgpack.unpackb(sample.payload.to_bytes())["n"]
        now = time.time()
        with self.lock:
            if n in self.sent:
                at, phase = self.sent.pop(n)
                self.latency[phase].append(now - at)

    def event(self, sample: zenoh.Sample) -> None:
        event = msgpack.unpackb(sample.payload.to_bytes())
        what = event.get("kind", "?")
        if what == "frame_dropped":
            what += f":{event.get('reason')}"
        with self.lock:  # (by the node's own clock: a summary a second never shares one)
            self.events[(self.phase, what, int(event.get("time", time.time())))] += 1
            self.event_total[self.phase] += 1


def run(args: argparse.Namespace) -> dict[str, Any]:
    work = Path(tempfile.mkdtemp(prefix="zab-flood-"))
    ports = {"UA": free_port(socket.SOCK_DGRAM), "UB": free_port(socket.SOCK_DGRAM),
             "ZA": free_port(), "ZB": free_port()}
    if args.ports:  # (a machine shared by several runs: each its own range)
        ports = {name: args.ports + i for i, name in enumerate(ports)}
    text = MISSION.replace("@AUTH@", "{tag_bytes: 4}" if args.auth else "off")
    for name, port in ports.items():
        text = text.replace(f"@{name}@", str(port))
    mission = work / "flood.yaml"
    mission.write_text(text)
    env = {"ZAB_KEY": secrets.token_hex(32)} if args.auth else {}
    nodes = {name: Node(mission, name, work / f"state-{name}", work / f"{name}.log", env)
             for name in ("a", "b")}
    sessions: list[zenoh.Session] = []
    watch = Watch()
    stop = threading.Event()
    try:
        for node in nodes.values():
            node.wait_running()
        if args.huge:
            return huge(args, f"tcp/127.0.0.1:{ports['ZA']}", nodes["a"].proc.pid)
        at_a, at_b = client(f"tcp/127.0.0.1:{ports['ZA']}"), client(f"tcp/127.0.0.1:{ports['ZB']}")
        sessions += [at_a, at_b]
        at_b.declare_subscriber("a/nav", watch.arrived)
        at_a.declare_subscriber("@zab/flood/a/events", watch.event)
        nav = at_a.declare_publisher("nav", encoding=zenoh.Encoding("application/msgpack"))
        pid = nodes["a"].proc.pid

        def legitimate() -> None:
            n = 0
            while not stop.is_set():
                with watch.lock:
                    watch.sent[n] = (time.time(), watch.phase)
                    watch.rss[watch.phase].append(rss_mb(pid))
                nav.put(msgpack.packb({"n": n, "x": 1.5}))
                n = (n + 1) % 65536
                stop.wait(0.5)

        threading.Thread(target=legitimate, daemon=True).start()
        lines_before: dict[str, int] = {}

        def phase(name: str, seconds: float, flood: bool) -> None:
            with watch.lock:
                watch.phase = name
            lines_before[name] = len(nodes["a"].lines())
            if not flood:
                time.sleep(seconds)
                return
            floods = [subprocess.Popen([sys.executable, __file__, "--flooder",
                                        f"tcp/127.0.0.1:{ports['ZA']}", str(seconds), str(i)],
                                       stdout=subprocess.PIPE, text=True)
                      for i in range(args.publishers)]
            puts = sum(int(f.communicate(timeout=seconds + 60)[0].strip() or 0) for f in floods)
            watch.puts[name] = puts

        phase("idle", args.idle, False)
        phase("flood 1", args.seconds, True)
        phase("after 1", args.after, False)
        phase("flood 2", args.seconds, True)
        phase("after 2", args.after, False)
        stop.set()
        a_lines = nodes["a"].lines()
    finally:
        stop.set()
        for session in sessions:
            session.close()
        for node in nodes.values():
            node.stop()
    return summarise(watch, a_lines, lines_before, args)


def huge(args: argparse.Namespace, endpoint: str, pid: int) -> dict[str, Any]:
    """One put of each size in ``args.huge`` (MB) on ``a``'s input ``cmd``: ``a``'s RSS before,
    the most after each put, and ``args.settle`` seconds after it."""
    time.sleep(args.settle)  # (the node's first seconds: its own allocations settle)
    idle = rss_mb(pid)
    session = client(endpoint)
    rows = []
    try:
        time.sleep(1.0)
        for size in [*(float(mb) for mb in args.huge.split(",")), 1.0]:
            data = os.urandom(int(size * (1 << 20)))
            session.put("cmd", data)
            del data
            samples = []
            end = time.monotonic() + args.settle
            while time.monotonic() < end:
                samples.append(rss_mb(pid))
                time.sleep(0.1)
            rows.append({"put_mb": size, "peak_mb": max(samples), "after_mb": samples[-1]})
    finally:
        session.close()
    return {"huge": True, "rss_idle_mb": idle, "puts": rows,
            "goals": {"rss after <= idle + 20 MB": rows[-1]["after_mb"] <= idle + 20}}


CAUSES = "too_large|undecodable|unfit|implausible|unpublishable"
DROPPED = re.compile(rf"dropped (?:a payload|\d+ more payloads) on '([^']*)'.*?\(({CAUSES})[;)]")


def summarise(watch: Watch, lines: list[str], before: dict[str, int],
              args: argparse.Namespace) -> dict[str, Any]:
    idle = statistics.median(watch.rss["idle"])
    peak = max(max(watch.rss["flood 1"]), max(watch.rss["flood 2"]))
    after = [watch.rss[p][-1] for p in ("after 1", "after 2")]
    per_second = Counter()
    for (phase, what, _), count in watch.events.items():
        if phase.startswith("flood"):
            per_second[what] = max(per_second[what], count)
    flood_lines = lines[before["flood 1"]:]
    by_cause = Counter(m.groups() for line in flood_lines if (m := DROPPED.search(line)))
    minutes = (2 * args.seconds + 2 * args.after) / 60
    lat = {p: watch.latency[p] for p in ("idle", "flood 1", "flood 2")}
    during = lat["flood 1"] + lat["flood 2"]
    median_idle = statistics.median(lat["idle"]) if lat["idle"] else math.nan
    median_during = statistics.median(during) if during else math.nan
    return {
        "auth": args.auth, "publishers": args.publishers, "seconds": args.seconds,
        "puts": [watch.puts["flood 1"], watch.puts["flood 2"]],
        "rss_idle_mb": idle, "rss_peak_mb": peak, "rss_after_mb": after,
        "events_published": dict(watch.event_total),
        "events_max_per_second": dict(per_second),
        "log_lines_after_start": len(flood_lines),
        "log_lines_per_key_cause": {f"{k} {c}": n for (k, c), n in by_cause.items()},
        "tracebacks": sum("Traceback" in line for line in flood_lines),
        "latency_median_s": {"idle": median_idle, "flood": median_during},
        "latency_p90_s": {"idle": _p90(lat["idle"]), "flood": _p90(during)},
        "nav_superseded_or_lost": {p: sum(1 for _, ph in watch.sent.values() if ph == p)
                                   for p in ("idle", "flood 1", "flood 2")},
        "goals": {
            "rss after <= idle + 20 MB": all(a <= idle + 20 for a in after),
            "rss during <= idle + 60 MB": peak <= idle + 60,
            "events <= 1 per cause per second": all(n <= 1 for n in per_second.values()),
            "log lines <= 1 per key and cause per minute": all(
                n <= max(1, math.ceil(minutes)) for n in by_cause.values()),
            "median latency during <= idle + one cycle":
                median_during <= median_idle + CYCLE_S,
        },
    }


def _p90(values: list[float]) -> float:
    return statistics.quantiles(values, n=10)[-1] if len(values) >= 2 else math.nan


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--publishers", type=int, default=8)
    parser.add_argument("--seconds", type=float, default=15.0, help="each flood round")
    parser.add_argument("--after", type=float, default=30.0, help="quiet after each round")
    parser.add_argument("--idle", type=float, default=15.0, help="before the first round")
    parser.add_argument("--auth", action="store_true", help="authenticated frames")
    parser.add_argument("--ports", type=int, metavar="BASE",
                        help="ports BASE to BASE+3 (default: free ones)")
    parser.add_argument("--huge", metavar="MB,MB,...",
                        help="instead of the flood: one put of each size on an input")
    parser.add_argument("--settle", type=float, default=10.0,
                        help="--huge: seconds after each put (and before the first)")
    parser.add_argument("--flooder", nargs=3, metavar=("ENDPOINT", "SECONDS", "SEED"),
                        help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.flooder:
        endpoint, seconds, seed = args.flooder
        flooder(endpoint, float(seconds), int(seed))
        return
    result = run(args)
    print(json.dumps(result, indent=2))
    idle = result["rss_idle_mb"]
    if result.get("huge"):
        print(f"\nRSS: idle {idle:.0f} MB; " + ", ".join(
            f"put {row['put_mb']:.0f} MB: peak {row['peak_mb']:.0f}, after {row['after_mb']:.0f}"
            for row in result["puts"]))
        for goal, met in result["goals"].items():
            print(f"{'met' if met else 'NOT MET':>8}  {goal}")
        return
    print(f"\nRSS: idle {idle:.0f} MB, peak {result['rss_peak_mb']:.0f} MB "
          f"({result['rss_peak_mb'] / idle:.2f}x), after each round "
          + ", ".join(f"{a:.0f} MB ({a / idle:.2f}x)" for a in result["rss_after_mb"]))
    lat = result["latency_median_s"]
    print(f"navigation latency, median: idle {lat['idle']:.2f} s, flood {lat['flood']:.2f} s "
          f"({lat['flood'] / lat['idle']:.2f}x)")
    for goal, met in result["goals"].items():
        print(f"{'met' if met else 'NOT MET':>8}  {goal}")


if __name__ == "__main__":
    main()
