"""Reliable channels: every value delivered once, in order, or reported failed (pure).

Rules (seed 003's acknowledged commands; selective repeat with a small window):

- The sender queues values (bounded; a full queue refuses the new value or gives up the
  oldest unsent one). Up to ``WINDOW`` values are *in flight*, each with a sequence number
  (``seq``, modulo 256) and ``lag``: how far it is past the oldest value still in flight.
- A value in flight is (re)sent when its timer is due: at once, then after ``retry_s``,
  doubling up to four times that. With several links or routes and no ``retry_s`` of its
  own, the timer learns each receiver's round trips (:meth:`ReliableSender.learn`), and
  doubles only while the receiver is not heard. A value whose acknowledgement shows a later
  one arrived (its copy is lost) goes again at once. Several values of one channel may
  share a frame.
- Receivers acknowledge in frames they send anyway: ``base`` (the next seq they will deliver)
  and a bitmap of the ``WINDOW`` seqs after it that they hold. ``base`` past a value completes
  it for that receiver; a bitmap bit only holds back its retransmission.
- A value fails after ``retries`` retransmissions without acknowledgement, or once older than
  ``ttl_s`` (every stream has one: see :func:`bridge.wire.channels.stream_defaults`); every
  state change is a :class:`~bridge.core.events.Delivery` for the publisher's side, and each
  value ends in exactly one terminal report, ``delivered`` or ``failed``, per receiver.
- A receiver delivers in order, drops duplicates, and skips what the sender gave up: ``seq -
  lag`` tells it the sender's oldest unfinished value, so nothing before it will come again.
- Restarts: both ends save their state (:meth:`ReliableSender.state`,
  :meth:`ReliableReceiver.state`) and resume from it. A node that starts without it begins a
  new *epoch* (``bridge.core.node``): its peers see the change in its frames; a receiver then
  opens a fresh window for it, and a sender calls :meth:`ReliableSender.resync` for it:
  what that receiver held is forgotten and everything outstanding is sent again.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from bridge.core.bounds import network_retry_s
from bridge.core.events import Delivery
from bridge.core.ids import Ids
from bridge.core.mac import mac_for
from bridge.core.persist import int_from_state, int_to_state
from bridge.core.round_trips import BACKOFF_CAP, RoundTrips, retry_wait
from bridge.mission.model import Mission
from bridge.wire.channels import LAG_BITS, SEQ_BITS, WINDOW, ChannelCodec

__all__ = ["BACKOFF_CAP", "DEFAULT_RETRIES", "SEQ_MOD", "Pending", "ReliableReceiver",
           "ReliableSender", "default_retry_s", "retry_wait", "seq_after", "stream_ttl_s"]

SEQ_MOD = 1 << SEQ_BITS
HALF = SEQ_MOD // 2
DEFAULT_RETRIES = 10  # retransmissions when a channel's retries is null (until its TTL)


def default_retry_s(mission: Mission) -> float:
    """The first retransmission's wait when a channel sets no ``retry_s``: the MAC's
    (:meth:`~bridge.core.mac.Mac.retry_s`: one TDMA cycle, else ten seconds); with several
    links or routes, the longest round trip (:func:`~bridge.core.bounds.network_retry_s`)."""
    if mission.links is not None or any(n.routes for n in mission.nodes.values()):
        return network_retry_s(mission)
    return mac_for(mission).retry_s()


def stream_ttl_s(retry_s: float, retries: int | None, queue: int = WINDOW) -> float:
    """The default ``ttl_s`` of a stream, from its creation: each window of ``WINDOW`` values
    ahead of it in a full ``queue`` may take every attempt its retries allow
    (``DEFAULT_RETRIES`` when unbounded) and one more wait. So the TTL ends only values the
    retry limit would have ended anyway, and no value is ever left without a terminal
    report."""
    attempts = (DEFAULT_RETRIES if retries is None else retries) + 2
    windows = -(-queue // WINDOW)
    return windows * sum(retry_wait(retry_s, a) for a in range(1, attempts + 1))


def seq_after(a: int, b: int) -> int:
    """How far ``a`` is after ``b`` modulo 256 (negative when before, within half the space)."""
    d = (a - b) % SEQ_MOD
    return d - SEQ_MOD if d >= HALF else d


@dataclass(eq=False)
class Pending:
    """One value of a reliable channel at its sender."""

    id: int
    payload: int
    created: float
    key: str | None
    ref: str | None
    waiting: set[str]
    seq: int | None = None
    attempts: int = 0
    last_sent: float | None = None
    next_send: float = float("-inf")
    held: set[str] = field(default_factory=set)
    first_sent: float | None = None
    silent: int = 0
    """Copies sent in a row with no acknowledgement heard between them from a receiver
    lacking it (what a learned timer backs off by)."""


class ReliableSender:
    """The sending side of one reliable channel at one node."""

    def __init__(self, channel: ChannelCodec, dests: Iterable[str], retry_s: float,
                 first_seq: int = 0) -> None:
        self.channel = channel
        self.dests = tuple(dests)
        self.retry_s = channel.retry_s or retry_s
        self.ttl_s = channel.ttl_s or stream_ttl_s(self.retry_s, channel.retries,
                                                   channel.queue)
        self.round_trips: dict[str, RoundTrips] = {}
        """Per receiver, where the wait before sending again learns (:meth:`learn`)."""
        self.heard: dict[str, float] = {}
        """Per receiver, when its last acknowledgement came."""
        self._alive: Mapping[str, float] = {}
        """Per receiver, when this node last heard a frame of it (:meth:`learn`)."""
        self.queue: deque[Pending] = deque()  # not yet numbered
        self.flight: list[Pending] = []  # numbered, oldest first
        self.ids = Ids()
        self.changed = False
        """Whether the last :meth:`offer` or :meth:`refuse` changed what a restart must resume
        (a refusal does only when its id starts a new block: :mod:`bridge.core.ids`)."""
        self._next_seq = first_seq % SEQ_MOD

    def learn(self, worst: Mapping[str, float], floor: float,
              heard: Mapping[str, float] | None = None) -> None:
        """The wait before a value is sent again learns each receiver's round trips from
        its acknowledgements (:class:`~bridge.core.round_trips.RoundTrips`, as TCP's timer):
        at first ``worst[d]``, the worst case of the round trip to ``d`` (its route's turns
        and frames, there and back), then the measured mean plus four deviations, never
        below ``floor`` (the MAC's own wait, a neighbour's) nor above ``BACKOFF_CAP`` times
        the worst case. ``heard``: when this node last heard a frame of each node (relayed
        ones by their origin): a receiver heard proves its route works. A channel's own
        ``retry_s`` stands as given."""
        if self.channel.retry_s:
            return
        self._alive = heard if heard is not None else {}
        self.round_trips = {d: RoundTrips(min(floor, worst[d]), BACKOFF_CAP * worst[d],
                                          initial=worst[d])
                            for d in self.dests if worst.get(d)}

    def wait(self, item: Pending) -> float:
        """How long ``item`` waits for its acknowledgements after its last copy: the
        longest wait of the receivers still lacking it. A learned timer doubles (up to its
        ceiling) only with the copies sent while nothing is heard of those receivers: a
        receiver heard between two copies (an acknowledgement, or any frame of it) shows its
        route works, so the copy was lost, not delayed, and the next waits one round trip
        again (losses on a lossy route are independent; backing off from them only stalls
        the values queued behind)."""
        waits = [self.round_trips[d].wait(max(1, item.silent))
                 for d in item.waiting - item.held if d in self.round_trips]
        return max(waits, default=retry_wait(self.retry_s, item.attempts))

    def offer(self, payload: int, now: float, key: str | None = None,
              ref: str | None = None) -> list[Delivery]:
        """A new value to deliver; reports it queued (or what the full queue did)."""
        reports: list[Delivery] = []
        if len(self.queue) + len(self.flight) >= self.channel.queue:
            if self.channel.overflow != "drop_oldest" or not self.queue:
                return self.refuse(now, key, ref, f"queue full ({self.channel.queue} values)")
            reports += self._fail(self.queue.popleft(), now, "queue overflow: dropped for a "
                                  "newer value")
        item = Pending(self.ids.take(), payload, now, key, ref, set(self.dests))
        self.changed = True
        self.queue.append(item)
        reports += self._report(item, "queued", now)
        self._fill()
        return reports

    def refuse(self, now: float, key: str | None, ref: str | None, reason: str
               ) -> list[Delivery]:
        """A new value not taken: reported ``failed`` with ``reason`` (it uses up an id)."""
        item_id, self.changed = self.ids.take_refused()
        return [Delivery(now, self.channel.name, item_id, dst, "failed", reason=reason,
                         attempts=0, key=key, ref=ref) for dst in sorted(self.dests)]

    def _fill(self) -> None:
        while self.queue and len(self.flight) < WINDOW:
            item = self.queue.popleft()
            item.seq = self._next_seq
            self._next_seq = (self._next_seq + 1) % SEQ_MOD
            self.flight.append(item)

    def due(self, now: float) -> list[Pending]:
        """Values to put in a frame sent at ``now``, oldest first."""
        return [p for p in self.flight
                if p.next_send <= now + 1e-9 and not p.waiting <= p.held]

    def next_time(self) -> float | None:
        """When a value is next due, or None."""
        times = [p.next_send for p in self.flight if not p.waiting <= p.held]
        return min(times, default=None)

    def entry(self, item: Pending) -> int:
        """The entry bits of ``item``: seq, lag, value."""
        assert item.seq is not None and self.flight
        lag = (item.seq - self.flight[0].seq) % SEQ_MOD  # type: ignore[operator]
        return (((item.seq << LAG_BITS) | lag) << self.channel.bits) | item.payload

    def sent(self, items: Iterable[Pending], now: float) -> list[Delivery]:
        reports: list[Delivery] = []
        for item in items:
            before = item.last_sent
            item.attempts += 1
            lacking = item.waiting - item.held
            item.silent = 1 if before is None or any(
                max(self.heard.get(d, -math.inf), self._alive.get(d, -math.inf)) > before
                for d in lacking) else item.silent + 1
            item.last_sent = now
            if item.first_sent is None:
                item.first_sent = now
            item.next_send = now + self.wait(item)
            if item.attempts == 1:
                reports += self._report(item, "sent", now)
        return reports

    def confirmed(self, items: Iterable[Pending], dst: str) -> None:
        """The modem confirmed ``items`` reached ``dst``: wait for its ack, do not resend."""
        for item in items:
            if dst in item.waiting:
                item.held.add(dst)

    def on_ack(self, dst: str, base: int, bitmap: int, now: float) -> list[Delivery]:
        """A receiver's acknowledgement (of this run's epoch). Where it shows a gap (a value
        held whose first copy left after the last copy of one it lacks), that copy is lost
        (as SACK's loss detection decides): the value goes again at the next opportunity,
        not after its timer; a copy still on its way is not sent again."""
        reports: list[Delivery] = []
        self.heard[dst] = now
        arrived = -math.inf  # the latest first copy among the values it holds
        timed: list[float] = []  # round trips of values sent once, newly acknowledged
        for item in list(self.flight):
            if dst not in item.waiting:
                continue
            d = seq_after(item.seq, base)  # type: ignore[arg-type]
            held = d < 0 or (1 <= d <= WINDOW and bitmap >> (d - 1) & 1)
            if held and item.first_sent is not None:
                arrived = max(arrived, item.first_sent)
                if item.attempts == 1 and dst not in item.held:
                    timed.append(now - item.first_sent)
            if d < 0:
                item.waiting.discard(dst)
                item.held.discard(dst)
                reports.append(self._one(item, dst, "delivered", now))
                if not item.waiting:
                    self.flight.remove(item)
            elif held:
                item.held.add(dst)
        trips = self.round_trips.get(dst)
        if trips is not None and timed:  # (Karn: only what was sent once)
            timeout = trips.timeout
            trips.sample(min(timed))
            if trips.timeout > timeout:  # a longer wait for those still on their way
                for item in self.flight:
                    if item.last_sent is not None and dst in item.waiting - item.held:
                        item.next_send = max(item.next_send, item.last_sent + self.wait(item))
        for item in self.flight:
            if dst in item.waiting - item.held and item.last_sent is not None \
                    and item.last_sent < arrived:
                item.next_send = min(item.next_send, now)
        self._fill()
        return reports

    def resync(self, dst: str) -> None:
        """``dst`` started afresh (a new epoch): it holds nothing of ours; send again now."""
        for item in self.flight:
            if dst in item.waiting:
                item.held.discard(dst)
                item.next_send = float("-inf")

    def pending(self) -> int:
        """Values not yet finished (queued or in flight)."""
        return len(self.queue) + len(self.flight)

    def state(self) -> dict[str, Any]:
        """Everything a restart must resume: numbering and every unfinished value."""
        return {"next_id": self.ids.state(), "next_seq": self._next_seq,
                "queue": [_pending_state(p) for p in self.queue],
                "flight": [_pending_state(p) for p in self.flight]}

    def restore(self, state: dict[str, Any]) -> None:
        """Resume from :meth:`state` (values keep their ids, numbers and attempts)."""
        self.ids = Ids.restore(state["next_id"])
        self._next_seq = int(state["next_seq"]) % SEQ_MOD
        self.queue = deque(_pending_from(s) for s in state["queue"])
        self.flight = [_pending_from(s) for s in state["flight"]]
        for item in self.flight:  # the receivers may have moved on: ask again at once
            item.next_send = float("-inf")

    def expire(self, now: float) -> list[Delivery]:
        """Give up values past their TTL or out of retries."""
        reports: list[Delivery] = []
        ttl = self.ttl_s
        retries = self.channel.retries
        for item in [*self.flight, *self.queue]:
            if now - item.created > ttl:
                reports += self._give_up(item, now, f"older than ttl_s={ttl:g}")
            elif (retries is not None and item.attempts > retries
                  and item.next_send <= now and not item.waiting <= item.held):
                reports += self._give_up(item, now, f"no acknowledgement after "
                                         f"{item.attempts} attempts")
        return reports

    def _give_up(self, item: Pending, now: float, reason: str) -> list[Delivery]:
        if item in self.flight:
            self.flight.remove(item)
            for other in self.flight:  # receivers need a fresh lag to skip this one
                if other.held:
                    other.held.clear()
                    other.next_send = min(other.next_send, now)
        else:
            self.queue.remove(item)
        self._fill()
        return self._fail(item, now, reason)

    def _fail(self, item: Pending, now: float, reason: str) -> list[Delivery]:
        return [self._one(item, dst, "failed", now, reason) for dst in sorted(item.waiting)]

    def _report(self, item: Pending, state: str, now: float) -> list[Delivery]:
        return [self._one(item, dst, state, now) for dst in sorted(item.waiting)]

    def _one(self, item: Pending, dst: str, state: str, now: float,
             reason: str | None = None) -> Delivery:
        return Delivery(now, self.channel.name, item.id, dst, state, reason=reason,
                        attempts=item.attempts, key=item.key, ref=item.ref)


def _pending_state(item: Pending) -> dict[str, Any]:
    return {"id": item.id, "payload": int_to_state(item.payload), "created": item.created,
            "key": item.key, "ref": item.ref, "waiting": sorted(item.waiting), "seq": item.seq,
            "attempts": item.attempts, "last_sent": item.last_sent, "held": sorted(item.held),
            "first_sent": item.first_sent}


def _pending_from(state: dict[str, Any]) -> Pending:
    return Pending(int(state["id"]), int_from_state(state["payload"]), float(state["created"]),
                   state["key"], state["ref"], set(state["waiting"]), state["seq"],
                   int(state["attempts"]), state["last_sent"], float("-inf"),
                   set(state["held"]), state.get("first_sent", state["last_sent"]),
                   int(state["attempts"]))


class ReliableReceiver:
    """The receiving side of one reliable channel from one sender."""

    def __init__(self) -> None:
        self.expected: int | None = None
        self.buffer: dict[int, Any] = {}
        self.duplicates = 0
        self.skipped = 0

    def on_entry(self, seq: int, lag: int, values: Any) -> list[Any]:
        """An entry arrived; returns the values now deliverable, in order."""
        oldest = (seq - lag) % SEQ_MOD
        if self.expected is None:
            self.expected = oldest
        elif seq_after(oldest, self.expected) > 0:  # the sender gave up what lies between
            for s in list(self.buffer):
                if seq_after(s, oldest) < 0:
                    del self.buffer[s]
            self.skipped += seq_after(oldest, self.expected)
            self.expected = oldest
        d = seq_after(seq, self.expected)
        if d < 0 or d > WINDOW or seq in self.buffer:
            self.duplicates += 1
        else:
            self.buffer[seq] = values
        out = []
        while self.expected in self.buffer:
            out.append(self.buffer.pop(self.expected))
            self.expected = (self.expected + 1) % SEQ_MOD
        return out

    def state(self) -> dict[str, Any]:
        """The delivered window: what a restarted receiver must not publish again."""
        return {"expected": self.expected, "buffer": [[s, v] for s, v in self.buffer.items()]}

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> ReliableReceiver:
        receiver = cls()
        receiver.expected = state["expected"]
        receiver.buffer = {int(s): v for s, v in state["buffer"]}
        return receiver

    def ack(self) -> tuple[int, int]:
        """``(base, bitmap)`` for the acknowledgement entry."""
        base = self.expected or 0
        bitmap = 0
        for i in range(WINDOW):
            if (base + 1 + i) % SEQ_MOD in self.buffer:
                bitmap |= 1 << i
        return base, bitmap
