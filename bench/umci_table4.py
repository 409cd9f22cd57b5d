"""Seed 002's Table 4 (HIL teleoperation over WFS S100 RF modems) reproduced in the simulator.

``deploy/missions/bluerov_rf.yaml``: the operator polls the ROV every 640 ms with a 16-byte
frame (its joystick command); the ROV answers each poll it hears with a 57-byte frame (status
and an image trunk). Both nodes' bridges (:class:`~bridge.core.NodeCore`) run on the virtual
clock of :class:`~bridge.fastsim.FastFleet` over the pure ocean with the ``s100-rf`` preset
(seed 002 Table 3: 1.9 kbit/s, 85 ms intrinsic delay, 13.2 ms jitter taken as the standard
deviation of a Gaussian, instant propagation), once with BER 0 and once with BER 0.07 %.

Measured per direction, from the frames each receiver decodes:

- throughput: bits of the frames received (whole frames: 16 B and 57 B, the paper's PDU
  sizes) per second of mission;
- delay: from the frame handed to the modem to the end of its reception (intrinsic delay +
  airtime + propagation), mean;
- jitter: standard deviation of the delay (how the preset reads Table 3's "intrinsic jitter");
  also shown: the mean |ΔD| between consecutive frames (RFC 3550 / ns-3 FlowMonitor);
- IAT: time between consecutive frames received, mean and standard deviation. With bit errors
  a corrupt frame is dropped whole (CRC), so it is not an arrival; the IAT counting corrupt
  frames that still reached the modem is shown too, as one way to read the paper's 727 ms.

Each figure is printed beside what the model implies analytically (independent Gaussian delay
per frame, whole-frame loss ``1 - (1 - BER)^bits``, a reply only to a poll heard), the paper's
UWSim-NET column and its HIL column, with the ratio to the paper; ``!`` marks figures more than
10 % off. Nothing is fitted to the paper: the inputs are Table 3's figures, the frame sizes
and the 640 ms IPG.

``--realtime S`` also runs BER 0 for ``S`` wall seconds through the deployed runtime
(every node's Zenoh peer and asyncio bridge, the water service over loopback, applications
publishing through Zenoh), to show what the event loop and the OS add to the timing.

Run: ``uv run python bench/umci_table4.py [--duration 1800] [--seed 1] [--realtime 120]``.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import socket
import statistics
import time
from collections import defaultdict
from dataclasses import dataclass, field
from itertools import pairwise
from pathlib import Path
from typing import Any

import msgpack
import yaml
import zenoh

from bridge.core import Notice
from bridge.fastsim import FastFleet, Timed
from bridge.fleet import Fleet
from bridge.mission_loader import LoadedMission, load_mission, parse_mission
from bridge.ocean.model import Loss
from bridge.ocean.presets import get_preset

MISSION = Path(__file__).resolve().parent.parent / "deploy" / "missions" / "bluerov_rf.yaml"
DIRECTIONS = (("rov", "operator", "robot→operator"), ("operator", "rov", "operator→robot"))
METRICS = ("throughput_kbps", "delay_ms", "jitter_ms", "iat_ms", "iat_sd_ms")
LABELS = {"throughput_kbps": "throughput kbps", "delay_ms": "delay ms", "jitter_ms": "jitter ms",
          "iat_ms": "IAT ms", "iat_sd_ms": "IAT σ ms"}

# Table 4 of seed 002: (robot→operator, operator→robot) per column
PAPER: dict[str, dict[str, tuple[float, float]]] = {
    "HIL": {"throughput_kbps": (0.72, 0.2), "delay_ms": (368.4, 154.12),
            "jitter_ms": (13.42, 10.55), "iat_ms": (640.38, 640.53), "iat_sd_ms": (15.36, 8.89)},
    "BER 0 %": {"throughput_kbps": (0.72, 0.2), "delay_ms": (333.17, 158.99),
                "jitter_ms": (12.84, 10.05), "iat_ms": (640.21, 640.36),
                "iat_sd_ms": (16.43, 7.26)},
    "BER 0.07 %": {"throughput_kbps": (0.41, 0.18), "delay_ms": (333.1, 158.8),
                   "jitter_ms": (10.42, 9.05), "iat_ms": (726.56, 640.42),
                   "iat_sd_ms": (157.82, 6.82)},
}
TOLERANCE = 0.10


@dataclass
class Link:
    """What one receiver saw from one sender."""

    arrivals: list[float] = field(default_factory=list)
    delays: list[float] = field(default_factory=list)
    bits: int = 0
    corrupt: list[float] = field(default_factory=list)  # frames lost to bit errors, at the end

    def figures(self, duration: float) -> dict[str, float]:
        iat = [b - a for a, b in pairwise(self.arrivals)]
        iat_all = [b - a for a, b in pairwise(sorted(self.arrivals + self.corrupt))]
        steps = [abs(b - a) for a, b in pairwise(self.delays)]
        return {
            "frames": len(self.arrivals),
            "throughput_kbps": self.bits / duration / 1000,
            "delay_ms": 1000 * statistics.fmean(self.delays),
            "jitter_ms": 1000 * statistics.pstdev(self.delays),
            "delta_jitter_ms": 1000 * statistics.fmean(steps),
            "iat_ms": 1000 * statistics.fmean(iat),
            "iat_sd_ms": 1000 * statistics.pstdev(iat),
            "iat_with_corrupt_ms": 1000 * statistics.fmean(iat_all),
            "iat_with_corrupt_sd_ms": 1000 * statistics.pstdev(iat_all),
        }


COMMAND = {"oid": False, "clo": False, "order_type": 0, "eisn": False, "ic": False, "rit": 0,
           "vx": 0.3, "vy": 0.0, "vz": -0.1, "yaw_rate": 0.05, "arm": True,
           "hold_heading": False, "nav_mode": "manual", "lights": 40, "camera_tilt": 0.0,
           "gain": 0.5}
STATUS = {"st": 1, "ready": True, "eoid": False, "loc": False, "hold_heading": False,
          "armed": True, "nav_mode": "manual", "x": 1.0, "y": 2.0, "z": 1.5, "roll": 0.0,
          "pitch": 0.0, "yaw": 90.0}
IMAGE = {"ft": True, "lt": False, "isn": False, "ci": False, "itsn": 0, "trunk": bytes(range(41))}
INPUTS = (("operator", "rov/command", COMMAND), ("rov", "rov/status", STATUS),
          ("rov", "rov/image_trunk", IMAGE))


def run(loaded: LoadedMission, ber: float, duration: float, seed: int) -> dict[str, Any]:
    """One teleoperation of ``duration`` virtual seconds; figures per direction."""
    links: dict[tuple[str, str], Link] = defaultdict(Link)
    name = loaded.mission.name_of

    def on_output(timed: Timed) -> None:
        out = timed.output
        if isinstance(out, Notice) and out.kind == "frame_received":
            link = links[(out.info["src"], timed.node)]
            link.arrivals.append(timed.time)
            link.delays.append(timed.time - out.info["meta"]["sent_at"])
            link.bits += 8 * out.info["bytes"]

    preset = get_preset("s100-rf").replace(ber=ber)
    fleet = FastFleet(loaded, seed=seed, preset=preset, on_output=on_output, keep_outputs=False)
    advance = fleet.ocean.advance

    def advance_noting_corrupt_frames(now: float) -> list:
        events = advance(now)
        for event in events:
            if isinstance(event, Loss) and event.reason == "bit_errors":
                src, dst = name(event.src), name(event.dst)
                if src is not None and dst is not None:
                    links[(src, dst)].corrupt.append(event.time)
        return events

    fleet.ocean.advance = advance_noting_corrupt_frames  # type: ignore[method-assign]
    for node, key, value in INPUTS:
        fleet.put(node, key, value)
    started = time.perf_counter()
    fleet.run_until(duration)
    wall = time.perf_counter() - started
    return {
        "wall_s": wall,
        "duration": duration,
        "figures": {label: links[(src, dst)].figures(duration)
                    for src, dst, label in DIRECTIONS},
    }


def analytic(loaded: LoadedMission, ber: float, result: dict[str, Any]) -> dict[str, dict]:
    """What the model gives without simulating: Table 3's preset, the frame sizes seen, the IPG;
    Gaussian intrinsic delay independent per frame; a frame lost whole with probability
    ``1 - (1 - BER)^bits``; the ROV answers only the polls it decodes."""
    preset = get_preset("s100-rf")
    mission = loaded.mission
    ipg = mission.mac.ipg_s  # type: ignore[union-attr]
    a, b = (mission.nodes[n].position for n in ("operator", "rov"))
    distance = math.dist((a.x, a.y, a.depth), (b.x, b.y, b.depth))  # type: ignore[union-attr]
    size = {label: round(f["throughput_kbps"] * 1000 * result["duration"] / f["frames"] / 8)
            for label, f in result["figures"].items()}
    ok = {label: (1 - ber) ** (8 * n) for label, n in size.items()}
    poll, reply = ok["operator→robot"], ok["operator→robot"] * ok["robot→operator"]
    sigma = preset.jitter_s
    out = {}
    for label, success, hops in (("operator→robot", poll, 1), ("robot→operator", reply, 2)):
        gaps_sd = ipg * math.sqrt(1 - success) / success  # whole cycles between arrivals
        out[label] = {
            "throughput_kbps": 8 * size[label] * success / ipg / 1000,
            "delay_ms": 1000 * (preset.intrinsic_delay_s + preset.airtime(size[label])
                                + preset.propagation_s(max(distance, preset.min_range_m))),
            "jitter_ms": 1000 * sigma,
            "iat_ms": 1000 * ipg / success,
            "iat_sd_ms": 1000 * math.sqrt(gaps_sd ** 2 + 2 * hops * sigma ** 2),
        }
    return out


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


async def run_realtime(loaded: LoadedMission, duration: float, seed: int) -> dict[str, Any]:
    """BER 0 through the deployed runtime for ``duration`` wall seconds (see the docstring)."""
    data = yaml.safe_load(MISSION.read_text())
    for node in data["nodes"].values():
        node["zenoh"]["listen"] = [f"tcp/127.0.0.1:{free_port()}"]
    loaded = parse_mission(yaml.safe_dump(data, sort_keys=False), MISSION.name)
    links: dict[tuple[str, str], Link] = defaultdict(Link)

    def on_event(node: str, kind: str, info: dict[str, Any]) -> None:
        if kind == "frame_received":
            link = links[(info["src"], node)]
            link.arrivals.append(info["time"])
            link.delays.append(info["time"] - info["meta"]["sent_at"])
            link.bits += 8 * info["bytes"]

    fleet = Fleet(loaded, seed=seed, on_event=on_event)
    stop = asyncio.Event()
    runner = asyncio.create_task(fleet.run(stop))
    await fleet.ready.wait()
    apps = {}
    for name in ("operator", "rov"):
        config = zenoh.Config()
        config.insert_json5("mode", '"client"')
        config.insert_json5("connect/endpoints",
                            json.dumps(loaded.mission.nodes[name].zenoh.listen))
        config.insert_json5("scouting/multicast/enabled", "false")
        apps[name] = zenoh.open(config)
    try:
        await asyncio.sleep(1.0)
        for node, key, value in INPUTS:
            apps[node].put(key, msgpack.packb(value, use_bin_type=True),
                           encoding=zenoh.Encoding("application/msgpack"))
        await asyncio.sleep(2.0)  # the first exchange
        links.clear()
        started = time.perf_counter()
        await asyncio.sleep(duration)
        measured = {label: links[(src, dst)].figures(duration) for src, dst, label in DIRECTIONS}
    finally:
        for app in apps.values():
            app.close()
        stop.set()
        await runner
    return {"wall_s": time.perf_counter() - started, "duration": duration, "figures": measured}


def show(loaded: LoadedMission, column: str, ber: float, result: dict[str, Any]) -> list[str]:
    """Print one column of Table 4 beside ours; return the figures more than 10 % off."""
    paper, hil = PAPER[column], PAPER["HIL"]
    model = analytic(loaded, ber, result)
    off = []
    clock = result.get("clock", "virtual clock")
    print(f"\n== UWSim-NET {column} vs ours ({clock}, {result['wall_s']:.2f} s wall) ==")
    print(f"{'figure':<16} {'direction':<15} {'ours':>9} {'model':>9} {'paper':>9} "
          f"{'ours/paper':>10}   {'HIL':>8}")
    for metric in METRICS:
        for i, (_, _, label) in enumerate(DIRECTIONS):
            ours = result["figures"][label][metric]
            ratio = ours / paper[metric][i]
            flag = "!" if abs(ratio - 1) > TOLERANCE else " "
            if flag == "!":
                off.append(f"{column} {LABELS[metric]} {label}: {ours:.3g} vs "
                           f"{paper[metric][i]:.3g} (×{ratio:.2f})")
            print(f"{LABELS[metric]:<16} {label:<15} {ours:9.2f} {model[label][metric]:9.2f} "
                  f"{paper[metric][i]:9.2f} {ratio:9.2f}{flag}   {hil[metric][i]:8.2f}")
    for _, _, label in DIRECTIONS:
        f = result["figures"][label]
        print(f"  {label}: {f['frames']} frames; mean |ΔD| {f['delta_jitter_ms']:.2f} ms; "
              f"IAT counting corrupt frames {f['iat_with_corrupt_ms']:.2f} ms "
              f"(σ {f['iat_with_corrupt_sd_ms']:.2f} ms)")
    return off


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=1800.0,
                        help="virtual seconds of teleoperation per run")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--realtime", type=float, default=0.0, metavar="S",
                        help="also run BER 0 for S wall seconds through Zenoh and the water")
    args = parser.parse_args()
    loaded = load_mission(MISSION)
    print(f"mission {MISSION.name}: polled, IPG {loaded.mission.mac.ipg_s} s, "  # type: ignore[union-attr]
          f"{args.duration:g} s per run, seed {args.seed}")
    off = show(loaded, "BER 0 %", 0.0, run(loaded, 0.0, args.duration, args.seed))
    off += show(loaded, "BER 0.07 %", 0.0007, run(loaded, 0.0007, args.duration, args.seed))
    if args.realtime > 0:
        live = asyncio.run(run_realtime(loaded, args.realtime, args.seed))
        live["clock"] = "real time: Zenoh, asyncio bridges, the water service"
        off += [f"real time: {line}" for line in show(loaded, "BER 0 %", 0.0, live)]
    print(f"\n{len(off)} of {2 * 2 * len(METRICS)} figures more than 10 % from Table 4:")
    for line in off:
        print(f"  {line}")
    print(WHY)


WHY = """
Why the flagged figures differ (ours follow the model column; the paper's cannot, with Table 3
read as a Gaussian delay independent per frame):
- jitter: the paper's link jitter (9-10.5 ms operator→robot) is below its own modem's
  intrinsic jitter (13.2 ms, Table 3); a delay drawn per frame cannot vary less than its draw.
- IAT σ: with independent delays, σ(IAT) = √2·σ(delay) for a poll and 2·σ for a reply to it,
  so σ(IAT) ≥ jitter; the paper reports σ(IAT) below its jitter (7.3 < 10.1 ms), which needs
  delays correlated from one frame to the next. Table 3 gives no such figure, so we do not
  invent one.
- BER 0.07 %: our receiver drops a corrupt frame whole (CRC), so the IAT counts valid frames
  only; the ROV answers only polls it decodes, so robot→operator frames survive two draws.
  The paper's robot→operator IAT (727 ms) and operator→robot IAT (640 ms) match instead the IAT
  of every frame that reached the modem, corrupt or not (printed under each table), while its
  throughput (0.41 kbps) counts valid frames; ours is higher because our 57-byte frame is the
  whole PDU, where the paper's link layer adds its own header bytes for errors to hit."""


if __name__ == "__main__":
    main()
