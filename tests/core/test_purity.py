"""The sans-I/O core loads no I/O library: importing it pulls in no asyncio, Zenoh, serial or
aiohttp (checked in a fresh interpreter, so other tests' imports do not count)."""

from __future__ import annotations

import subprocess
import sys

PURE = ["bridge.core.node", "bridge.core.mac", "bridge.core.positioning", "bridge.core.store",
        "bridge.core.builder", "bridge.core.reliable", "bridge.core.transfer",
        "bridge.core.link", "bridge.wire.frame", "bridge.wire.auth", "bridge.wire.channels",
        "bridge.mission.loader", "bridge.codec", "bridge.ranging", "bridge.sim.ocean",
        "bridge.gui.model", "bridge.modems.evologics.protocol",
        "bridge.modems.micromodem.protocol", "bridge.modems.protocol", "bridge.core.reception"]
IO = ("asyncio", "zenoh", "serial", "aiohttp")


def test_the_core_imports_no_io_library() -> None:
    code = (f"import sys\nimport {', '.join(PURE)}\n"
            f"print(','.join(m for m in {IO!r} if m in sys.modules))")
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            check=True).stdout.strip()
    assert loaded == ""


def test_the_check_itself_sees_an_io_import() -> None:
    code = "import sys\nimport bridge.runtime.zenoh_node\nprint('zenoh' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "True"
