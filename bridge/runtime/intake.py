"""Samples from Zenoh into the bridge, in bounded memory whatever the input rate.

Anyone on a vehicle's Zenoh network can publish on the bridge's input keys, as fast and as big
as they like. Three places could hold what they send, and each is bounded here:

- *Zenoh's queue.* A plain callback subscriber hands each sample to a Python thread through a
  queue of Zenoh's own that holds whole samples: one application putting 1 MB samples as fast
  as it could held ~460 MB there (a ``RingChannel`` of 8: ~45 MB with six such applications,
  with shared memory off as :func:`~bridge.runtime.session.zenoh_config` sets it; a
  subscriber that sleeps 1 ms a sample, eclipse-zenoh 1.10). Each subscription here is a
  ``RingChannel`` of :data:`RING` samples:
  Zenoh drops the oldest, in Rust, without waiting for the GIL, so one flooded key never
  holds back another's samples (Zenoh does not say how many it dropped).
- *The hand-off to the event loop.* A thread of ours per subscription takes the samples out
  (:meth:`Intake.subscribe`); what must run on the loop waits in a queue of :data:`HANDOFF`
  calls per *lane* (:meth:`Intake.to_loop`: a subscription's key; a key family's samples, each
  under its own key, share their subscription's lane), the oldest dropped and counted
  (:attr:`Intake.overflow`), and the loop is woken once for a batch, not once per sample.
- *Reliable channels' keys* (``subscribe(..., fifo=True)``) lose nothing on the way in: a
  burst bigger than both queues must reach the channel's own queue whole (which refuses, with
  a report, what it cannot hold). Their subscription is a ``FifoChannel`` of :data:`RING`
  samples (Zenoh's thread waits for room: backpressure to the publisher) and their lane waits
  for room rather than dropping (:meth:`Intake.to_loop` from the subscription's thread), until
  :meth:`Intake.close` at shutdown. Memory stays bounded the same.
- *Failures.* A sample whose handling raises (it never should: bad input is a counted drop) is
  counted (:attr:`Intake.errors`) and its traceback logged at most once a minute per key; the
  thread goes on with the next sample. Only the session's end stops it.
- *The last sample.* A thread holds no sample while it waits for the next: a huge one dropped
  as over its key's cap would otherwise keep Zenoh's buffers for it (up to the payload's size)
  until the key's next sample (:mod:`bridge.runtime.heap` gives the freed heap back).
"""

from __future__ import annotations

import asyncio
import logging
import math
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from typing import Any

import zenoh

log = logging.getLogger("zab.node")

RING = 8
"""Samples Zenoh keeps per subscription while its thread is busy (the oldest dropped)."""
HANDOFF = 16
"""Calls per lane waiting for the event loop (the oldest dropped, counted)."""
TRACEBACK_EVERY_S = 60.0


class Intake:
    """The bridge's subscriptions on one session, each drained by a thread of its own."""

    def __init__(self, session: zenoh.Session, loop: asyncio.AbstractEventLoop,
                 node: str) -> None:
        self.session = session
        self.loop = loop
        self.node = node
        self.overflow: Counter[str] = Counter()
        """Calls dropped from the hand-off to the loop, per key."""
        self.errors: Counter[str] = Counter()
        """Samples whose handling raised, per key."""
        self._waiting: dict[str, deque[Callable[[], object]]] = {}
        self._lock = threading.Lock()
        self._room = threading.Condition(self._lock)  # a lane was emptied, or the intake closed
        self._fifo: set[str] = set()  # lanes that wait for room (reliable channels' keys)
        self._closed = False
        self._woken = False  # a call to _run is on its way to the loop
        self._told: dict[str, float] = {}  # when each key's last traceback was logged
        self.subscribers: list[Any] = []
        self._threads: list[threading.Thread] = []

    def subscribe(self, key: str, handle: Callable[[zenoh.Sample], None], *,
                  fifo: bool = False) -> None:
        """Subscribe to ``key``; ``handle`` gets each sample on this subscription's thread.
        ``fifo`` (a reliable channel's key): no sample dropped, neither by Zenoh nor in the
        lane ``key`` (each waits for room)."""
        if fifo:
            self._fifo.add(key)
        handler: Any = zenoh.handlers.FifoChannel(RING) if fifo \
            else zenoh.handlers.RingChannel(RING)
        subscriber = self.session.declare_subscriber(key, handler)
        self.subscribers.append(subscriber)
        thread = threading.Thread(target=self._drain, args=(subscriber, key, handle),
                                  daemon=True, name=f"zab-in {key}")
        thread.start()
        self._threads.append(thread)

    def close(self) -> None:
        """The node stops (before the session closes): a thread waiting for room in a lane
        returns at once, its call dropped, and no call waits from now on."""
        with self._lock:
            self._closed = True
            self._room.notify_all()

    def join(self, timeout_s: float = 2.0) -> None:
        """After the session closed (which ends every subscription): wait for the threads to
        return. A thread still inside Zenoh when the interpreter exits is unwound through
        Rust code, and the process aborts (``FATAL: exception not rethrown``)."""
        end = time.monotonic() + timeout_s
        for thread in self._threads:
            thread.join(max(0.0, end - time.monotonic()))

    def _drain(self, subscriber: Any, key: str, handle: Callable[[zenoh.Sample], None]
               ) -> None:
        while True:
            try:
                sample = subscriber.recv()  # (releases the GIL while it waits)
            except Exception:  # the session closed: ZError "channel is empty and closed"
                return
            try:
                handle(sample)
            except Exception:
                self.failed(key)
            del sample  # (not held while the next is awaited: a huge one's buffers go back)

    def failed(self, key: str) -> None:
        """Handling something that came on ``key`` raised: counted, its traceback logged at
        most once a minute per key (call from the ``except`` block)."""
        self.errors[key] += 1
        now = time.monotonic()
        if now - self._told.get(key, -math.inf) >= TRACEBACK_EVERY_S:
            self._told[key] = now
            log.exception("%s: a sample on %r could not be handled (counted as intake_errors; "
                          "this traceback is logged at most once a minute per key)",
                          self.node, key)

    def to_loop(self, key: str, call: Callable[[], object]) -> None:
        """Run ``call`` on the loop soon; at most :data:`HANDOFF` wait per lane ``key``
        (any thread). A full lane drops its oldest call, counted, unless it is a ``fifo``
        subscription's: then a thread other than the loop's waits for room (after
        :meth:`close`, ``call`` is dropped)."""
        with self._lock:
            waiting = self._waiting.get(key)
            if key in self._fifo and not self._on_loop():
                while waiting is not None and len(waiting) >= HANDOFF and not self._closed:
                    self._room.wait()  # (a run of the lane is on its way: _woken is set)
                    waiting = self._waiting.get(key)
                if self._closed:
                    return
            if waiting is None:
                waiting = self._waiting[key] = deque(maxlen=HANDOFF)
            if len(waiting) == HANDOFF:
                self.overflow[key] += 1
            waiting.append(call)
            wake, self._woken = not self._woken, True
        if wake:
            try:
                self.loop.call_soon_threadsafe(self._run)
            except RuntimeError:  # the loop has closed: the node is gone, nothing will wait
                self.close()

    def _on_loop(self) -> bool:
        """Whether this thread runs the loop (which must never wait for itself)."""
        try:
            return asyncio.get_running_loop() is self.loop
        except RuntimeError:
            return False

    def _run(self) -> None:
        """On the loop: every waiting call, a key's in the order they came."""
        with self._lock:
            batches = [(key, list(waiting)) for key, waiting in self._waiting.items()]
            self._waiting.clear()  # (a lane is made again when it has something)
            self._woken = False
            self._room.notify_all()
        for key, batch in batches:
            for call in batch:
                try:
                    call()
                except Exception:
                    self.failed(key)

    def snapshot(self) -> dict[str, Any]:
        """Counters for the node's stats."""
        return {"ring": RING, "handoff": HANDOFF, "overflow": dict(self.overflow),
                "errors": dict(self.errors)}
