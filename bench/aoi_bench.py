"""Slot fill and age of information on a saturated TDMA mission in the simulated ocean.

Three nodes share a static TDMA cycle over the ``s100-rf`` preset (128-byte frames). Each node
sends two channels that together fill its frame, and applications publish fresh data on every
input key far faster than the slots, so every slot carries a full frame. Measured in one run:

- slot fill: channel payload bits over frame bits, for every frame sent (target ≥ 95 %);
- age of information at the receivers (time since the channel last arrived, sampled every
  0.25 s) against the TDMA bound: a channel sent once per cycle has mean age cycle/2 and
  worst age one cycle (target: within 10 %).

Run: ``uv run python bench/aoi_bench.py [--duration 40]``.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import socket
import statistics
import time

import msgpack
import yaml
import zenoh

from bridge.core.events import Event, FrameSent
from bridge.core.loaded import parse_mission
from bridge.runtime.fleet import Fleet

NODES = ("n1", "n2", "n3")
SLOT_S = 0.8
FRAME_BYTES = 128
FIELDS = [{"field": f"f{i}", "bits": 64, "min": 0, "max": 1} for i in range(7)] + [
    {"field": "f7", "bits": 51, "min": 0, "max": 1}
]  # 499 bits: two such channels, their indices, the count and the check fill 128 bytes


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def mission_text() -> str:
    nodes = {
        n: {"address": i + 1, "position": {"x": i * 1.0, "y": 0, "depth": 1},
            "zenoh": {"listen": [f"tcp/127.0.0.1:{free_port()}"]}}
        for i, n in enumerate(NODES)
    }
    channels = [
        {"name": f"{n}_{c}", "from": n, "to": ".*",
         "elements": [{"in": f"data/{c}", "out": f"{n}/data/{c}", "fields": FIELDS}]}
        for n in NODES for c in ("a", "b")
    ]
    return yaml.safe_dump({
        "mission": "aoi",
        "modem": {"backend": "sim", "frame_bytes": FRAME_BYTES,
                  "options": {"preset": "s100-rf", "seed": 5}},
        "mac": {"type": "tdma", "slot_s": SLOT_S, "guard_s": 0.1, "order": list(NODES)},
        "nodes": nodes,
        "channels": channels,
    })


async def main(duration: float) -> None:
    loaded = parse_mission(mission_text(), "aoi.yaml")
    fills: list[float] = []
    bits = {c.name: c.bits for c in loaded.table.channels}

    def on_event(node: str, event: Event) -> None:
        if isinstance(event, FrameSent):
            fills.append(sum(bits[c] for c in event.channels) / (FRAME_BYTES * 8))

    fleet = Fleet(loaded, on_event=on_event)
    stop = asyncio.Event()
    runner = asyncio.create_task(fleet.run(stop))
    await fleet.ready.wait()
    apps = []
    for n in NODES:
        c = zenoh.Config()
        c.insert_json5("mode", '"client"')
        c.insert_json5("connect/endpoints", json.dumps(loaded.mission.nodes[n].zenoh.listen))
        c.insert_json5("scouting/multicast/enabled", "false")
        apps.append(zenoh.open(c))
    end = time.time() + duration
    try:
        while time.time() < end:
            for app in apps:
                for c in ("a", "b"):
                    value = {f"f{i}": (time.time() * 0.01 + i / 10) % 1 for i in range(8)}
                    app.put(f"data/{c}", msgpack.packb(value),
                            encoding=zenoh.Encoding("application/msgpack"))
            await asyncio.sleep(0.1)
    finally:
        for app in apps:
            app.close()
        stop.set()
        await runner
    cycle = SLOT_S * len(NODES)
    print(f"frames sent {len(fills)}; slot fill mean {statistics.mean(fills):.1%}, "
          f"min {min(fills):.1%} (target ≥ 95 %)")
    print(f"TDMA cycle {cycle:.2f} s → bound: mean age {cycle / 2:.2f} s, worst age {cycle:.2f} s")
    print(f"{'channel':<8} {'mean age':>9} {'ratio':>6} {'max age':>8} {'ratio':>6}")
    report = fleet.report()
    for name, c in sorted(report.channels.items()):
        if c.age is not None:
            print(f"{name:<8} {c.age.mean_s:8.2f}s {c.age.mean_s / (cycle / 2):6.2f} "
                  f"{c.age.max_s:7.2f}s {c.age.max_s / cycle:6.2f}")
    links = report.links
    lost = sum(sum(link.lost.values()) for link in links)
    print(f"frames lost in the water: {lost} of {sum(link.sent for link in links)}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=40.0)
    asyncio.run(main(parser.parse_args().duration))
