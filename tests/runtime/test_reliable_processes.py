"""Reliable channels through real processes: delivery reports reach Zenoh with the
publisher's ref, and ``bench/chaos.py``'s run with ``zab water`` and a ``zab run`` per node
killed with SIGKILL while commands stream loses and repeats nothing."""

from __future__ import annotations

import msgpack
import zenoh

from tests.conftest import on_free_ports
from tests.core.reliable.test_fleet import MISSION
from tests.harness import Inbox, bench_module, outside_session, running_fleet

LONG = True  # half a minute of processes killed and restarted: handed out first
chaos = bench_module("chaos")


def test_delivery_reports_reach_zenoh_with_the_publishers_ref() -> None:
    text = MISSION.replace("slot_s: 2.0, guard_s: 0.2", "slot_s: 0.5, guard_s: 0.05")
    text = text.replace("options: {preset: evologics-s2c-im}",
                        "options: {preset: evologics-s2c-im, seed: 4}")
    loaded = on_free_ports(text)
    with running_fleet(loaded):
        ops = outside_session(loaded, "ops")
        auv = outside_session(loaded, "auv")
        try:
            reports, commands = Inbox(), Inbox()
            ops.declare_subscriber("@zab/lossy/ops/delivery/command", reports)
            auv.declare_subscriber("ops/cmd", commands)
            ops.put("cmd", msgpack.packb({"n": 5, "go": True}),
                    encoding=zenoh.Encoding("application/msgpack"), attachment=b"ref:abc-1")
            _, value, _ = commands.get(timeout=10)
            assert value == {"n": 5, "go": True}
            states = []
            while "delivered" not in states:
                _, report, _ = reports.get(timeout=10)
                assert report["ref"] == "abc-1" and report["dst"] == "auv"
                states.append(report["state"])
            assert states[:2] == ["queued", "sent"]
        finally:
            ops.close()
            auv.close()


def test_real_processes_killed_with_sigkill_lose_and_repeat_nothing() -> None:
    result = chaos.run_real(36, 0.3, seed=2, kill_every_s=5.0, interval_s=0.4,
                            settle_s=90.0)
    # commands put while ops is down or starting again are never accepted (a third of them
    # on a loaded 2-core machine); what matters is that every accepted one ends once
    assert result["sent"] >= 24, result
    assert chaos.goal_met(result), result
