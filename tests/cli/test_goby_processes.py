"""A Goby-format mission in a real ``zab sim`` process under ``mac: none``: idle nodes send
nothing, a value still crosses, and Ctrl-C stops the process at once. Each idle node used to
build an empty heartbeat frame 10 s in, which the modem refused, and ask again at once for
ever: thousands of warnings a second, and the process no longer heard SIGINT or SIGTERM."""

from __future__ import annotations

import signal
import time
from pathlib import Path

from tests.conftest import MISSIONS
from tests.harness import put
from tests.zsim import Inbox, app, mission_file, zab_sim

GOBY = MISSIONS / "goby_dccl.yaml"
NAV = {"lat": 41.52, "lon": -70.67, "depth": 12.3, "heading": 271.5, "speed": 1.25,
       "battery": 87, "mode": "survey", "time": 43210}
FIRST_HEARTBEAT_S = 10.0  # random access's default heartbeat period, where one was built


def goby_under_no_mac(folder: Path) -> tuple[Path, dict[str, list[str]]]:
    """The example with ``mac: none``, each node on a free port (zab sim picks its water's)."""
    text = GOBY.read_text().replace("dccl/auv.proto", str(GOBY.parent / "dccl" / "auv.proto"))
    tdma = "  type: tdma\n  slot_s: 10.0\n  guard_s: 0.5\n  order: [topside, auv1, topside, auv2]\n"
    assert tdma in text
    return mission_file(text.replace(tdma, "  type: none\n"), folder)


def test_an_idle_goby_fleet_under_mac_none_stays_quiet_and_stops_at_ctrl_c(
        tmp_path: Path) -> None:
    mission, endpoints = goby_under_no_mac(tmp_path)
    with zab_sim(mission, endpoints, timeout=120) as proc:
        started = time.monotonic()
        topside, auv1 = app(endpoints["topside"]), app(endpoints["auv1"])
        try:
            inbox = Inbox()
            topside.declare_subscriber("auv1/nav_status", inbox)
            time.sleep(0.3)
            put(auv1, "nav_status", NAV)
            key, value = inbox.items.get(timeout=20)  # a 17-byte frame at 80 bit/s, ~5 s
            assert key == "auv1/nav_status" and value["mode"] == "survey"
        finally:
            topside.close()
            auv1.close()
        time.sleep(max(0.0, started + FIRST_HEARTBEAT_S + 3.0 - time.monotonic()))
        assert proc.poll() is None
        interrupted = time.monotonic()
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=5)  # (zab_sim kills it if not)
        stopped_s = time.monotonic() - interrupted
        assert proc.stderr is not None
        log = proc.stderr.read()
    assert proc.returncode == 0, log
    assert "send failed" not in log and "empty frame" not in log, log[:2000]
    assert stopped_s < 5
