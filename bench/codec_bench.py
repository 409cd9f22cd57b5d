"""Codec round trips per second: bridge.codec layouts vs WHOI's ltcodecs, measured in one run.

Run: ``uv run --group bench python bench/codec_bench.py [--seconds 0.5]``.
A round trip is ``encode`` to bytes then ``decode`` back to a dict, for three reference
layouts (MORPH Listing 1, CCL bathymetry, a navigation status). Prints bits and the ratio.
Then the same three in DCCL wire format (``deploy/missions/dccl/auv.proto``, bytes as
libdccl writes them), under each numeric rule (``dccl-4.2``, ``dccl-2026``), against
libdccl's recorded round trips per second on this machine class (:data:`LIBDCCL_RT_S`;
libdccl is not installable here, so not re-measured). Last, whole frames of the MORPH
mission (DLBL on) as plain, authenticated (HMAC) and sealed (AES-CCM, ``wire.auth.encrypt``):
bytes, bytes added, and encode+decode round trips per second, each against plain in the same
run (``--frames-only`` for these alone).
"""

from __future__ import annotations

import argparse
import random
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bridge.codec import Layout
from bridge.dccl import RULES, load_message

MORPH = [
    {"field": "vector.x", "bits": 8, "min": 0, "max": 6.2831},
    {"field": "vector.y", "bits": 6, "min": -0.052359878, "max": 0.052359878},
]
BATHY = [
    {"field": "depth", "type": "float", "min": 0, "max": 1000, "resolution": 0.1, "count": 3},
    {"field": "altitude", "type": "float", "min": 0, "max": 655, "resolution": 0.1, "count": 3},
    {"field": "latitude", "codec": "ccl.latitude", "count": 3},
    {"field": "longitude", "codec": "ccl.longitude", "count": 3},
]
MODES = ["idle", "dive", "survey", "transit", "surface", "hold", "abort", "home"]
NAV = [
    {"field": "lat", "min": -90, "max": 90, "resolution": 1e-6},
    {"field": "lon", "min": -180, "max": 180, "resolution": 1e-6},
    {"field": "depth", "min": 0, "max": 6000, "resolution": 0.1},
    {"field": "heading", "min": 0, "max": 360, "resolution": 0.1},
    {"field": "speed", "min": 0, "max": 5, "resolution": 0.01},
    {"field": "battery", "type": "int", "min": 0, "max": 100},
    {"field": "mode", "values": MODES},
    {"field": "time", "type": "int", "min": 0, "max": 86400},
]
MINIMUM_BITS = {"MORPH": 14, "CCL bathymetry": 225, "nav status": 121}
#: libdccl 4 encode+decode round trips per second, recorded for issue #17 (same machine class).
LIBDCCL_RT_S = {"MORPH": 63_000, "CCL bathymetry": 22_000, "nav status": 30_000}
DCCL_MESSAGES = {"MORPH": "MorphVector", "CCL bathymetry": "Bathymetry",
                 "nav status": "NavStatus"}
AUV_PROTO = Path(__file__).resolve().parents[1] / "deploy" / "missions" / "dccl" / "auv.proto"


def _lin(lo: float, hi: float, *, resolution: float | None = None, bits: int | None = None) -> dict:
    params: dict[str, Any] = {"codec": "linspace_float", "min_value": lo, "max_value": hi}
    params.update({"resolution": resolution} if resolution else {"num_bits": bits})
    return params


LT_MORPH = {
    "vector": {
        "codec": "dict",
        "fields": {"x": _lin(0, 6.2831, bits=8), "y": _lin(-0.052359878, 0.052359878, bits=6)},
    }
}
LT_BATHY = {
    "depth": {
        "codec": "fixed_len_array",
        "element_type": "linspace_float",
        "length": 3,
        "element_params": {"min_value": 0, "max_value": 1000, "resolution": 0.1},
    },
    "altitude": {
        "codec": "fixed_len_array",
        "element_type": "linspace_float",
        "length": 3,
        "element_params": {"min_value": 0, "max_value": 655, "resolution": 0.1},
    },
    "latitude": {"codec": "fixed_len_array", "element_type": "ccl_latlon", "length": 3},
    "longitude": {"codec": "fixed_len_array", "element_type": "ccl_latlon", "length": 3},
}
LT_NAV = {
    "lat": _lin(-90, 90, resolution=1e-6),
    "lon": _lin(-180, 180, resolution=1e-6),
    "depth": _lin(0, 6000, resolution=0.1),
    "heading": _lin(0, 360, resolution=0.1),
    "speed": _lin(0, 5, resolution=0.01),
    "battery": {"codec": "integer", "min_value": 0, "max_value": 100},
    "mode": {"codec": "string_enum", "entries": MODES},
    "time": {"codec": "integer", "min_value": 0, "max_value": 86400},
}


def samples(name: str, rng: random.Random, n: int = 64) -> list[dict[str, Any]]:
    """Random in-range payloads for a reference layout."""
    out: list[dict[str, Any]] = []
    for _ in range(n):
        if name == "MORPH":
            out.append({"vector": {"x": rng.uniform(0, 6.2831), "y": rng.uniform(-0.05, 0.05)}})
        elif name == "CCL bathymetry":
            out.append(
                {
                    "depth": [rng.uniform(0, 1000) for _ in range(3)],
                    "altitude": [rng.uniform(0, 655) for _ in range(3)],
                    "latitude": [rng.uniform(-90, 90) for _ in range(3)],
                    "longitude": [rng.uniform(-180, 180) for _ in range(3)],
                }
            )
        else:
            out.append(
                {
                    "lat": rng.uniform(-90, 90),
                    "lon": rng.uniform(-180, 180),
                    "depth": rng.uniform(0, 6000),
                    "heading": rng.uniform(0, 360),
                    "speed": rng.uniform(0, 5),
                    "battery": rng.randint(0, 100),
                    "mode": rng.choice(MODES),
                    "time": rng.randint(0, 86400),
                }
            )
    return out


def rate(round_trip: Callable[[dict[str, Any]], Any], values: list[dict], seconds: float,
         clock: Callable[[], float] = time.perf_counter) -> float:
    """Round trips per second over ``values`` for about ``seconds`` of ``clock``."""
    done, start = 0, clock()
    deadline = start + seconds
    while True:
        for v in values:
            round_trip(v)
        done += len(values)
        now = clock()
        if now >= deadline:
            return done / (now - start)


def dccl_rows(seconds: float) -> list[tuple[str, str, int, float, float]]:
    """(name, numeric rule, max bytes, our round trips/s, libdccl's recorded) for the DCCL
    messages under each rule."""
    rows = []
    for name, message in DCCL_MESSAGES.items():
        values = samples(name, random.Random(1))
        for rule in RULES:
            msg = load_message(AUV_PROTO, message, rule)
            # the generated path measured here writes the exact reference path's bytes
            assert all(msg.encode(v) == msg.encode_reference(v) for v in values), name

            def ours(v: dict, msg: Any = msg) -> Any:
                return msg.decode(msg.encode(v))

            # the best of five slices of CPU time, as timeit takes the least: the recorded
            # libdccl rates are from an idle machine, and this one is shared
            best = max(rate(ours, values, seconds / 5, time.process_time) for _ in range(5))
            rows.append((name, rule, msg.max_size, best, LIBDCCL_RT_S[name]))
    return rows


def print_dccl(seconds: float) -> None:
    """The DCCL-format table."""
    head = (f"{'DCCL message':<15} {'rule':<10} {'bytes':>5} {'zab rt/s':>12} "
            f"{'libdccl rt/s':>13} {'ratio':>7}")
    print(head)
    print("-" * len(head))
    for name, rule, nbytes, r_ours, r_lib in dccl_rows(seconds):
        print(f"{name:<15} {rule:<10} {nbytes:>5} {r_ours:>12,.0f} {r_lib:>13,.0f} "
              f"{r_ours / r_lib:>6.1f}×")
    print("DCCL wire format (deploy/missions/dccl/auv.proto); zab rt/s: the best of five "
          "slices of CPU time; libdccl rt/s as recorded.")


FRAME_KEY = b"0123456789abcdef0123456789abcdef"
FRAME_MODES = {"plain": None, "authenticated": {"tag_bytes": 4},
               "sealed": {"tag_bytes": 4, "encrypt": True}}
MORPH_MISSION = Path(__file__).resolve().parents[1] / "deploy" / "missions" / "morph.yaml"
DELAYS = [1000, None, 250_000, 7]  # the DLBL delays of gcv's frame, µs
NOW = 1_700_000_000.0  # the clock sealed frames choose their key by


def frame_rows(seconds: float) -> list[tuple[str, int, float]]:
    """(mode, frame bytes, round trips per second) of a MORPH frame carrying one
    ``target_reference`` and the DLBL delays, from gcv (address 1) to lsv (address 3)."""
    import yaml

    from bridge.core.loaded import parse_mission
    from bridge.wire.frame import FrameCodec
    from bridge.wire.seal import frame_authenticator

    rows = []
    for mode, auth in FRAME_MODES.items():
        data = yaml.safe_load(MORPH_MISSION.read_text())
        data["wire"]["auth"] = auth if auth is not None else "off"
        table = parse_mission(yaml.safe_dump(data, sort_keys=False), "morph.yaml").table
        sender, receiver = (FrameCodec(table, frame_authenticator(table, FRAME_KEY, a)
                                       if auth is not None else None) for a in (1, 3))
        channel = table.by_name("target_reference")
        items = [(channel, channel.pack([{"vector": {"x": 3.0, "y": 0.02}}]))]

        def trip(_: Any, s: FrameCodec = sender, r: FrameCodec = receiver,
                 i: Any = items) -> Any:
            return r.decode(s.encode(i, DELAYS, now=NOW), 1, now=NOW)

        size = len(sender.encode(items, DELAYS, now=NOW))
        best = max(rate(trip, [{}] * 16, seconds / 5, time.process_time) for _ in range(5))
        rows.append((mode, size, best))
    return rows


def print_frames(seconds: float) -> None:
    """The frames table: plain, authenticated and sealed, each against plain."""
    rows = frame_rows(seconds)
    plain_bytes, plain_rate = rows[0][1], rows[0][2]
    head = f"{'MORPH frame':<15} {'bytes':>5} {'added':>5} {'rt/s':>12} {'vs plain':>9}"
    print(head)
    print("-" * len(head))
    for mode, size, r in rows:
        print(f"{mode:<15} {size:>5} {size - plain_bytes:>+5} {r:>12,.0f} "
              f"{r / plain_rate:>8.2f}×")
    print("a frame of one target_reference and 4 DLBL delays, gcv to lsv: FrameCodec.encode "
          "then decode (sealing and opening included); rt/s: the best of five slices of CPU "
          "time.")


def main(seconds: float = 0.5) -> None:
    """Measure and print the table."""
    from bitstring import ConstBitStream
    from ltcodecs import DictCodec

    rng = random.Random(1)
    rows = []
    for name, fields, lt_fields in (
        ("MORPH", MORPH, LT_MORPH),
        ("CCL bathymetry", BATHY, LT_BATHY),
        ("nav status", NAV, LT_NAV),
    ):
        layout = Layout.from_fields(fields)
        lt = DictCodec(lt_fields)
        values = samples(name, rng)

        def ours(v: dict, layout: Layout = layout) -> Any:
            return layout.decode(layout.encode(v))

        def ours_int(v: dict, layout: Layout = layout) -> Any:
            return layout.unpack(layout.pack(v))

        def theirs(v: dict, lt: DictCodec = lt) -> Any:
            bits, _ = lt.encode(v)
            return lt.decode(ConstBitStream(bits.tobytes()))

        r_ours, r_int, r_lt = (rate(f, values, seconds) for f in (ours, ours_int, theirs))
        rows.append((name, layout.bits, lt.max_length_bits, r_ours, r_int, r_lt))

    head = (
        f"{'layout':<15} {'bits':>5} {'min':>5} {'lt bits':>8} {'bytes rt/s':>12} "
        f"{'int rt/s':>12} {'ltcodecs rt/s':>14} {'ratio':>7}"
    )
    print(head)
    print("-" * len(head))
    for name, bits, lt_bits, r_ours, r_int, r_lt in rows:
        print(
            f"{name:<15} {bits:>5} {MINIMUM_BITS[name]:>5} {lt_bits:>8} {r_ours:>12,.0f} "
            f"{r_int:>12,.0f} {r_lt:>14,.0f} {r_ours / r_lt:>6.1f}×"
        )
    print("rt/s = encode+decode round trips per second (bytes: encode/decode; int: pack/unpack);")
    print("ratio = bytes round trips vs ltcodecs, same payloads, same run.")
    print()
    print_dccl(seconds)
    print()
    print_frames(seconds)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=0.5, help="time per measurement")
    parser.add_argument("--dccl-only", action="store_true",
                        help="only the DCCL rows (no ltcodecs needed)")
    parser.add_argument("--frames-only", action="store_true",
                        help="only the frame rows: plain, authenticated, sealed")
    args = parser.parse_args()
    if args.dccl_only:
        print_dccl(args.seconds)
    elif args.frames_only:
        print_frames(args.seconds)
    else:
        main(args.seconds)
