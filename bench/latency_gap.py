"""What the node core's machinery costs on the direct path: ``zab sim`` against a lean bridge.

Three paths side by side in one run, as in ``latency_bench.py`` (a put every 1/60 s on each,
a third of a tick apart, in rotating order):

- direct: one plain Zenoh hop (the baseline of ``latency_bench.py``);
- bridged: ``zab sim`` carries the sample over ``udp`` with ``mac: none``, as in
  ``latency_bench.py``;
- lean: a process of its own does the same wire work with the bridge's own codecs and
  nothing else: the Zenoh callback decodes the payload, packs the element
  (``element.layout.pack``), builds the frame (``FrameCodec.encode``) and sends it; a reader
  thread decodes it (``FrameCodec.decode``) and puts the value with the bridge's attachment.
  No store, MAC, events, statistics, links or persistence.

The two bridges send the same frames and publish the same values, so the difference between
them is the node core and its runtime around the codecs: what a leaner hot path could win.

Run: ``uv run python bench/latency_gap.py [--count 2000]``.
"""

from __future__ import annotations

import argparse
import json
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import yaml
import zenoh
from latency_bench import (
    Latencies,
    bridge_mission,
    client,
    config,
    free_port,
    percentile,
    run_paths,
    stop,
)

from bridge.core.loaded import parse_mission
from bridge.core.node import NodeCore
from bridge.modems.udp import HEADER, MAGIC
from bridge.runtime.session import origin_tag
from bridge.wire.payloads import decode_payload, encode_payload

RATE = 60.0
KEY = "bench/bridged"


def lean_process(mission: Path, listen_a: str, listen_b: str) -> None:
    """Child: the lean bridge (see the module's docstring), until its stdin closes."""
    loaded = parse_mission(mission.read_text())
    sender, receiver = NodeCore(loaded, "a"), NodeCore(loaded, "b")
    ((channel, _, element),) = sender.bindings[KEY]
    codec, decoder = sender.codec, receiver.codec
    attachment = origin_tag(loaded.mission.mission, "b")
    with zenoh.open(config("peer", [listen_a], [])) as a, \
            zenoh.open(config("peer", [listen_b], [])) as b, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as rx:
        rx.bind(("127.0.0.1", 0))
        target = rx.getsockname()
        publisher = b.declare_publisher(KEY, encoding=zenoh.Encoding("application/msgpack"))

        def send(sample: zenoh.Sample) -> None:
            if sample.kind != zenoh.SampleKind.PUT:
                return
            value = decode_payload(sample.payload.to_bytes(), str(sample.encoding))
            frame = codec.encode([(channel, element.layout.pack(value))], (), 0)
            tx.sendto(HEADER.pack(MAGIC, 1, 2) + frame, socket.MSG_DONTWAIT, target)

        def carry() -> None:
            while True:
                data = rx.recv(2048)
                for entry in decoder.decode(data[HEADER.size:], 1).entries:
                    for value in entry.values:
                        publisher.put(encode_payload(value)[0], attachment=attachment)

        a.declare_subscriber(KEY, send)
        threading.Thread(target=carry, daemon=True).start()
        print("ready", flush=True)
        sys.stdin.read()


def measure(count: int) -> dict[str, list[float]]:
    """Latencies (µs) of the three paths, from one interleaved run."""
    peer = f"tcp/127.0.0.1:{free_port()}"
    ports = {n: free_port() for n in "ab"}
    udp = {n: free_port(socket.SOCK_DGRAM) for n in "ab"}
    lean_ends = [f"tcp/127.0.0.1:{free_port()}" for _ in "ab"]
    got = {name: Latencies(count) for name in ("bridged", "lean")}
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "latency.yaml"
        path.write_text(yaml.safe_dump(bridge_mission(ports, udp)))
        child = subprocess.Popen([sys.executable, str(Path(__file__).with_name(
            "latency_bench.py")), "--child", peer, str(count)], stdout=subprocess.PIPE, text=True)
        lean = subprocess.Popen([sys.executable, __file__, "--lean", str(path), *lean_ends],
                                stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        for process in (child, lean):
            assert process.stdout is not None
            assert process.stdout.readline().strip() == "ready"
        log = Path(tmp) / "fleet.log"
        fleet = subprocess.Popen([sys.executable, "-m", "bridge", "sim", str(path), "--no-live"],
                                 stdout=log.open("w"), stderr=subprocess.STDOUT)
        sessions: list[zenoh.Session] = []
        try:
            deadline = time.time() + 20
            for end in (peer, f"tcp/127.0.0.1:{ports['a']}", f"tcp/127.0.0.1:{ports['b']}",
                        *lean_ends):
                try:
                    sessions.append(client(end, deadline))
                except zenoh.ZError:
                    child.kill()
                    sys.exit(f"nobody listens at {end}; zab sim printed:\n{log.read_text()}")
            put_peer, put_a, get_b, put_lean, get_lean = sessions
            get_b.declare_subscriber(KEY, got["bridged"])
            get_lean.declare_subscriber(KEY, got["lean"])
            paths = [(put_peer, "bench/direct"), (put_a, KEY), (put_lean, KEY)]
            run_paths(paths, got, count, RATE)
        finally:
            stop(sessions, [fleet], [lean])
    assert child.stdout is not None
    direct = json.loads(child.stdout.readline())
    child.wait(30)
    return {"direct": direct,
            **{name: v.values for name, v in got.items()}}


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--lean":
        lean_process(Path(sys.argv[2]), sys.argv[3], sys.argv[4])
        return
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=2000)
    runs = measure(parser.parse_args().count)
    base_med, base_p99 = statistics.median(runs["direct"]), percentile(runs["direct"], 0.99)
    for name, values in runs.items():
        med, p99 = statistics.median(values), percentile(values, 0.99)
        added = "" if name == "direct" else \
            f"   added over direct: median {(med - base_med) / 1000:.2f} ms, " \
            f"p99 {(p99 - base_p99) / 1000:.2f} ms"
        print(f"{name:<8} n={len(values):>5}  median {med:6.0f} µs  p99 {p99:6.0f} µs{added}")


if __name__ == "__main__":
    main()
