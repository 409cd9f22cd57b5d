"""Random and mutated frames into the frame decoder: only FrameError, and no false deliveries.

Run: ``uv run python bench/fuzz_frames.py [--frames 1000000] [--seed 1]``.

A mission with every kind of entry (plain, reliable, fragmented, acknowledgements, DLBL) is
encoded into valid frames by one node and fed, mutated, to another node's decoder, with and
without authentication. Mutations: random bytes of random length, bit flips, byte changes,
truncation, extension, splices of two frames, and the frame unchanged (a replay when
authenticated). Prints, per case, how the decoder answered: ``ok`` (accepted), each FrameError
reason, and any other exception (which must be zero). With authentication on, a mutated
frame accepted is a false delivery (must be zero); without it the 16-bit check lets about one
in 65,536 changed frames through, which the table shows.
"""

from __future__ import annotations

import argparse
import os
import random
import time
from collections import Counter
from collections.abc import Callable

from bridge.core.loaded import parse_mission
from bridge.errors import FrameError
from bridge.wire.auth import Authenticator
from bridge.wire.frame import FrameCodec

MISSION = """\
mission: fuzz
modem: {backend: sim, frame_bytes: 64}
mac: {type: tdma, slot_s: 2, order: [a, b, c]}
wire: {dlbl: true%s}
nodes:
  a: {address: 1}
  b: {address: 2}
  c: {address: 3}
channels:
  - name: nav
    from: a
    to: ".*"
    elements: [{in: nav, out: a/nav, fields: [
      {field: x, min: -1000, max: 1000, bits: 16}, {field: mode, values: [idle, dive, up]}]}]
  - name: cmd
    from: b
    to: a
    reliable: true
    elements: [{in: cmd, out: b/cmd, fields: [{field: n, type: int, min: 0, max: 255}]}]
  - name: blob
    from: a
    to: b
    elements: [{in: blob, out: a/blob, fields: [{field: data, type: bytes, max_length: 400}]}]
"""


def valid_frames(codec: FrameCodec, rng: random.Random, n: int) -> list[bytes]:
    """``n`` well-formed frames from node a: nav, fragments, acknowledgements, delays."""
    table = codec.table
    nav, _cmd, blob = table.channels
    ack = table.ack
    assert ack is not None and blob.fragmented
    frames = []
    for _ in range(n):
        items: list[tuple] = [(nav, nav.pack([{"x": rng.uniform(-999, 999),
                                               "mode": rng.choice(["idle", "dive"])}]))]
        for _ in range(rng.randrange(2)):
            count = rng.randrange(1, 9)
            fb = blob.fragment_bits
            header = (((rng.randrange(16) << fb) | rng.randrange(count)) << fb) | count
            items.append((blob, (header << (8 * blob.chunk_bytes)) | rng.getrandbits(
                8 * blob.chunk_bytes)))
        if rng.random() < 0.5:
            items.append((ack, ack.pack(1, 0, rng.randrange(256), 0, rng.randrange(256),
                                        rng.getrandbits(16))))
        delays = [rng.choice([None, rng.randrange(1 << 24 - 1)]) for _ in range(codec.delay_count)]
        frames.append(codec.encode(items, delays))
    return frames


def mutations(rng: random.Random, frames: list[bytes]) -> list[tuple[str, Callable[[], bytes]]]:
    def pick() -> bytes:
        return rng.choice(frames)

    def flip() -> bytes:
        data = bytearray(pick())
        for _ in range(rng.randrange(1, 9)):
            data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
        return bytes(data)

    def change() -> bytes:
        data = bytearray(pick())
        data[rng.randrange(len(data))] = rng.randrange(256)
        return bytes(data)

    def truncate() -> bytes:
        data = pick()
        return data[:rng.randrange(len(data))]

    def extend() -> bytes:
        return pick() + os.urandom(rng.randrange(1, 8))

    def splice() -> bytes:
        a, b = pick(), pick()
        return a[:rng.randrange(len(a))] + b[rng.randrange(len(b)):]

    return [
        ("random", lambda: os.urandom(rng.randrange(0, 80))),
        ("bit flips", flip),
        ("byte change", change),
        ("truncated", truncate),
        ("extended", extend),
        ("spliced", splice),
        ("unchanged", pick),
    ]


def run(frames_total: int, seed: int, authenticated: bool) -> tuple[dict[str, Counter], int]:
    rng = random.Random(seed)
    auth_yaml = ", auth: {tag_bytes: 4}" if authenticated else ""
    loaded = parse_mission(MISSION % auth_yaml)
    table = loaded.table
    key = b"a fuzzing key, 32 bytes long ..."
    sender = FrameCodec(table, Authenticator(key, table.fingerprint, 1, 4)
                        if authenticated else None)
    frames = valid_frames(sender, rng, 2000)
    cases = mutations(rng, frames)
    results: dict[str, Counter] = {name: Counter() for name, _ in cases}
    false = 0
    originals = set(frames)
    receiver = FrameCodec(table, Authenticator(key, table.fingerprint, 2, 4)
                          if authenticated else None)
    for i in range(frames_total):
        name, make = cases[i % len(cases)]
        data = make()
        try:
            receiver.decode(data, 1)
        except FrameError as exc:
            results[name][exc.reason] += 1
        except Exception as exc:  # counting what must never happen
            results[name][f"EXCEPTION {type(exc).__name__}"] += 1
        else:
            results[name]["ok"] += 1
            if data not in originals:
                false += 1
    return results, false


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=1_000_000)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    for authenticated in (True, False):
        start = time.perf_counter()
        results, false = run(args.frames, args.seed, authenticated)
        elapsed = time.perf_counter() - start
        title = "authenticated (4-byte tag)" if authenticated else "check only (CRC-16)"
        print(f"\n{title}: {args.frames:,} frames in {elapsed:.1f} s "
              f"({args.frames / elapsed:,.0f} decodes/s)")
        reasons = sorted({r for c in results.values() for r in c})
        print(f"{'case':<12}" + "".join(f"{r:>12}" for r in reasons))
        for name, counts in results.items():
            print(f"{name:<12}" + "".join(f"{counts[r]:>12,}" for r in reasons))
        other = sum(n for c in results.values() for r, n in c.items() if r.startswith("EXC"))
        print(f"exceptions other than FrameError: {other}; false deliveries (a changed frame "
              f"accepted): {false}")


if __name__ == "__main__":
    main()
