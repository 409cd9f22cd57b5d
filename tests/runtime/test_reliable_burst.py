"""A burst of puts on a reliable channel's input key, back to back from a plain Zenoh
application, more than the intake holds at once (bridge.runtime.intake): every value reaches
the channel's queue, none is dropped on the way in (the intake waits for room)."""

from __future__ import annotations

import time

import msgpack
import zenoh

from bridge.core.reliable import ReliableSender
from bridge.runtime.intake import HANDOFF, RING
from tests.conftest import on_free_ports
from tests.core.reliable.test_fleet import MISSION
from tests.harness import Inbox, outside_session, running_fleet

BURST = 50


def test_a_burst_on_a_reliable_key_loses_nothing_at_intake() -> None:
    assert BURST > RING + HANDOFF  # more than Zenoh's ring and the hand-off hold together
    loaded = on_free_ports(MISSION)  # command: reliable, queue 1000 (the core takes them all)
    with running_fleet(loaded) as fleet:
        ops = outside_session(loaded, "ops")
        try:
            reports = Inbox()
            ops.declare_subscriber("@zab/lossy/ops/delivery/command", reports)
            time.sleep(0.5)  # the subscriber declared at the bridge's router
            for n in range(BURST):
                ops.put("cmd", msgpack.packb({"n": n, "go": True}),
                        encoding=zenoh.Encoding("application/msgpack"),
                        attachment=f"ref:{n}".encode())
            queued: set[str] = set()
            end = time.time() + 20
            while len(queued) < BURST and time.time() < end:
                try:
                    _, report, _ = reports.get(timeout=max(0.01, end - time.time()))
                except Exception:
                    break
                if report["state"] == "queued":
                    queued.add(report["ref"])
            node = fleet.nodes["ops"]
            intake = node.intake
            assert intake is not None
            with node.lock:  # the channel's sender took each value: an id each
                sender = next(s for s in node.core.outbound.senders.values()
                              if s.channel.name == "command")
                assert isinstance(sender, ReliableSender)
                assert sender.ids.next == BURST
            assert intake.overflow.total() == 0, intake.snapshot()
            assert queued == {str(n) for n in range(BURST)}, \
                f"{BURST - len(queued)} of {BURST} never reached the channel's queue"
        finally:
            ops.close()
