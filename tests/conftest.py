"""Shared test helpers: free loopback ports and missions rewritten to use them."""

from __future__ import annotations

import importlib
import importlib.util
import os
import secrets
import shutil
import socket
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml
from hypothesis import settings

from bridge.core.loaded import LoadedMission, parse_mission

# Property tests are timed by nothing: hypothesis's default deadline of 200 ms an example failed
# on CI's loaded machine (a first example took 607 ms, then 13 ms).
settings.register_profile("zab", deadline=None)
settings.load_profile("zab")

REPO = Path(__file__).resolve().parent.parent
MISSIONS = REPO / "deploy" / "missions"
CHROMIUM = Path("/usr/bin/chromium")


def browser_missing() -> str | None:
    """Why the browser tests cannot run here (None: they can)."""
    if not CHROMIUM.exists():
        return "needs Debian's chromium (apt-get install chromium)"
    if importlib.util.find_spec("playwright") is None:
        return "needs Playwright (the browser group: uv sync --group browser)"
    return None


needs_browser = pytest.mark.browser
"""Tests that drive Debian's Chromium through Playwright (the `browser` dependency group)."""

TEST_GROUPS = {"browser": "playwright", "docs": "mkdocs", "interop": "acomms"}
"""The dependency groups only some tests use, each with a module it brings: not default groups,
so ``uv run zab demo`` does not install them; the test session does, the first time."""


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "browser: drives Debian's Chromium through Playwright")
    if hasattr(config, "workerinput"):
        return  # an xdist worker: the controller installed what was missing before starting it
    missing = [group for group, module in TEST_GROUPS.items()
               if importlib.util.find_spec(module) is None]
    uv = os.environ.get("UV") or shutil.which("uv")
    if not missing or uv is None:
        return
    command = [uv, "sync", "--locked", "--inexact", *(f"--group={group}" for group in missing)]
    done = subprocess.run(command, cwd=REPO, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise pytest.UsageError(f"installing the test groups {', '.join(missing)} failed "
                                f"({' '.join(command[1:])}):\n{done.stderr}")
    importlib.invalidate_caches()


def pytest_runtest_setup(item: pytest.Item) -> None:
    if item.get_closest_marker("browser") is not None and (reason := browser_missing()):
        pytest.skip(reason)


PORT_BASE, PORT_BLOCK = 16000, 1500
"""Ports handed out to tests: a block of its own per xdist worker, all below the kernel's
ephemeral range (``net.ipv4.ip_local_port_range``, 32768-60999 by default). A port the
kernel chose (bind to 0) could be taken, before its test's process listened on it, as the
source port of any outgoing connection (five workers' Zenoh sessions make many): a suite
failed so with 'tcp/127.0.0.1:41821 is already in use'."""
_cursor = secrets.randbelow(PORT_BLOCK)  # (two suites at once start apart)


def _ephemeral_low() -> int:
    try:
        return int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return 0


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    """A port free on 127.0.0.1 now, from this worker's block (:data:`PORT_BASE`), or the
    kernel's choice where the ephemeral range reaches down into the blocks."""
    global _cursor
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0")[2:]
    start = PORT_BASE + (int(worker) % 10 if worker.isdigit() else 0) * PORT_BLOCK
    if _ephemeral_low() >= PORT_BASE + 10 * PORT_BLOCK:
        for _ in range(PORT_BLOCK):
            port = start + _cursor % PORT_BLOCK
            _cursor += 1
            with socket.socket(socket.AF_INET, kind) as s:
                try:
                    s.bind(("127.0.0.1", port))
                except OSError:
                    continue
                return port
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def udp_ports(text: str) -> str:
    """``text`` with its ``PORT_A`` and ``PORT_B`` replaced by free loopback UDP ports."""
    for name in ("PORT_A", "PORT_B"):
        text = text.replace(name, str(free_port(socket.SOCK_DGRAM)))
    return text


def on_free_ports(text: str, name: str | Path = "test.yaml") -> LoadedMission:
    """Load mission ``text`` with every node listening on a fresh loopback port."""
    data = yaml.safe_load(text)
    for node in data["nodes"].values():
        node.setdefault("zenoh", {})["listen"] = [f"tcp/127.0.0.1:{free_port()}"]
    return parse_mission(yaml.safe_dump(data, sort_keys=False), name)


def mission_on_free_ports(path: Path) -> LoadedMission:
    """An example mission from ``deploy/missions`` on fresh loopback ports."""
    return on_free_ports(path.read_text(), path)


def pytest_xdist_auto_num_workers(config: pytest.Config) -> int:
    """``-n auto``: two workers per core, and one more: most of the suite's wall time is
    waiting on real time (fleets, TDMA slots, demos, browsers), so on two cores five workers
    fill those waits (a full run with three used ~330 s of CPU in 474 s on two cores; five
    gave 283 s against 446 s for three, the same machine)."""
    return 2 * len(os.sched_getaffinity(0)) + 1


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Under pytest-xdist (``--dist loadgroup``): a module's tests run on one worker, in their
    order, sharing its fixtures (a fleet, a router, a demo on fixed ports), unless the module
    says ``INDEPENDENT = True`` (pure tests, no shared state: each goes where a worker is
    free, so one long module does not hold the run up).

    Modules that say ``LONG = True`` (a minute or more of real time or CPU on a loaded
    machine) come first, in their order: workers take groups in the order collected
    (``--no-loadscope-reorder``; xdist's own reorder, by tests per group, put them last), so
    the run does not end on one worker's long tail."""
    items.sort(key=lambda item: not getattr(getattr(item, "module", None), "LONG", False))
    for item in items:
        module = getattr(item, "module", None)
        if module is None or getattr(module, "INDEPENDENT", False) \
                or item.get_closest_marker("xdist_group") is not None:
            continue
        item.add_marker(pytest.mark.xdist_group(module.__name__))


@pytest.fixture(autouse=True)
def _no_frame_key_from_outside(monkeypatch: pytest.MonkeyPatch) -> None:
    """Tests see no $ZAB_KEY unless they set one: a key in the shell running them would turn
    every mission without wire.auth into an error (and every test mission into a different
    one)."""
    monkeypatch.delenv("ZAB_KEY", raising=False)


@pytest.fixture(scope="session", autouse=True)
def _state_directory_of_the_session(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """A module's fixture starts before a test's own fixtures: its ``zab run`` processes (as
    test_acomms' lab) save in a $STATE_DIRECTORY of this test session's, never in
    ~/.local/state/zab, where a second test run on the machine met their locks."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("STATE_DIRECTORY", str(tmp_path_factory.mktemp("session-state")))
        yield


@pytest.fixture(autouse=True)
def _state_directory_of_its_own(monkeypatch: pytest.MonkeyPatch,
                                tmp_path_factory: pytest.TempPathFactory) -> None:
    """Each test's ``zab run`` (without --state-dir) saves in a $STATE_DIRECTORY of the
    test's own, never in ~/.local/state/zab: tests running at once with one mission and node
    would share a state file, and the second bridge of a node refuses to start (its lock)."""
    monkeypatch.setenv("STATE_DIRECTORY", str(tmp_path_factory.mktemp("state")))


@pytest.fixture
def mission_key(monkeypatch: pytest.MonkeyPatch) -> str:
    """A frame key in $ZAB_KEY for this test, as an operator sets it (zab check, run, doctor)."""
    key = secrets.token_hex(32)
    monkeypatch.setenv("ZAB_KEY", key)
    return key


@pytest.fixture
def morph_path() -> Path:
    return MISSIONS / "morph.yaml"
