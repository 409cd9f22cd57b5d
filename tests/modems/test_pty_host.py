"""The stable link of an emulated modem's pty (``zab emulate --link``, the ``device`` a bridge
opens) belongs to the emulator that made it: a second emulator for the same node, refused by
the water or failing to start, leaves the running one's link as it was, and an emulator
removes its link on close only while the link still points to its own pty."""

from __future__ import annotations

import asyncio
import os
import socket
from collections.abc import Awaitable, Callable
from pathlib import Path

import pytest

from bridge.errors import BackendError
from bridge.mission.presets import get_preset
from bridge.modems.base import ModemSetup
from bridge.modems.evologics.emulator import EvologicsEmulator
from bridge.modems.micromodem.emulator import MicromodemEmulator
from bridge.modems.pty_host import PtyHost
from bridge.modems.transport import ByteTransport
from bridge.sim.service import WaterService

FAST = get_preset("evologics-s2c-im").replace(name="test-evologics", overhead_s=0.02,
                                              per_byte_s=0.001)


def arun(main: Callable[[], Awaitable[None]], timeout: float = 15.0) -> None:
    asyncio.run(asyncio.wait_for(main(), timeout))


def setup_in(water: WaterService, address: int = 1) -> ModemSetup:
    return ModemSetup(node="ssv", address=address, frame_bytes=64,
                      options={"water": f"127.0.0.1:{water.port}"}, position=(0.0, 0.0, 0.0))


async def reachable(device: Path) -> None:
    """A driver opens ``device`` (the link) as it would at sea."""
    port = ByteTransport(str(device))
    await port.open()
    await port.close()


def test_a_host_closing_leaves_a_link_it_did_not_make(tmp_path: Path) -> None:
    async def main() -> None:
        link = tmp_path / "modem"
        first = PtyHost(lambda data: None, link=link)
        await first.open()
        other = PtyHost(lambda data: None, link=link)  # never opened
        await other.close()
        assert os.readlink(link) == first.path
        await first.replug()  # the first's own link follows its fresh pty
        assert os.readlink(link) == first.path
        os.replace(_symlink(tmp_path, "/dev/null"), link)  # someone else's link now
        await first.close()
        assert os.readlink(link) == "/dev/null"

    arun(main)


def test_a_host_removes_its_own_link_on_close_and_never_a_file(tmp_path: Path) -> None:
    async def main() -> None:
        link = tmp_path / "modem"
        host = PtyHost(lambda data: None, link=link)
        await host.open()
        await host.close()
        assert not link.exists() and not link.is_symlink()
        link.write_text("not a pty")
        with pytest.raises(BackendError, match="not a symlink"):
            await PtyHost(lambda data: None, link=link).open()
        assert link.read_text() == "not a pty"

    arun(main)


@pytest.mark.parametrize("kind", ["evologics", "micromodem"])
def test_a_second_emulator_refused_by_the_water_leaves_the_first_ones_link(
        tmp_path: Path, kind: str) -> None:
    async def main() -> None:
        water = WaterService(FAST, seed=1)
        await water.start()
        link = tmp_path / "pty-ssv"
        first, second = (_emulator(kind, setup_in(water), link) for _ in range(2))
        try:
            await _start(first)
            assert os.readlink(link) == first.pty.path
            with pytest.raises(BackendError, match="modem address 1 is already in the water"):
                await _start(second)
            await _stop(second)  # as `zab emulate` does when it cannot start
            assert os.readlink(link) == first.pty.path
            await reachable(link)  # a bridge reopening its modem finds it
        finally:
            await _stop(first)
            await _stop(second)
            await water.stop()
        assert not link.is_symlink()  # the first removed its own link

    arun(main)


def test_the_link_is_made_once_the_emulator_is_up(tmp_path: Path) -> None:
    async def main() -> None:
        waters = [WaterService(FAST, seed=1), WaterService(FAST, seed=1)]
        for water in waters:
            await water.start()
        link = tmp_path / "pty-ssv"
        first = EvologicsEmulator(setup_in(waters[0]), link=link)
        with socket.socket() as taken:
            taken.bind(("127.0.0.1", 0))
            taken.listen()
            second = EvologicsEmulator(setup_in(waters[1]), link=link,
                                       tcp_port=taken.getsockname()[1])
            try:
                await first.start()
                with pytest.raises(BackendError, match=r"cannot listen on TCP port \d+: Address "
                                   "already in use"):  # it joins its water, then cannot listen
                    await second.start()
                await second.stop()
                assert os.readlink(link) == first.pty.path
            finally:
                await first.stop()
                await second.stop()
                for water in waters:
                    await water.stop()

    arun(main)


def _symlink(folder: Path, target: str) -> Path:
    path = folder / "elsewhere"
    path.symlink_to(target)
    return path


def _emulator(kind: str, setup: ModemSetup, link: Path) -> EvologicsEmulator | MicromodemEmulator:
    if kind == "evologics":
        return EvologicsEmulator(setup, link=link)
    return MicromodemEmulator(setup, link=link)


async def _start(emulator: EvologicsEmulator | MicromodemEmulator) -> None:
    if isinstance(emulator, EvologicsEmulator):
        await emulator.start()
    else:
        await emulator.open()


async def _stop(emulator: EvologicsEmulator | MicromodemEmulator) -> None:
    if isinstance(emulator, EvologicsEmulator):
        await emulator.stop()
    else:
        await emulator.close()


def test_a_second_opener_of_a_port_is_told_it_is_busy(tmp_path: Path) -> None:
    """A port is opened exclusively: `zab doctor` beside a running bridge gets "busy" instead
    of sharing (and disturbing) the modem's line; once the first closes, it opens."""
    async def main() -> None:
        host = PtyHost(lambda data: None, link=tmp_path / "modem")
        device = await host.open()
        first, second = ByteTransport(device), ByteTransport(device)
        try:
            await first.open()
            with pytest.raises(BackendError, match="busy"):
                await second.open()
            await first.close()
            await second.open()
        finally:
            await second.close()
            await first.close()
            await host.close()

    arun(main)
