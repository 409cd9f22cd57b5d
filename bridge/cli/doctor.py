"""``zab doctor``: is this vehicle ready to run its bridge? Each check says what to fix.

Checks, in order: the mission (as ``zab check``) and the frame key; the modem (the serial
device exists and is usable, then the backend opens and the modem answers its start-up
commands; a serial modem that does not is asked which kind it is, as each backend would);
the Zenoh session (listen endpoints free, connect endpoints reachable); the state directory
(a save works there, with room to spare: a bridge that cannot save its state refuses new
reliable values); the clock (TDMA slots are wall-clock aligned, so every node needs a
synchronised clock: chrony, systemd's timesyncd or a PPS source). When a bridge of the node
is running (it holds the node's state lock), the modem, Zenoh and state checks are skipped:
they would open what the bridge holds.

Parsing of the clock tools' output is pure (:func:`parse_chronyc`, :func:`parse_timedatectl`);
running them, opening the modem and the Zenoh session happen in :func:`run_doctor`.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import re
import shutil
import socket
import stat
import subprocess
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from bridge.core.loaded import LoadedMission
from bridge.core.mac import mac_for
from bridge.errors import BackendError
from bridge.mission.model import Mission
from bridge.modems.identify import identify
from bridge.modems.registry import load_backend
from bridge.modems.setup import backend_factory
from bridge.report.check import check_mission
from bridge.runtime.keys import frame_key

__all__ = [
    "ClockState",
    "Finding",
    "clock_findings",
    "parse_chronyc",
    "parse_timedatectl",
    "run_doctor",
]

Status = Literal["ok", "warn", "fail"]
RunCommand = Callable[[Sequence[str]], str | None]

SERIAL_BACKENDS = frozenset({"evologics", "micromodem"})
CONNECT_PROBE_S = 1.0
STATE_ROOM_BYTES = 1 << 20  # free space under which the state directory is a warning


@dataclass(frozen=True)
class Finding:
    """One check's result: ``fix`` says what to do when the status is not ok."""

    check: str
    status: Status
    message: str
    fix: str | None = None


@dataclass(frozen=True)
class ClockState:
    """What a clock tool says: synchronised or not, and the offset when it knows it."""

    source: str
    synchronised: bool
    offset_s: float | None = None
    detail: str = ""


# -- clock: pure parsing -------------------------------------------------------------------------

_CHRONY_OFFSET = re.compile(r"^System time\s*:\s*([0-9.eE+-]+) seconds (fast|slow)", re.M)
_CHRONY_LEAP = re.compile(r"^Leap status\s*:\s*(.+?)\s*$", re.M)
_CHRONY_REF = re.compile(r"^Reference ID\s*:\s*(.+?)\s*$", re.M)


def parse_chronyc(text: str) -> ClockState | None:
    """``chronyc tracking`` output → state; ``None`` when it is not that output."""
    leap = _CHRONY_LEAP.search(text)
    offset = _CHRONY_OFFSET.search(text)
    if leap is None or offset is None:
        return None
    value = float(offset.group(1)) * (1 if offset.group(2) == "fast" else -1)
    ref = _CHRONY_REF.search(text)
    synced = leap.group(1) != "Not synchronised"
    return ClockState("chrony", synced, value, ref.group(1) if ref else "")


def parse_timedatectl(text: str) -> ClockState | None:
    """``timedatectl show`` output (``Key=value`` lines) → state; ``None`` if unrecognised."""
    values = dict(line.split("=", 1) for line in text.splitlines() if "=" in line)
    if "NTPSynchronized" not in values:
        return None
    ntp = values.get("NTP", "")
    return ClockState("timedatectl", values["NTPSynchronized"] == "yes",
                      detail=f"NTP service {'on' if ntp == 'yes' else 'off'}")


def clock_findings(loaded: LoadedMission, state: ClockState | None,
                   pps: Sequence[str] = ()) -> list[Finding]:
    """Judge a clock state against the mission: TDMA needs offsets well inside the guard."""
    limits = min((found for link in loaded.network.links  # the tightest of the links' MACs
                  if (found := mac_for(link.view).clock_limits()) is not None), default=None)
    if limits is None:
        return [Finding("clock", "ok", "no TDMA: the bridge does not depend on the wall clock")]
    limit, guard = limits
    install = ("install chrony (apt install chrony) and point it at the surface station's NTP "
               "server, or a GPS/PPS source")
    if state is None:
        if pps:
            return [Finding("clock", "warn", f"PPS device {', '.join(pps)} present, but no "
                            "chrony/timedatectl to tell whether the clock follows it",
                            "install chrony with a `refclock PPS` line")]
        return [Finding("clock", "warn", "cannot tell whether the clock is synchronised "
                        "(no chronyc, no timedatectl); TDMA slots need it", install)]
    if not state.synchronised:
        return [Finding("clock", "fail", f"{state.source}: the clock is not synchronised; TDMA "
                        "slots of different vehicles will overlap",
                        "start chrony (systemctl enable --now chrony) and wait for `chronyc "
                        "tracking` to show `Leap status : Normal`")]
    if state.offset_s is None:
        return [Finding("clock", "ok", f"{state.source}: synchronised ({state.detail})")]
    offset_ms = abs(state.offset_s) * 1000
    if abs(state.offset_s) >= limit:
        return [Finding("clock", "fail", f"{state.source}: offset {offset_ms:.1f} ms is more "
                        f"than half the TDMA guard ({guard * 1000:.0f} ms)",
                        "let chrony converge (chronyc makestep), or widen mac.guard_s")]
    if abs(state.offset_s) >= limit / 5:
        return [Finding("clock", "warn", f"{state.source}: offset {offset_ms:.1f} ms uses a "
                        f"tenth of the TDMA guard ({guard * 1000:.0f} ms)",
                        "check the NTP/PPS source; chronyc sources -v")]
    return [Finding("clock", "ok", f"{state.source}: synchronised, offset {offset_ms:.2f} ms "
                    f"(guard {guard * 1000:.0f} ms)")]


# -- checks with I/O -----------------------------------------------------------------------------


def run_command(argv: Sequence[str]) -> str | None:
    """Output of a local tool, or ``None`` when it is missing or fails."""
    if shutil.which(argv[0]) is None:
        return None
    try:
        done = subprocess.run(list(argv), capture_output=True, text=True, timeout=5, check=False)
    except (OSError, subprocess.SubprocessError):
        return None
    return done.stdout if done.returncode == 0 else None


def read_clock(run: RunCommand = run_command) -> ClockState | None:
    for argv, parse in ((["chronyc", "tracking"], parse_chronyc),
                        (["timedatectl", "show"], parse_timedatectl)):
        text = run(argv)
        if text is not None and (state := parse(text)) is not None:
            return state
    return None


def mission_findings(loaded: LoadedMission) -> list[Finding]:
    report = check_mission(loaded)
    found = [Finding("mission", "fail", error, "edit the mission; `zab check` shows the budget")
             for error in report.errors]
    found += [Finding("mission", "warn", warning) for warning in report.warnings]
    if not found:
        found.append(Finding("mission", "ok", f"{loaded.path}: valid, every channel fits"))
    key = frame_key(loaded.mission)
    if key.problem:
        found.append(Finding("key", "fail", key.problem, "`zab run` refuses to start"))
    elif key.state == "on":
        found.append(Finding("key", "ok", f"frame key found in {key.source}"))
    elif key.state == "unsaid":
        found.append(Finding("key", "warn", key.describe()))
    return found


def device_findings(loaded: LoadedMission, node: str) -> list[Finding]:
    """The serial device of each serial backend of the node (one per link): present, a
    character device, usable."""
    return [finding for view, label in _modems(loaded, node)
            for finding in _device(view, node, label)]


def _modems(loaded: LoadedMission, node: str) -> list[tuple[Mission, str]]:
    """Each link of ``node`` as its MAC and modem see the mission, and a label for findings
    (``modem``, or ``modem (rf)`` with several links)."""
    links = loaded.network.links_of(node)
    return [(link.view, f"modem ({link.name})" if len(links) > 1 else "modem")
            for link in links]


def _device(mission: Mission, node: str, label: str) -> list[Finding]:
    modem = mission.node_modem(node)
    name = label.replace("modem", "device")
    if modem.backend not in SERIAL_BACKENDS:
        return []
    device = modem.options.get("device")
    where = f"nodes.{node}.modem.options.device (or modem.options.device)"
    if not device:
        return [Finding(name, "fail", f"the {modem.backend} backend needs a device",
                        f"set {where} to the modem's serial port, e.g. /dev/ttyUSB0")]
    device = str(device)
    if "://" in device:
        return [Finding(name, "ok", f"{device} (a URL; checked by opening the modem)")]
    path = Path(device)
    if not path.exists():
        hint = "plug the modem in and check `ls -l /dev/serial/by-id/`"
        if path.is_symlink():
            hint = f"{device} is a dangling link; " + hint
        return [Finding(name, "fail", f"{device} does not exist", hint)]
    try:
        mode = path.stat().st_mode
    except OSError as exc:
        return [Finding(name, "fail", f"{device}: {exc}", "check the path")]
    if not stat.S_ISCHR(mode):
        return [Finding(name, "fail", f"{device} is not a serial (character) device",
                        f"set {where} to the modem's serial port")]
    if not os.access(path, os.R_OK | os.W_OK):
        return [Finding(name, "fail", f"{device}: no permission to read and write",
                        "add the user to the `dialout` group (usermod -aG dialout zab) or "
                        "give the systemd unit DeviceAllow= and SupplementaryGroups=dialout")]
    return [Finding(name, "ok", f"{device} is a usable serial device")]


async def modem_findings(loaded: LoadedMission, node: str, timeout_s: float) -> list[Finding]:
    """Open each of the node's modem backends (its start-up commands are the exchange) and
    close it."""
    return [finding for view, label in _modems(loaded, node)
            for finding in await _modem(view, node, label, timeout_s)]


async def _modem(mission: Mission, node: str, label: str, timeout_s: float) -> list[Finding]:
    modem = mission.node_modem(node)
    try:
        backend = backend_factory(mission, node)()
    except BackendError as exc:
        return [Finding(label, "fail", str(exc), "fix the modem options in the mission")]
    try:
        async with asyncio.timeout(timeout_s):
            await backend.open()
    except TimeoutError:
        failed = Finding(label, "fail", f"{modem.backend}: no answer within {timeout_s:g} s",
                         _modem_fix(modem.backend))
    except BackendError as exc:
        failed = Finding(label, "fail", f"{modem.backend}: {exc}", _modem_fix(modem.backend))
    else:
        return [Finding(label, "ok", f"{modem.backend}: opened, the modem answered")]
    finally:
        with contextlib.suppress(BackendError, OSError):
            await backend.close()
    return [await _told_apart(mission, node, label, failed)]


async def _told_apart(mission: Mission, node: str, label: str, failed: Finding) -> Finding:
    """A serial modem that did not start, asked which kind it is: another kind of modem
    (its first line telling so), a device whose lines no backend speaks (a wrong baud
    rate?), or ``failed`` as it was (silent, or speaking the backend's own protocol)."""
    modem = mission.node_modem(node)
    if modem.backend not in SERIAL_BACKENDS:
        return failed
    try:
        baud = int(modem.options.get("baud", 19200))
    except (TypeError, ValueError):
        return failed
    order = [modem.backend, *sorted(SERIAL_BACKENDS - {modem.backend})]  # its own probe first
    backends = {name: load_backend(name) for name in order}
    name, line = await identify(str(modem.options.get("device")), baud, backends)
    if line is None or name == modem.backend:
        return failed
    shown = line.decode("latin-1").strip()[:80]
    if name is None:
        return Finding(label, "fail", f"{modem.backend}: the device answers, in no modem "
                       f"protocol zab knows: {shown!r}", "check the baud option (the modem's "
                       "serial speed) and that the device is the modem's port")
    return Finding(label, "fail", f"{modem.backend}: the device answers, but speaks the "
                   f"{name} protocol: {shown!r}", f"set `backend: {name}` in {node}'s modem "
                   f"settings, or its device to the port of a modem the {modem.backend} "
                   "backend drives")


def _modem_fix(backend: str) -> str:
    if backend in SERIAL_BACKENDS:
        return ("check the modem's power and cable, the baud option, and that no other "
                "program (zab run, minicom) holds the port")
    if backend == "sim":
        return "start the simulated water (zab water MISSION) or fix modem.options.water"
    if backend == "udp":
        return "another process holds the UDP port: stop it or change modem.options.port"
    return "check the backend's options"


def _tcp_target(endpoint: str) -> tuple[str, int] | None:
    match = re.fullmatch(r"tcp/\[?([^\]]+?)\]?:(\d+)", endpoint.split("#", 1)[0])
    return (match.group(1), int(match.group(2))) if match else None


def _reachable(host: str, port: int) -> bool:
    try:
        with socket.create_connection((host, port), timeout=CONNECT_PROBE_S):
            return True
    except OSError:
        return False


def zenoh_findings(loaded: LoadedMission, node: str) -> list[Finding]:
    """Open a session with the node's Zenoh settings and close it; probe connect endpoints."""
    from bridge.runtime.session import close_quietly, open_session

    settings = loaded.mission.nodes[node].zenoh
    found: list[Finding] = []
    if not settings.listen and settings.mode != "client":
        found.append(Finding("zenoh", "warn", "no listen endpoint: applications on this "
                             "vehicle cannot connect to the bridge",
                             f"set nodes.{node}.zenoh.listen, e.g. [tcp/127.0.0.1:7447]"))
    try:
        session = open_session(settings, node)
    except Exception as exc:  # zenoh raises ZError, a plain Exception subclass
        text = str(exc)
        fix = "fix the endpoints in nodes.<node>.zenoh"
        if "in use" in text.lower() or "bind" in text.lower():
            fix = "another process listens there (is `zab run` already running?)"
        elif settings.mode == "client":
            fix = "start the router this client connects to, or fix zenoh.connect"
        found.append(Finding("zenoh", "fail", f"cannot open the session: {text}", fix))
        return found
    close_quietly(session)
    shown = " ".join(settings.listen) or "(no listen endpoint)"
    found.append(Finding("zenoh", "ok", f"{settings.mode} session opens on {shown}"))
    for endpoint in settings.connect:
        target = _tcp_target(endpoint)
        if target is not None and not _reachable(*target):
            found.append(Finding("zenoh", "warn", f"nothing answers at {endpoint}",
                                 "start the router there (zenohd -c deploy/zenoh/...) or fix "
                                 "zenoh.connect; the bridge keeps retrying"))
    return found


def state_findings(loaded: LoadedMission, node: str, directory: Path) -> list[Finding]:
    """Whether the node's state can be saved in ``directory``: a real save of a probe file
    (as the bridge saves, atomically), and the room left."""
    from bridge.runtime.persistence import problem
    from bridge.runtime.state_file import StateError, StateFile

    try:
        probe = StateFile(directory, loaded.mission.mission, f"{node}.doctor")
        probe.save({"doctor": True})
        probe.path.unlink()
    except StateError as exc:
        return [Finding("state", "fail", str(exc), "create the directory and give the bridge's "
                        "user write access (systemd: StateDirectory=zab), or pass --state-dir")]
    except OSError as exc:
        return [Finding("state", "fail", f"cannot save a state file in {directory}: "
                        f"{problem(exc)}", "free space on that filesystem or remount it "
                        "read-write: meanwhile a running bridge refuses new reliable values")]
    free = shutil.disk_usage(directory).free
    if free < STATE_ROOM_BYTES:
        return [Finding("state", "warn", f"{directory}: only {free // 1024} KiB free",
                        "free space: a bridge that cannot save its state refuses new reliable "
                        "values until it can")]
    return [Finding("state", "ok", f"{directory} takes a save ({free // (1 << 20)} MiB free)")]


def running_findings(loaded: LoadedMission, node: str, directory: Path | None) -> list[Finding]:
    """A bridge of this node running (it holds the node's state lock): opening its modem
    would disturb the bridge, so the modem and state checks are skipped."""
    from bridge.runtime.state_file import lock_holder

    holder = None if directory is None else lock_holder(directory, loaded.mission.mission, node)
    if holder is None:
        return []
    return [Finding("bridge", "warn", f"a bridge of {node} is running ({holder} holds its "
                    f"state in {directory}): modem, Zenoh and state not checked",
                    "stop that bridge to check them")]


def _pps_devices() -> list[str]:
    return sorted(str(p) for p in Path("/dev").glob("pps*"))


async def run_doctor(
    loaded: LoadedMission,
    node: str,
    *,
    timeout_s: float = 15.0,
    run: RunCommand = run_command,
    modem: Callable[[LoadedMission, str, float], Awaitable[list[Finding]]] = modem_findings,
    state_dir: Path | None = None,
) -> list[Finding]:
    """Every check for ``node``; the modem is opened only when its device looks usable;
    ``state_dir``: where the node saves its state (not checked when None)."""
    if node not in loaded.mission.nodes:
        return [Finding("mission", "fail", f"no node {node!r}; nodes: "
                        f"{', '.join(loaded.mission.nodes)}", "pass --node with one of them")]
    found = mission_findings(loaded)
    running = running_findings(loaded, node, state_dir)
    found += running
    devices = device_findings(loaded, node)
    found += devices
    if not running and all(f.status == "ok" for f in devices):
        found += await modem(loaded, node, timeout_s)
    if not running:  # (a running bridge holds the node's listen endpoints, too)
        found += await asyncio.to_thread(zenoh_findings, loaded, node)
    if state_dir is not None and not running:
        found += await asyncio.to_thread(state_findings, loaded, node, state_dir)
    state = await asyncio.to_thread(read_clock, run)
    found += clock_findings(loaded, state, _pps_devices())
    return found
