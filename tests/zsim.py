"""A real ``zab sim`` process, and plain Zenoh applications talking to its nodes.

The applications use only ``zenoh`` and ``msgpack`` (no import from the project), as one
written in another language would.
"""

from __future__ import annotations

import collections
import contextlib
import json
import queue
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import msgpack
import yaml
import zenoh

from tests.conftest import REPO, free_port

LOG_TAIL = 40
"""Lines of a ``zab sim``'s log a test prints at its end."""


def mission_file(text: str, folder: Path, name: str = "mission.yaml") -> tuple[Path, dict]:
    """Write mission ``text`` with each node on a free loopback port; returns the path and
    the node endpoints."""
    data = yaml.safe_load(text)
    for node in data["nodes"].values():
        node.setdefault("zenoh", {})["listen"] = [f"tcp/127.0.0.1:{free_port()}"]
    path = folder / name
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path, {n: node["zenoh"]["listen"] for n, node in data["nodes"].items()}


def app(endpoints: list[str]) -> zenoh.Session:
    """A plain application in client mode, connected only to ``endpoints``."""
    config = zenoh.Config()
    config.insert_json5("mode", '"client"')
    config.insert_json5("connect/endpoints", json.dumps(endpoints))
    config.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(config)


@contextlib.contextmanager
def zab_sim(mission: Path, endpoints: dict[str, list[str]], *args: str,
            timeout: float = 120) -> Iterator[subprocess.Popen[str]]:
    """Run ``zab sim mission`` until the block ends (SIGINT, then kill if need be); yields
    once every node's endpoint accepts a client. Its log is read all along (a pipe left full
    would stop the fleet) and its last lines printed at the end (a failing test shows them)."""
    proc = subprocess.Popen([sys.executable, "-m", "bridge", "sim", str(mission), "--no-live",
                             "--duration", str(timeout), *args], cwd=REPO,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    log: collections.deque[str] = collections.deque(maxlen=LOG_TAIL)
    assert proc.stderr is not None
    reader = threading.Thread(target=log.extend, args=(proc.stderr,), daemon=True)
    reader.start()
    try:
        deadline = time.time() + 30
        for listen in endpoints.values():
            while True:
                if proc.poll() is not None:
                    reader.join(5)
                    raise AssertionError("zab sim ended:\n" + "".join(log))
                try:
                    app(listen).close()
                    break
                except zenoh.ZError:
                    assert time.time() < deadline, "zab sim did not open its endpoints"
                    time.sleep(0.1)
        yield proc
    finally:
        interrupt(proc)
        reader.join(5)  # (the pipe ends with the process)
        proc.stderr.close()
        print(f"zab sim's last {LOG_TAIL} log lines:\n" + "".join(log))


@contextlib.contextmanager
def zab_water(mission: Path, port: int, env: dict[str, str] | None = None) -> Iterator[None]:
    """A ``zab water`` process on ``port`` (``env``: its environment, default this one's),
    until the block ends."""
    proc = subprocess.Popen([sys.executable, "-m", "bridge", "water", str(mission), "--port",
                             str(port)], cwd=REPO, env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    try:
        deadline = time.time() + 20
        while True:
            with contextlib.suppress(OSError):
                socket.create_connection(("127.0.0.1", port)).close()
                break
            assert proc.poll() is None and time.time() < deadline, "zab water did not start"
            time.sleep(0.1)
        yield
    finally:
        interrupt(proc, 10)


def interrupt(proc: subprocess.Popen[Any], timeout: float = 30) -> None:
    """Stop ``proc`` as Ctrl-C does (killed if it does not stop within ``timeout``: Zenoh's
    ``close()`` alone may take its 10 s open timeout, more on a loaded machine; CI saw a
    ``zab listen`` outlive 15 s once)."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGABRT)  # (with PYTHONFAULTHANDLER: its threads' stacks)
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


class Inbox:
    """(key, value) of every sample a subscriber gets, decoded from msgpack."""

    def __init__(self) -> None:
        self.items: queue.Queue[tuple[str, Any]] = queue.Queue()

    def __call__(self, sample: zenoh.Sample) -> None:
        self.items.put((str(sample.key_expr), msgpack.unpackb(sample.payload.to_bytes())))

    def drain(self, seconds: float) -> list[tuple[str, Any]]:
        return drain(self.items, seconds)


def drain(items: queue.Queue[Any], seconds: float) -> list[Any]:
    """Whatever ``items`` gets within ``seconds``."""
    out, end = [], time.time() + seconds
    while (left := end - time.time()) > 0:
        try:
            out.append(items.get(timeout=left))
        except queue.Empty:
            break
    return out

