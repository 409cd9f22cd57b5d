"""What putting a mission log on disk every second costs, against the writer that only wrote a
chunk when 32 KiB had gathered (and so left a killed node's log empty), in one run:

- per event: the time ``MissionLog(event)`` takes (the bridge's thread waits for it) for a
  node's real events, with the flusher thread off, on (every ``FLUSH_S``) and every 0.05 s,
  and the longest single call (one that waited for a flush);
- per flush: how long :meth:`MissionLog.flush` takes (closing a chunk, under the writer's
  lock, then fsync, outside it) after ``--per-flush`` events (a second of a busy node's);
- the file's size (a chunk a second compresses less than a 32 KiB one);
- a whole fleet on the virtual clock (``zab sim --fast --log``): wall time without logs, with
  the old writer's behaviour and with the flusher.

Run: ``uv run python bench/logbook_bench.py [--events 20000] [--fast-s 1800]``.
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import tempfile
import time
from pathlib import Path

from bridge.cli.sim_fast import run_fast
from bridge.core.events import Event
from bridge.core.loaded import LoadedMission, load_mission
from bridge.runtime.logbook import FLUSH_S, FleetLogs, MissionLog
from bridge.runtime.virtual_fleet import FastFleet, Timed

MISSION = Path(__file__).resolve().parent.parent / "deploy" / "missions" / "morph.yaml"


def node_events(loaded: LoadedMission, seconds: float) -> tuple[str, list[Event]]:
    """The events of the busiest node of a virtual-clock run of ``seconds``."""
    events: dict[str, list[Event]] = {}

    def keep(timed: Timed) -> None:
        if isinstance(timed.output, Event):
            events.setdefault(timed.node, []).append(timed.output)

    fleet = FastFleet(loaded, seed=1, on_output=keep, kinds=(Event,))
    fleet.run_until(seconds)  # (no inputs: heartbeats, ranges, links)
    node = max(events, key=lambda n: len(events[n]))
    return node, events[node]


def per_event_us(loaded: LoadedMission, node: str, events: list[Event], count: int,
                 flush_s: float | None, path: Path) -> tuple[float, float, int]:
    """Microseconds per logged event, the longest one call took (one that waited while the
    flusher closed a chunk), and the file's size."""
    log = MissionLog(path, loaded, node, flush_s=flush_s)
    longest = 0.0
    start = time.perf_counter()
    for k in range(count):
        before = time.perf_counter()
        log(events[k % len(events)])
        longest = max(longest, time.perf_counter() - before)
    mean = (time.perf_counter() - start) / count * 1e6
    log.close()
    return mean, longest * 1e6, path.stat().st_size


def flush_ms(loaded: LoadedMission, node: str, events: list[Event], per_flush: int,
             flushes: int, folder: Path) -> list[float]:
    """Milliseconds per :meth:`MissionLog.flush` (chunk closed, written, fsynced) after
    ``per_flush`` events, ``flushes`` times."""
    log = MissionLog(folder / "flushes.mcap", loaded, node, flush_s=None)
    took = []
    for i in range(flushes):
        for k in range(per_flush):
            log(events[(i * per_flush + k) % len(events)])
        start = time.perf_counter()
        log.flush()
        took.append((time.perf_counter() - start) * 1e3)
    log.close()
    return took


def fleet_s(loaded: LoadedMission, seconds: float, logs: FleetLogs | None) -> float:
    """Wall seconds of a virtual-clock run of the whole fleet."""
    start = time.perf_counter()
    asyncio.run(run_fast(loaded, duration=seconds, seed=1, record=logs))
    took = time.perf_counter() - start
    if logs is not None:
        logs.close()
    return took


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--events", type=int, default=20_000)
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--per-flush", type=int, default=20, help="events between flushes")
    parser.add_argument("--flushes", type=int, default=100)
    parser.add_argument("--fast-s", type=float, default=1800.0, help="virtual seconds")
    args = parser.parse_args()
    loaded = load_mission(MISSION)
    node, events = node_events(loaded, 600)
    print(f"{MISSION.name}: {len(events)} events of {node} in 600 virtual seconds")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        rows = {"no flusher (old)": None, f"every {FLUSH_S:g} s": FLUSH_S,
                "every 0.05 s (stress)": 0.05}
        measured: dict[str, tuple[float, float, int]] = {}
        for i in range(args.rounds):  # interleaved, the best of each: a busy host's noise
            for name, flush_s in rows.items():
                got = per_event_us(loaded, node, events, args.events, flush_s,
                                   folder / f"events-{flush_s}-{i}.mcap")
                was = measured.get(name, got)
                measured[name] = (min(was[0], got[0]), min(was[1], got[1]), got[2])
        base = measured["no flusher (old)"][0]
        for name, (mean, longest, size) in measured.items():
            print(f"per event, {name:22}: {mean:5.1f} µs ({mean / base:.2f}x), longest call "
                  f"{longest / 1e3:6.2f} ms, file {size} B")
        took = flush_ms(loaded, node, events, args.per_flush, args.flushes, folder)
        print(f"a flush after {args.per_flush} events (chunk + fsync): median "
              f"{statistics.median(took):.2f} ms, max {max(took):.2f} ms, on the flusher's "
              f"thread once every {FLUSH_S:g} s")
        old_size = measured["no flusher (old)"][2]
        small = (folder / "flushes.mcap").stat().st_size
        print(f"file size: {args.events} events {old_size} B in 32 KiB chunks; "
              f"{args.flushes * args.per_flush} events in {args.flushes} chunks of "
              f"{args.per_flush}: {small} B ({small / (args.flushes * args.per_flush):.0f} "
              f"B/event against {old_size / args.events:.0f})")
        fleet: dict[str, float] = {}
        for i in range(3):  # interleaved, the best of three
            for name, flush_s in (("bare", None), ("old", None), ("new", FLUSH_S)):
                logs = None if name == "bare" else FleetLogs(folder / f"{name}{i}", loaded,
                                                             flush_s)
                fleet[name] = min(fleet.get(name, float("inf")),
                                  fleet_s(loaded, args.fast_s, logs))
        bare, old, new = fleet["bare"], fleet["old"], fleet["new"]
        print(f"zab sim --fast {args.fast_s:g} s of {MISSION.stem}: {bare:.2f} s without "
              f"logs, {old:.2f} s logged without the flusher ({old / bare:.2f}x), {new:.2f} s "
              f"with it ({new / bare:.2f}x; {new / old:.2f}x the old)")


if __name__ == "__main__":
    main()
