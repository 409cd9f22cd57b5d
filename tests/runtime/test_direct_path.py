"""A direct backend (``udp``) carries a sample from the Zenoh callback to the wire and from
the wire to Zenoh with no hop through the event loop; what the loop's consumers get (events)
still reaches them there."""

from __future__ import annotations

import itertools
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import zenoh

from bridge.core.events import Event, FrameReceived, FrameSent
from bridge.runtime.fleet import Fleet
from bridge.runtime.zenoh_node import EVENTS_S
from tests.conftest import on_free_ports, udp_ports
from tests.harness import Inbox, outside_session, put, running_fleet

MISSION = """\
mission: direct
modem: {backend: udp, frame_bytes: 16}
mac: {type: none}
nodes:
  a: {address: 1, modem: {options: {port: PORT_A}}}
  b: {address: 2, modem: {options: {port: PORT_B}}}
channels:
  - name: cmd
    from: a
    to: b
    elements: [{in: cmd, out: a/cmd, fields: [{field: n, type: int, min: 0, max: 255}]}]
"""


def mission():
    text = udp_ports(MISSION)
    return on_free_ports(text, "direct.yaml")


@dataclass
class Crossing:
    """A running fleet, an application at ``a`` that puts ``cmd``, ``inbox`` of ``a/cmd`` at
    ``b``, and ``seen``: every event as (node, kind, thread carrying it out)."""

    fleet: Fleet
    app: zenoh.Session
    inbox: Inbox
    seen: list[tuple[str, type, str]]

    def frames_sent(self) -> list[str]:
        """The thread each of ``a``'s ``FrameSent`` events was carried out on."""
        return [where for who, kind, where in self.seen if who == "a" and kind is FrameSent]


@contextmanager
def crossing() -> Iterator[Crossing]:
    loaded = mission()
    seen: list[tuple[str, type, str]] = []

    def on_event(node: str, event: Event) -> None:
        seen.append((node, type(event), threading.current_thread().name))

    with running_fleet(loaded, on_event=on_event) as fleet:
        a, b = outside_session(loaded, "a"), outside_session(loaded, "b")
        try:
            inbox = Inbox()
            b.declare_subscriber("a/cmd", inbox)
            time.sleep(0.3)  # the declarations reach the bridges
            yield Crossing(fleet, a, inbox, seen)
        finally:
            a.close()
            b.close()


def test_a_sample_crosses_while_the_event_loop_is_busy_and_events_follow_on_the_loop() -> None:
    with crossing() as c:
        put(c.app, "cmd", {"n": 1})
        assert c.inbox.get(5)[1] == {"n": 1}  # the path works at all
        loop = c.fleet.nodes["a"]._loop
        assert loop is not None
        busy = threading.Event()
        loop.call_soon_threadsafe(lambda: (busy.set(), time.sleep(1.5)))
        assert busy.wait(2)
        blocked_at = time.time()
        put(c.app, "cmd", {"n": 2})
        key, value, at = c.inbox.get(5)
        assert (key, value) == ("a/cmd", {"n": 2})
        assert at - blocked_at < 1.0, "the sample waited for the blocked loop"
        time.sleep(max(0.0, blocked_at + 2.0 - time.time()))  # the loop is back
        assert c.frames_sent() == ["fleet"] * 2
        received = [where for who, kind, where in c.seen if who == "b" and kind is FrameReceived]
        assert received == ["fleet"] * 2
        assert c.fleet.nodes["b"].stats.values_published == 2


def test_steady_traffic_does_not_wake_the_loop_per_frame() -> None:
    """The events of a steady data path reach the loop by the loop's own timer: one wake from
    the data path starts it, not one per batch."""
    with crossing() as c:
        put(c.app, "cmd", {"n": 0})
        assert c.inbox.get(5)[1] == {"n": 0}
        time.sleep(3 * EVENTS_S)  # quiet: the timer has stopped
        loop = c.fleet.nodes["a"]._loop
        assert loop is not None
        wakes: list[str] = []
        plain = loop.call_soon_threadsafe

        def counted(callback, *args):  # type: ignore[no-untyped-def]
            wakes.append(getattr(callback, "__name__", repr(callback)))
            return plain(callback, *args)

        loop.call_soon_threadsafe = counted  # type: ignore[method-assign]
        sent = 12
        times: list[float] = []
        for n in range(1, sent + 1):  # ~0.3 s of traffic: six batches of events
            times.append(time.monotonic())
            put(c.app, "cmd", {"n": n})
            assert c.inbox.get(5)[1] == {"n": n}
            time.sleep(EVENTS_S / 2)
        time.sleep(3 * EVENTS_S)
        del loop.call_soon_threadsafe
        # a gap of over a timer period lets the timer stop, and the next frame start it again
        # (a loaded machine stretches the round trip between puts past it)
        pauses = sum(1 for a, b in itertools.pairwise(times) if b - a > EVENTS_S)
        assert len(wakes) <= 2 + pauses, \
            f"the data path woke a's loop {len(wakes)} times ({pauses} pauses): {wakes}"
        assert c.frames_sent() == ["fleet"] * (sent + 1)  # every event arrived, on the loop


def test_each_sample_leaves_from_the_zenoh_callback_with_its_books_kept_at_once() -> None:
    """The one path, called from the Zenoh callback: every sample's frame is sent on Zenoh's
    thread, in order, and the node's counters and store are up to date as it leaves."""
    with crossing() as c:
        node = c.fleet.nodes["a"]
        backend = node.backend
        assert backend is not None
        threads: list[str] = []
        plain = backend.send_now

        def counted(*args, **kwargs):  # type: ignore[no-untyped-def]
            threads.append(threading.current_thread().name)
            return plain(*args, **kwargs)

        backend.send_now = counted  # type: ignore[method-assign]
        sent = 20
        for n in range(sent):
            put(c.app, "cmd", {"n": n})
            assert c.inbox.get(5)[1] == {"n": n}
            with node.lock:
                assert node.stats.frames_sent == n + 1  # kept as the frame left, not later
            time.sleep(0.02)
        assert len(threads) == sent and "fleet" not in threads  # never the loop's thread
        state = node.core.store.states[0]
        assert state.sends == sent and state.packed == [sent - 1] and not state.fresh
        time.sleep(3 * EVENTS_S)  # the events reach the loop
        assert c.frames_sent() == ["fleet"] * sent
        assert c.fleet.nodes["b"].stats.values_published == sent
