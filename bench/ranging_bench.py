"""Ranging error vs distance and localisation error vs timing noise, over simulated runs.

Ranging (table 1): two nodes at 12–150 m in 0.9 m deep water, on a two-slot TDMA cycle, with
clocks ±50 ppm apart, reception timestamps jittered by ``--jitter`` µs and, as seed 001
observed at a jetty, a share of receptions locked onto the surface reflection (a path longer by
``√(d² + (2h)²) − d``, which shrinks with distance). Each row gives the error of DLBL from one
side, from one side after learning the peer's clock rate from its TDMA cycle, both sides
combined (:func:`~bridge.ranging.dlbl.two_sided`), and explicit two-way ranging; the baseline
is the same jitter without reflections or drift.

Localisation (table 2): seed 001's static geometry, anchors at (25.4, 19.3) m and
(−17.4, 20.8) m and the node at the origin, every timestamp jittered by σ_t; two anchors
(circle intersection) and with a third at (4, −24) m (least squares). The baseline is the
prediction ``σ_r · √trace((JᵀJ)⁻¹)``; the ratio column is measured RMS over predicted.

Modem ranges (table 3): the real drivers over emulated modems on ptys, 150 m apart in the
simulated water. One two-way exchange a → b → a as DLBL does it, with host-timed sends
(``AT*SENDIM``: host clock, reception at the host's parse time) and modem-timed sends
(``AT*SENDIMS`` on the modem's µs clock, the modem's reception stamps); the EvoLogics
``propagation`` time (``AT?T`` after an acknowledged IM); the Micro-Modem ``ping``. The
baseline is the host-timed DLBL exchange; ×base is RMS error over the baseline's.

Run: ``uv run python bench/ranging_bench.py [--runs 400] [--modem-runs 20] [--plot FILE]``.
"""

from __future__ import annotations

import argparse
import asyncio
import math
import random
import statistics
import tempfile
import time
from pathlib import Path

from bridge.ranging.dlbl import DlblRanger, Range, two_sided
from bridge.ranging.localise import dop, locate
from bridge.ranging.twr import travel_time

C = 1480.0
DEPTH = 0.9
DISTANCES = (12.6, 20.9, 33.5, 50.0, 90.0, 150.0)
TIMING_US = (5, 10, 25, 50, 100, 200)
SEED_ANCHORS = [(25.4, 19.3, DEPTH), (-17.4, 20.8, DEPTH)]
THIRD = (4.0, -24.0, DEPTH)


def reflection_extra_s(distance: float) -> float:
    """Extra travel time of the surface-reflected path between two hydrophones at DEPTH."""
    return (math.hypot(distance, 2 * DEPTH) - distance) / C


def dlbl_run(
    distance: float,
    rnd: random.Random,
    *,
    cycles: int,
    jitter_s: float,
    drift: float,
    reflect_p: float,
    learn: bool,
) -> tuple[list[float], list[float]]:
    """One-sided and two-sided travel-time errors (s) from a two-node TDMA exchange."""
    slot = 1.5
    clocks = {"a": (123.0, drift / 2), "b": (-45.0, -drift / 2)}  # offset, rate error
    rangers = {
        n: DlblRanger(n, ["a", "b"], cycle_s=2 * slot if learn else None) for n in ("a", "b")
    }
    tau = distance / C
    one: list[float] = []
    got: dict[tuple[str, int], Range] = {}
    for k in range(cycles):
        for i, (src, dst) in enumerate((("a", "b"), ("b", "a"))):
            off, eps = clocks[src]
            start = off + k * 2 * slot + i * slot
            emitted = (start - off) / (1 + eps)
            delays = rangers[src].on_transmit(start)
            arrival = emitted + tau
            if rnd.random() < reflect_p:
                arrival += reflection_extra_s(distance)
            off_d, eps_d = clocks[dst]
            stamp = off_d + (1 + eps_d) * arrival + rnd.gauss(0, jitter_s)
            for rng in rangers[dst].on_receive(src, stamp, delays):
                if k >= 10:  # after the clock rate is learned
                    one.append(rng.travel_time_s - tau)
                got[(dst, k)] = rng
    two = [
        two_sided(got[("a", k)], got[("b", k)]) - tau
        for k in range(10, cycles)
        if ("a", k) in got and ("b", k) in got
    ]
    return one, two


def twr_errors(
    distance: float, rnd: random.Random, n: int, jitter_s: float, reflect_p: float
) -> list[float]:
    """Explicit two-way ranging errors (s): four jittered stamps, reflections on both legs."""
    out = []
    for _ in range(n):
        legs = sum(reflection_extra_s(distance) for _ in range(2) if rnd.random() < reflect_p)
        tp = 0.3
        t_rx = 2 * distance / C + legs + tp + rnd.gauss(0, jitter_s)
        tp_m = tp + rnd.gauss(0, jitter_s) - rnd.gauss(0, jitter_s)
        out.append(travel_time(rnd.gauss(0, jitter_s), t_rx, tp_m) - distance / C)
    return out


def stats_cm(errors_s: list[float]) -> tuple[float, float, float]:
    """Mean, standard deviation and 95th percentile of |error|, in cm."""
    m = [e * C * 100 for e in errors_s]
    p95 = sorted(abs(v) for v in m)[int(0.95 * (len(m) - 1))]
    return statistics.fmean(m), statistics.pstdev(m), p95


def ranging_table(runs: int, jitter_us: float, reflect_p: float, seed: int) -> list[dict]:
    rows = []
    print(
        f"\nRanging error vs distance ({runs} exchanges each; jitter {jitter_us:g} µs, "
        f"±50 ppm clocks, {reflect_p:.0%} surface-reflection locks)"
    )
    head = (
        f"{'d (m)':>7} | {'method':<22} | {'mean cm':>8} {'σ cm':>7} {'p95 cm':>7} | {'×base':>6}"
    )
    print(head)
    print("-" * len(head))
    for d in DISTANCES:
        rnd = random.Random(seed + int(d * 10))
        jit = jitter_us * 1e-6
        cycles = runs + 10
        base, _ = dlbl_run(d, rnd, cycles=cycles, jitter_s=jit, drift=0, reflect_p=0, learn=False)
        raw, two = dlbl_run(
            d, rnd, cycles=cycles, jitter_s=jit, drift=100e-6, reflect_p=reflect_p, learn=False
        )
        learned, _ = dlbl_run(
            d, rnd, cycles=cycles, jitter_s=jit, drift=100e-6, reflect_p=reflect_p, learn=True
        )
        twr = twr_errors(d, rnd, runs, jit, reflect_p)
        b_sigma = stats_cm(base)[1]
        for name, errs in (
            ("baseline (jitter only)", base),
            ("dlbl one side", raw),
            ("dlbl learned rate", learned),
            ("dlbl two sides", two),
            ("twr", twr),
        ):
            mean, sd, p95 = stats_cm(errs)
            rms = math.hypot(mean, sd)
            print(
                f"{d:7.1f} | {name:<22} | {mean:8.2f} {sd:7.2f} {p95:7.2f} | {rms / b_sigma:6.2f}"
            )
            rows.append({"d": d, "method": name, "mean": mean, "sd": sd, "p95": p95})
    return rows


def localisation_table(runs: int, seed: int) -> list[dict]:
    rows = []
    print(f"\nLocalisation error vs timing noise, seed 001 geometry ({runs} fixes each)")
    head = (
        f"{'σt µs':>6} | {'σr cm':>6} | {'anchors':>7} | {'rms cm':>7} {'p95 cm':>7} | "
        f"{'pred cm':>7} {'×pred':>6}"
    )
    print(head)
    print("-" * len(head))
    node = (0.0, 0.0, DEPTH)
    for sigma_us in TIMING_US:
        rnd = random.Random(seed + sigma_us)
        sig = sigma_us * 1e-6
        for anchors in (SEED_ANCHORS, [*SEED_ANCHORS, THIRD]):
            errs, rerr = [], []
            for _ in range(runs):
                ranges = []
                for a in anchors:
                    (err,) = twr_errors(math.dist(node, a), rnd, 1, sig, 0.0)
                    ranges.append(math.dist(node, a) + err * C)
                    rerr.append(err * C)
                fix = locate(anchors, ranges, DEPTH, previous=(0.5, 0.5), range_sigma_m=C * sig)
                if fix is not None:
                    errs.append(math.hypot(fix.x, fix.y))
            sr = math.sqrt(statistics.fmean(e * e for e in rerr))
            rms = math.sqrt(statistics.fmean(e * e for e in errs))
            p95 = sorted(errs)[int(0.95 * (len(errs) - 1))]
            pred = sr * dop(anchors, DEPTH, (0.0, 0.0))
            print(
                f"{sigma_us:6d} | {sr * 100:6.2f} | {len(anchors):7d} | {rms * 100:7.2f} "
                f"{p95 * 100:7.2f} | {pred * 100:7.2f} {rms / pred:6.2f}"
            )
            rows.append({"sigma_us": sigma_us, "anchors": len(anchors), "rms": rms, "p95": p95})
    return rows


MODEM_DISTANCE_M = 150.0


async def _evologics_errors(runs: int, folder: Path) -> dict[str, list[float]]:
    """Travel-time errors (s) through the EvoLogics driver: DLBL host- and modem-timed, AT?T."""
    from bridge.mission.presets import get_preset
    from bridge.modems.base import ModemSetup
    from bridge.modems.evologics.driver import EvologicsBackend
    from bridge.modems.evologics.emulator import EvologicsEmulator
    from bridge.sim.ocean import LossCurve
    from bridge.sim.service import WaterService

    preset = get_preset("evologics-s2c-im").replace(overhead_s=0.02, per_byte_s=0.001)
    where = {1: (0.0, 0.0, 5.0), 2: (MODEM_DISTANCE_M, 0.0, 5.0)}
    tau = MODEM_DISTANCE_M / preset.sound_speed_mps
    water = WaterService(preset, seed=1, loss_curve=LossCurve(edge_loss=0.0))
    port = await water.start()
    emulators = {}
    out: dict[str, list[float]] = {}
    try:
        for a in where:
            setup = ModemSetup(node=f"n{a}", address=a, frame_bytes=64,
                               options={"water": f"127.0.0.1:{port}"}, position=where[a])
            emulators[a] = EvologicsEmulator(setup, link=folder / f"evo{a}", positions=where)
            await emulators[a].start()

        def driver(a: int, **options: object) -> EvologicsBackend:
            return EvologicsBackend(ModemSetup(node=f"n{a}", address=a, frame_bytes=64, options={
                "device": str(folder / f"evo{a}"), "timeout_s": 1.0, **options}))

        for name, timed in (("dlbl host-timed", False), ("dlbl modem-timed", True)):
            a, b = driver(1, timed_send=timed), driver(2, timed_send=timed)
            async with a, b:
                errs = out[name] = []
                lead = a.tx_lead_s if timed else 0.0  # as the runtime does
                for _ in range(runs):
                    at_a = a.clock() + lead
                    await a.send(b"request", 2, at=at_a)
                    rx_b = await asyncio.wait_for(b.recv(), 5)
                    at_b = b.clock() + lead
                    await b.send(b"reply", 1, at=at_b)
                    rx_a = await asyncio.wait_for(a.recv(), 5)
                    two_way = (rx_a.meta["start"] - at_a) - (at_b - rx_b.meta["start"])
                    errs.append(two_way / 2 - tau)
        a, b = driver(1, ack=True), driver(2)
        async with a, b:
            got: list[float] = []
            a.on_range = lambda rng: got.append(rng.travel_time_s - tau)
            for _ in range(runs):
                await a.send(b"acked", 2, ack=True)
                await asyncio.wait_for(b.recv(), 5)
            out["propagation (AT?T)"] = got
    finally:
        for emulator in emulators.values():
            await emulator.stop()
        await water.stop()
    return out


async def _micromodem_errors(runs: int, folder: Path) -> list[float]:
    """Travel-time errors (s) of the Micro-Modem ping through its driver."""
    from bridge.mission.presets import get_preset
    from bridge.modems.base import ModemSetup
    from bridge.modems.micromodem.driver import MicromodemBackend
    from bridge.modems.micromodem.emulator import MicromodemEmulator
    from bridge.sim.service import WaterService

    preset = get_preset("micromodem-rate0").replace(bitrate_bps=3200.0, overhead_s=0.05)
    where = {1: (0.0, 0.0, 5.0), 2: (MODEM_DISTANCE_M, 0.0, 5.0)}
    water = WaterService(preset, seed=1, positions=where)
    port = await water.start()
    emulators = []
    errs: list[float] = []
    try:
        for a in where:
            setup = ModemSetup(node=f"n{a}", address=a, frame_bytes=32,
                               options={"water": f"127.0.0.1:{port}"}, position=where[a])
            emulator = MicromodemEmulator(setup, link=folder / f"mm{a}", rev_period_s=None)
            await emulator.open()
            emulators.append(emulator)
        modem = MicromodemBackend(ModemSetup(node="n1", address=1, frame_bytes=32, options={
            "device": str(folder / "mm1"), "timeout_s": 1.0}))
        async with modem:
            for _ in range(runs):
                rng = await modem.ping(2)
                errs.append(rng.travel_time_s - MODEM_DISTANCE_M / preset.sound_speed_mps)
    finally:
        for emulator in emulators:
            await emulator.close()
        await water.stop()
    return errs


def modem_table(runs: int) -> list[dict]:
    """Table 3: ranges through the real drivers over emulated modems."""
    with tempfile.TemporaryDirectory() as tmp:
        started = time.time()
        rows = asyncio.run(_evologics_errors(runs, Path(tmp)))
        rows["ping (Micro-Modem)"] = asyncio.run(_micromodem_errors(runs, Path(tmp)))
        took = time.time() - started
    print(f"\nModem ranges through the drivers, emulated modems {MODEM_DISTANCE_M:g} m apart "
          f"({runs} each, {took:.0f} s)")
    head = f"{'method':<22} | {'mean cm':>8} {'σ cm':>7} {'p95 cm':>7} | {'×base':>8}"
    print(head)
    print("-" * len(head))
    base = stats_cm(rows["dlbl host-timed"])
    base_rms = math.hypot(base[0], base[1])
    out = []
    for name, errs in rows.items():
        mean, sd, p95 = stats_cm(errs)
        print(f"{name:<22} | {mean:8.2f} {sd:7.2f} {p95:7.2f} | "
              f"{math.hypot(mean, sd) / base_rms:8.5f}")
        out.append({"method": name, "mean": mean, "sd": sd, "p95": p95})
    return out


def plot(ranging: list[dict], local: list[dict], path: str) -> None:
    try:
        import matplotlib  # type: ignore[import-not-found]

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt  # type: ignore[import-not-found]
    except ImportError:
        return
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4))
    for method in dict.fromkeys(r["method"] for r in ranging):
        pts = [(r["d"], r["p95"]) for r in ranging if r["method"] == method]
        ax1.plot(*zip(*pts, strict=True), marker="o", label=method)
    ax1.set(xlabel="distance (m)", ylabel="95th percentile |error| (cm)", title="Ranging")
    ax1.legend(fontsize=8)
    for n in (2, 3):
        pts = [(r["sigma_us"], r["p95"] * 100) for r in local if r["anchors"] == n]
        ax2.plot(*zip(*pts, strict=True), marker="o", label=f"{n} anchors")
    ax2.set(
        xscale="log",
        xlabel="timestamp σ (µs)",
        ylabel="95th percentile error (cm)",
        title="Localisation, seed 001 geometry",
    )
    ax2.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    print(f"\nplot: {path}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=400)
    parser.add_argument("--jitter", type=float, default=20.0, help="timestamp jitter, µs")
    parser.add_argument("--reflect", type=float, default=0.3, help="share of reflection locks")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--modem-runs", type=int, default=20,
                        help="exchanges per method through the emulated modems (0: skip)")
    parser.add_argument("--plot", default="ranging_bench.png")
    args = parser.parse_args()
    ranging = ranging_table(args.runs, args.jitter, args.reflect, args.seed)
    local = localisation_table(args.runs * 5, args.seed)
    if args.modem_runs > 0:
        modem_table(args.modem_runs)
    plot(ranging, local, args.plot)


if __name__ == "__main__":
    main()
