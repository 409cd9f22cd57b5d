"""A surface node publishes the fixes of its modem's USBL head (MM2 ``$CAUSB2``) on Zenoh."""

from __future__ import annotations

import asyncio
import contextlib
import math
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from bridge.modems.micromodem.nmea import LineBuffer, Sentence, parse_sentence
from tests.conftest import on_free_ports
from tests.harness import Inbox, outside_session, running_fleet

MISSION = """
mission: usbl
modem:
  backend: micromodem
  options: {{device: {device}, timeout_s: 1}}
mac: {{type: none}}
nodes:
  top: {{address: 1, role: surface}}
  auv: {{address: 2}}
channels: []
"""

# azimuth 30 deg, elevation 20 deg (down), one-way travel time 0.1 s: 150 m slant range
USB2 = Sentence("CA", "USB2", ("0", "2025-05-29T15:26:07.286444", "30.0", "20.0", "0.1", "2",
                               *["0.1", "0.0"] * 4, "3"))


@contextlib.contextmanager
def scripted_modem(link: Path) -> Iterator[None]:
    """A modem on a pty that echoes ``$CCCFG`` and, once set up, hears node 2 (``$CAMPA``)
    and locates it (``$CAUSB2``) every half second, as an MM2 with a USBL head prints them."""
    from bridge.modems.pty_host import PtyHost

    loop = asyncio.new_event_loop()
    ready = threading.Event()
    lines = LineBuffer()

    def on_data(data: bytes) -> None:
        for line in lines.feed(data)[0]:
            cmd = parse_sentence(line)
            if cmd.kind == "CFG":
                pty.write(Sentence("CA", "CFG", cmd.fields).encode())
                loop.call_later(0.5, heard)

    def heard() -> None:
        pty.write(Sentence("CA", "MPA", ("2", "1")).encode())
        pty.write(USB2.encode())
        loop.call_later(0.5, heard)

    pty = PtyHost(on_data, link=link)

    def main() -> None:
        loop.run_until_complete(pty.open())
        ready.set()
        loop.run_forever()
        loop.run_until_complete(pty.close())
        loop.close()

    thread = threading.Thread(target=main, daemon=True)
    thread.start()
    try:
        assert ready.wait(5)
        yield
    finally:
        loop.call_soon_threadsafe(loop.stop)
        thread.join(5)


def test_surface_node_publishes_the_usbl_fix(tmp_path: Path) -> None:
    link = tmp_path / "mm-top"
    loaded = on_free_ports(MISSION.format(device=link), "usbl.yaml")
    with scripted_modem(link), running_fleet(loaded, only=["top"]):
        app = outside_session(loaded, "top")
        try:
            inbox = Inbox()
            app.declare_subscriber("@zab/usbl/top/usbl/*", inbox)
            key, fix, _ = inbox.get(10)
        finally:
            app.close()
    assert key == "@zab/usbl/top/usbl/auv"
    slant, down = 150.0, 150.0 * math.sin(math.radians(20))
    level = 150.0 * math.cos(math.radians(20))
    assert fix["range_m"] == pytest.approx(slant)
    assert (fix["azimuth_deg"], fix["elevation_deg"]) == (30.0, 20.0)
    assert fix["down_m"] == pytest.approx(down)
    assert fix["east_m"] == pytest.approx(level * 0.5)
    assert fix["north_m"] == pytest.approx(level * math.sqrt(3) / 2)
    assert fix["covariance"] is None  # $CAUSB2 carries none
