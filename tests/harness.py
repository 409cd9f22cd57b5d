"""Run a fleet in a background event loop and talk to it with plain Zenoh sessions."""

from __future__ import annotations

import asyncio
import contextlib
import importlib.util
import json
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

import msgpack
import zenoh

from bridge.core.loaded import LoadedMission
from bridge.runtime.fleet import Fleet

REPO = Path(__file__).resolve().parent.parent


@contextlib.contextmanager
def running_fleet(loaded: LoadedMission, **kwargs: Any) -> Iterator[Fleet]:
    """Start every node (and the water) in a thread; stop and close everything on exit."""
    fleet = Fleet(loaded, **kwargs)
    loop = asyncio.new_event_loop()
    stop = asyncio.Event()
    done = threading.Event()
    failure: list[BaseException] = []

    def main() -> None:
        async def go() -> None:
            await fleet.run(stop)

        try:
            loop.run_until_complete(go())
        except BaseException as exc:  # reported to the test below
            failure.append(exc)
        finally:
            loop.close()
            done.set()

    thread = threading.Thread(target=main, name="fleet", daemon=True)
    thread.start()
    deadline = time.time() + 30  # start-up under a loaded machine
    while not fleet.ready.is_set() and not done.is_set() and time.time() < deadline:
        time.sleep(0.01)
    try:
        if failure:
            raise failure[0]
        assert fleet.ready.is_set(), "fleet did not start"
        yield fleet
    finally:
        if not done.is_set():
            loop.call_soon_threadsafe(stop.set)
        assert done.wait(30), "fleet did not stop"
        thread.join(5)
    if failure:
        raise failure[0]


def outside_session(loaded: LoadedMission, node: str) -> zenoh.Session:
    """An application's session, connected only to ``node``'s endpoint (client mode)."""
    config = zenoh.Config()
    config.insert_json5("mode", '"client"')
    config.insert_json5("connect/endpoints", json.dumps(loaded.mission.nodes[node].zenoh.listen))
    config.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(config)


class Inbox:
    """Collects (key, decoded msgpack value, time) from a subscriber callback."""

    def __init__(self) -> None:
        self.items: queue.Queue[tuple[str, Any, float]] = queue.Queue()

    def __call__(self, sample: zenoh.Sample) -> None:
        self.items.put((str(sample.key_expr), msgpack.unpackb(sample.payload.to_bytes()),
                        time.time()))

    def get(self, timeout: float) -> tuple[str, Any, float]:
        return self.items.get(timeout=timeout)

    def drain(self, seconds: float) -> list[tuple[str, Any, float]]:
        out = []
        end = time.time() + seconds
        while (left := end - time.time()) > 0:
            try:
                out.append(self.items.get(timeout=left))
            except queue.Empty:
                break
        return out


def put(session: zenoh.Session, key: str, value: Any) -> None:
    session.put(key, msgpack.packb(value), encoding=zenoh.Encoding("application/msgpack"))


def listing1_crosses_in_the_next_slot(loaded: LoadedMission) -> None:
    """Seed 000 Listing 1 end to end: put at lsv's endpoint just after one of lsv's TDMA slots;
    gcv's endpoint gets it decoded within quantisation, during lsv's next slot."""
    from bridge.core.mac import TdmaSchedule
    from bridge.mission.model import TdmaMac

    assert isinstance(loaded.mission.mac, TdmaMac)
    lsv_app = outside_session(loaded, "lsv")
    gcv_app = outside_session(loaded, "gcv")
    try:
        inbox = Inbox()
        gcv_app.declare_subscriber("lsv/target_reference", inbox)
        schedule = TdmaSchedule(loaded.mission.mac, "lsv")
        slot = schedule.next_slot(time.time())
        assert slot is not None
        time.sleep(max(0.0, slot.start + 0.1 - time.time()))  # just after an lsv slot
        put(lsv_app, "target_reference", {"vector": {"x": 3.0, "y": 0.02}})
        expected = schedule.next_slot(time.time())
        assert expected is not None
        key, value, arrived = inbox.get(timeout=expected.end - time.time() + 2.0)
        assert key == "lsv/target_reference"
        assert abs(value["vector"]["x"] - 3.0) <= 6.2831 / 255 / 2 + 1e-9
        assert abs(value["vector"]["y"] - 0.02) <= 2 * 0.052359878 / 63 / 2 + 1e-9
        # it crossed in lsv's next slot: not before the slot, done by the slot's end
        assert expected.start < arrived <= expected.end + 0.25
    finally:
        lsv_app.close()
        gcv_app.close()


@contextlib.contextmanager
def zab_run(mission: Path, node: str, *args: str, env: dict[str, str] | None = None,
            stop: signal.Signals = signal.SIGTERM
            ) -> Iterator[tuple[subprocess.Popen[str], list[str]]]:
    """A real ``zab run`` process, yielded once it says it runs, with the lines it printed so
    far; ``stop`` (SIGTERM, or SIGINT as Ctrl-C) on exit, after which it must stop cleanly
    (exit 0). Killed if anything fails; its pipe closed either way."""
    argv = [sys.executable, "-m", "bridge", "run", str(mission), "--node", node, *args]
    with subprocess.Popen(argv, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                          text=True, env={**(os.environ if env is None else env),
                                          "COLUMNS": "300"}) as proc:
        try:
            assert proc.stdout is not None
            lines: list[str] = []
            for line in proc.stdout:
                lines.append(line)
                if "bridge running" in line:
                    break
            else:
                raise AssertionError("zab run did not start:\n" + "".join(lines))
            yield proc, lines
            proc.send_signal(stop)
            rest, _ = proc.communicate(timeout=30)
            lines.append(rest)
            assert proc.returncode == 0, "".join(lines)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()


def bench_module(name: str) -> ModuleType:
    """``bench/<name>.py`` imported as a module (registered, so its dataclasses find it)."""
    spec = importlib.util.spec_from_file_location(name, REPO / "bench" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module
