"""``zab doctor`` against emulated modems on real ptys, real Zenoh sessions and clock outputs."""

from __future__ import annotations

import asyncio
import contextlib
import os
import re
import secrets
import socket
import subprocess
import sys
from collections.abc import AsyncIterator, Sequence
from pathlib import Path

import pytest
import yaml

from bridge.cli.doctor import (
    ClockState,
    Finding,
    clock_findings,
    parse_chronyc,
    parse_timedatectl,
    run_doctor,
    state_findings,
)
from bridge.core.loaded import LoadedMission
from bridge.errors import BackendError
from bridge.modems.evologics.emulator import EvologicsEmulator
from bridge.modems.micromodem.emulator import MicromodemEmulator
from bridge.modems.setup import backend_factory, modem_setup
from bridge.modems.transport import ByteTransport
from bridge.runtime.fleet import water_for
from bridge.runtime.state_file import StateFile
from tests.conftest import MISSIONS, REPO, free_port, on_free_ports

CHRONY = """\
Reference ID    : C0A80101 (surface.local)
Stratum         : 3
Ref time (UTC)  : Tue Mar 03 10:12:01 2026
System time     : {offset} seconds {side} of NTP time
Last offset     : -0.000004203 seconds
RMS offset      : 0.000010031 seconds
Frequency       : 12.702 ppm slow
Residual freq   : -0.001 ppm
Skew            : 0.021 ppm
Root delay      : 0.000356 seconds
Root dispersion : 0.000121 seconds
Update interval : 64.4 seconds
Leap status     : {leap}
"""


def no_tools(argv: Sequence[str]) -> str | None:
    return None


def by_check(findings: list[Finding]) -> dict[str, list[Finding]]:
    out: dict[str, list[Finding]] = {}
    for f in findings:
        out.setdefault(f.check, []).append(f)
    return out


def prepared(name: str, node: str, device: Path, water_port: int, **options: object
             ) -> LoadedMission:
    data = yaml.safe_load((MISSIONS / name).read_text())
    data["modem"]["options"]["water"] = f"127.0.0.1:{water_port}"
    data["nodes"][node]["modem"]["options"].update({"device": str(device), **options})
    return on_free_ports(yaml.safe_dump(data, sort_keys=False), name)


@contextlib.asynccontextmanager
async def emulated(kind: str, tmp_path: Path, device: str | None = None, **options: object
                   ) -> AsyncIterator[tuple[LoadedMission, str, object]]:
    """The mission's first node with an emulated modem behind a pty link, in the water: a
    ``kind`` modem, or a ``device`` one behind the ``kind`` backend."""
    name = {"evologics": "morph_evologics.yaml", "micromodem": "remus_micromodem.yaml"}[kind]
    node = {"evologics": "ssv", "micromodem": "topside"}[kind]
    water_port = free_port()
    loaded = prepared(name, node, tmp_path / f"modem-{node}", water_port, **options)
    water = water_for(loaded)
    await water.start("127.0.0.1", water_port)
    setup = modem_setup(loaded.mission, node)
    emulator = (EvologicsEmulator(setup, link=tmp_path / f"modem-{node}")
                if (device or kind) == "evologics"
                else MicromodemEmulator(setup, link=tmp_path / f"modem-{node}",
                                        rev_period_s=None))
    evologics = isinstance(emulator, EvologicsEmulator)
    await (emulator.start() if evologics else emulator.open())
    try:
        yield loaded, node, emulator
    finally:
        await (emulator.stop() if evologics else emulator.close())
        await water.stop()


@pytest.mark.parametrize("kind", ["evologics", "micromodem"])
def test_a_ready_vehicle_passes(tmp_path: Path, kind: str) -> None:
    async def main() -> list[Finding]:
        async with emulated(kind, tmp_path, timeout_s=1.0) as (loaded, node, _):
            return await run_doctor(loaded, node, timeout_s=10, run=no_tools)

    found = by_check(asyncio.run(asyncio.wait_for(main(), 30)))
    assert all(f.status != "fail" for f in found["mission"])  # remus: budget warnings
    assert found["device"][0].status == "ok"
    assert found["modem"][0].status == "ok" and "answered" in found["modem"][0].message
    assert found["zenoh"][0].status == "ok"
    assert found["clock"][0].status == "warn"  # TDMA mission, no clock tool to ask


def test_beside_a_running_bridge_the_modem_is_left_alone(tmp_path: Path) -> None:
    """Found from outside: doctor beside the node's running bridge opened the same port,
    disturbed the bridge and called the healthy modem FAIL. The bridge holds the node's state
    lock (as `zab run` does) and its port: doctor says a bridge is running and skips the
    modem, Zenoh and state checks, without a byte to the modem."""
    async def main() -> tuple[list[Finding], int]:
        async with emulated("micromodem", tmp_path) as (loaded, node, emulator):
            state = StateFile(tmp_path / "state", loaded.mission.mission, node)
            state.hold()
            port = ByteTransport(str(tmp_path / f"modem-{node}"))
            await port.open()
            try:
                lines = emulator.stats["lines"]  # type: ignore[attr-defined]
                found = await run_doctor(loaded, node, timeout_s=10, run=no_tools,
                                         state_dir=tmp_path / "state")
                return found, emulator.stats["lines"] - lines  # type: ignore[attr-defined]
            finally:
                await port.close()
                state.release()

    found, heard = asyncio.run(asyncio.wait_for(main(), 30))
    checks = by_check(found)
    [bridge] = checks["bridge"]
    assert bridge.status == "warn" and f"process {os.getpid()}" in bridge.message
    assert "modem" not in checks and "state" not in checks and "zenoh" not in checks
    assert all(f.status != "fail" for f in found) and heard == 0


def test_a_modem_that_does_not_answer_fails_with_a_fix(tmp_path: Path) -> None:
    async def main() -> list[Finding]:
        async with emulated("evologics", tmp_path, timeout_s=0.2, probe_retries=1) as (
                loaded, node, emulator):
            emulator.deaf = True  # type: ignore[attr-defined]
            return await run_doctor(loaded, node, timeout_s=10, run=no_tools)

    [modem] = by_check(asyncio.run(asyncio.wait_for(main(), 30)))["modem"]
    assert modem.status == "fail" and "no answer" in modem.message
    assert modem.fix is not None and "cable" in modem.fix


@pytest.mark.parametrize(("backend", "device", "said"), [
    ("evologics", "micromodem", r"'\$CAERR,\d+,NMEA,1,Bad sentence\*[0-9A-F]{2}'"),
    ("micromodem", "evologics", r"'\+\+\+AT\?MODE:\d+:\w+'")])
def test_a_modem_of_the_other_kind_is_named_with_the_line_it_answered(
        tmp_path: Path, backend: str, device: str, said: str) -> None:
    """Found from outside: the evologics backend at a Micro-Modem said "no answer within 5 s:
    check the power and cable", though the modem answered $CAERR; the micromodem backend at an
    EvoLogics "no echo of $CCCFG,SRC". Doctor now names the protocol the device speaks, with
    the first line telling so, and the backend to set."""
    quick = {"evologics": {"probe_retries": 1}, "micromodem": {"retries": 0}}[backend]

    async def main() -> list[Finding]:
        async with emulated(backend, tmp_path, device, timeout_s=0.5, **quick) as (
                loaded, node, _):
            return await run_doctor(loaded, node, timeout_s=10, run=no_tools)

    [modem] = by_check(asyncio.run(asyncio.wait_for(main(), 30)))["modem"]
    assert modem.status == "fail"
    assert re.fullmatch(rf"{backend}: the device answers, but speaks the {device} protocol: "
                        f"{said}", modem.message), modem.message
    assert modem.fix is not None and modem.fix.startswith(f"set `backend: {device}`")


def test_the_evologics_driver_says_what_another_modem_wrote(tmp_path: Path) -> None:
    """What `zab run` logs at each retry, too: not only "no answer"."""
    async def main() -> str:
        async with emulated("evologics", tmp_path, "micromodem", timeout_s=0.5,
                            probe_retries=1) as (loaded, node, _):
            backend = backend_factory(loaded.mission, node)()
            try:
                await backend.open()
            except BackendError as exc:
                return str(exc)
            finally:
                await backend.close()
            return "opened"

    error = asyncio.run(asyncio.wait_for(main(), 30))
    assert re.search(r"no answer from the modem .*; the device wrote '\$CAERR,\d+,NMEA,1,Bad "
                     r"sentence\*[0-9A-F]{2}' instead \(another kind of modem\? zab doctor "
                     r"tells\)$", error), error


def test_missing_device_and_busy_endpoint_fail(tmp_path: Path) -> None:
    loaded = prepared("morph_evologics.yaml", "ssv", tmp_path / "nothing-here", free_port())
    endpoint = loaded.mission.nodes["ssv"].zenoh.listen[0]
    port = int(endpoint.rsplit(":", 1)[1])
    with socket.socket() as held:
        held.bind(("127.0.0.1", port))
        held.listen()
        found = by_check(asyncio.run(run_doctor(loaded, "ssv", timeout_s=2, run=no_tools)))
    assert found["device"][0].status == "fail" and "does not exist" in found["device"][0].message
    assert "modem" not in found  # not opened when the device is missing
    assert found["zenoh"][0].status == "fail"


def test_doctor_command_prints_fixes_and_exits_1(tmp_path: Path) -> None:
    loaded = prepared("morph_evologics.yaml", "gcv", tmp_path / "no-modem", free_port())
    mission = tmp_path / "m.yaml"
    mission.write_text(yaml.safe_dump(loaded.mission.model_dump(
        by_alias=True, mode="json", exclude_unset=True)))
    done = subprocess.run([sys.executable, "-m", "bridge", "doctor", str(mission), "--node",
                           "gcv"], capture_output=True, text=True, timeout=60, cwd=REPO,
                          env={**os.environ, "ZAB_KEY": secrets.token_hex(32)})
    assert done.returncode == 1, done.stdout + done.stderr
    assert "FAIL device" in done.stdout and "fix:" in done.stdout
    assert re.search(r"^gcv: 1 to fix, (1 warning|\d+ warnings)$", done.stdout, re.M), \
        done.stdout  # (the clock's warning or not, by the machine; "1 warning(s)" once)
    unknown = subprocess.run([sys.executable, "-m", "bridge", "doctor", str(mission), "--node",
                              "nobody"], capture_output=True, text=True, timeout=60, cwd=REPO)
    assert unknown.returncode == 1 and "no node 'nobody'" in unknown.stdout


def test_clock_outputs_are_parsed_and_judged_against_the_guard() -> None:
    loaded = on_free_ports((MISSIONS / "morph.yaml").read_text())  # TDMA, guard 0.3 s
    good = parse_chronyc(CHRONY.format(offset="0.000012000", side="fast", leap="Normal"))
    assert good == ClockState("chrony", True, 0.000012, "C0A80101 (surface.local)")
    assert clock_findings(loaded, good)[0].status == "ok"
    slow = parse_chronyc(CHRONY.format(offset="0.200000000", side="slow", leap="Normal"))
    assert slow is not None and slow.offset_s == pytest.approx(-0.2)
    assert clock_findings(loaded, slow)[0].status == "fail"
    drifting = parse_chronyc(CHRONY.format(offset="0.040000000", side="fast", leap="Normal"))
    assert clock_findings(loaded, drifting)[0].status == "warn"
    lost = parse_chronyc(CHRONY.format(offset="0.0", side="fast", leap="Not synchronised"))
    [finding] = clock_findings(loaded, lost)
    assert finding.status == "fail" and finding.fix and "chrony" in finding.fix
    assert parse_chronyc("506 Cannot talk to daemon") is None
    synced = parse_timedatectl("Timezone=UTC\nNTP=yes\nNTPSynchronized=yes\n")
    assert synced == ClockState("timedatectl", True, None, "NTP service on")
    assert clock_findings(loaded, synced)[0].status == "ok"
    unsynced = parse_timedatectl("NTP=no\nNTPSynchronized=no\n")
    assert unsynced is not None and clock_findings(loaded, unsynced)[0].status == "fail"
    assert clock_findings(loaded, None, ["/dev/pps0"])[0].message.startswith("PPS device")
    data = yaml.safe_load((MISSIONS / "morph.yaml").read_text())
    data["mac"] = {"type": "none"}
    free_mac = on_free_ports(yaml.safe_dump(data))
    assert clock_findings(free_mac, None)[0].status == "ok"


def test_the_state_directory_must_take_a_save(tmp_path: Path) -> None:
    """A real save in the node's state directory: fine; on a full or read-only filesystem (a
    real tmpfs) a failure saying why and what to do."""
    from tests.runtime.tmpfs import fill, remount, small_tmpfs

    loaded = on_free_ports((MISSIONS / "morph.yaml").read_text())
    [fine] = state_findings(loaded, "gcv", tmp_path / "state")
    assert fine.status == "ok" and "takes a save" in fine.message
    assert not any((tmp_path / "state").iterdir())  # the probe is gone
    with small_tmpfs(tmp_path / "small") as where:
        [low] = state_findings(loaded, "gcv", where)
        assert low.status == "warn" and "KiB free" in low.message
        filler = fill(where)
        [full] = state_findings(loaded, "gcv", where)
        assert full.status == "fail" and "No space left on device" in full.message
        assert full.fix is not None and "refuses new reliable values" in full.fix
        filler.unlink()
        remount(where, "ro")
        [read_only] = state_findings(loaded, "gcv", where)
        assert read_only.status == "fail" and "not writable" in read_only.message
