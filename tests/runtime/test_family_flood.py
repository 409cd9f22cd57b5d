"""An application putting on ever new keys under a key family's input: what waits for the
event loop stays bounded (a lane per subscription, not a queue per key), over a real Zenoh
session. Before, each new key made a queue of its own that was never removed: ``zab run``
grew by 230 MB in a minute of such puts and never gave it back."""

from __future__ import annotations

import time

import msgpack

from bridge.runtime.intake import HANDOFF
from tests.conftest import MISSIONS, mission_on_free_ports
from tests.harness import outside_session, running_fleet


def test_new_keys_flooding_a_family_wait_in_its_lane_and_leave_nothing_behind() -> None:
    loaded = mission_on_free_ports(MISSIONS / "zspace.yaml")
    with running_fleet(loaded) as fleet:
        node = fleet.nodes["auv1"]
        app = outside_session(loaded, "auv1")
        try:
            time.sleep(1.5)  # the subscriptions reach the bridge
            intake = node.intake
            assert intake is not None and node._loop is not None
            node._loop.call_soon_threadsafe(time.sleep, 4.0)  # a busy loop takes nothing
            value = msgpack.packb({"range_m": 5, "bearing_deg": 90})
            for i in range(3000):
                app.put(f"auv1/contacts/c{i}", value)
                app.put(f"auv1/sensors/s{i}/temp", msgpack.packb({"celsius": 5}))
            time.sleep(1.5)  # the intake threads hand off what Zenoh gave them
            with intake._lock:
                lanes = dict(intake._waiting)
                waiting = sum(len(q) for q in lanes.values())
            assert len(lanes) <= 2 and waiting <= 2 * HANDOFF, (len(lanes), waiting)
            assert set(intake.overflow) <= {"auv1/contacts/*", "auv1/sensors/*/temp"}
            assert sum(intake.overflow.values()) > 0
            time.sleep(3.0)  # the loop takes the lanes' last calls, and keeps no lane
            assert not intake._waiting
        finally:
            app.close()
