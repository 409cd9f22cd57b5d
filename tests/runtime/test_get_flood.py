"""A flood of Zenoh gets on an asked key stays bounded: at most WAITING_GETS wait for the
bridge's loop, the oldest of the others ended at once with an error and counted, and every get
ends (a reply, or one error), none left hanging."""

from __future__ import annotations

import threading
import time

import zenoh

from bridge.runtime.zenoh_queries import WAITING_GETS
from tests.conftest import MISSIONS, mission_on_free_ports
from tests.harness import outside_session, running_fleet

GETS = 6 * WAITING_GETS


def test_a_flood_of_gets_is_bounded_and_every_get_ends() -> None:
    loaded = mission_on_free_ports(MISSIONS / "zspace.yaml")
    with running_fleet(loaded) as fleet:
        app = outside_session(loaded, "top")
        ended = threading.Semaphore(0)
        errors: list[str] = []
        lock = threading.Lock()
        busy, free = threading.Event(), threading.Event()
        try:
            def on_reply(reply: zenoh.Reply) -> None:
                if reply.err is not None:
                    with lock:
                        errors.append(reply.err.payload.to_string())

            time.sleep(0.3)  # the app's declarations reach the bridge
            loop = fleet.nodes["top"]._loop
            assert loop is not None
            # the bridge's loop is busy until the gets have piled up (however long a loaded
            # machine takes to send them)
            loop.call_soon_threadsafe(lambda: (busy.set(), free.wait(30)))
            assert busy.wait(2)
            for _ in range(GETS):
                app.get("auv1/info?detail=1", zenoh.handlers.Callback(on_reply, ended.release),
                        timeout=30.0)
            deadline = time.monotonic() + 20
            while len(errors) < GETS - WAITING_GETS and time.monotonic() < deadline:
                time.sleep(0.05)  # the refusals come back while the loop is still held
            free.set()
            for _ in range(GETS):
                assert ended.acquire(timeout=40), "a get was left hanging"
            refused = fleet.nodes["top"].snapshot()["queries"]["refused_gets"]
            assert refused >= GETS - WAITING_GETS - 8  # (a few may reach the loop early)
            assert sum("too many gets waiting" in e for e in errors) == refused
        finally:
            free.set()
            app.close()
