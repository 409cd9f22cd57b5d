"""Values too big for a frame: fragmented transfers with selective retransmission (pure).

A channel whose value does not fit a frame sends it as a *transfer*: the packed value's bytes,
trailing zero bytes trimmed, cut into ``chunk_bytes`` fragments that share frames with other
channels. Each fragment carries the transfer id (modulo 16), its index and the fragment count.
A new transfer skips the id each receiver last acknowledged (a receiver takes fragments of the
id it holds for that transfer's), and a receiver given other bytes at a place it holds under
that id starts afresh.

Receivers acknowledge in the frames they send anyway with ``base`` (first fragment missing, or
the count when complete) and a bitmap of the ``WINDOW`` fragments after it that they hold (seed
002's requested trunks: what is missing is exactly what gets sent again). The sender keeps at
most ``WINDOW + 1`` fragments past the lowest ``base`` in flight, re-sends a fragment after
``retry_s`` (doubling up to four times that), and fails a transfer after ``retries``
retransmissions of one fragment or once older than ``ttl_s``.

Latest-wins channels cancel an unfinished transfer when a newer value arrives; reliable ones
queue values (bounded) and send them one transfer after another.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from bridge.core.events import Delivery
from bridge.core.ids import Ids
from bridge.core.reliable import BACKOFF_CAP, retry_wait, stream_ttl_s
from bridge.core.round_trips import RoundTrips
from bridge.wire.channels import TID_BITS, WINDOW, ChannelCodec

TID_MOD = 1 << TID_BITS


def to_bytes(channel: ChannelCodec, payload: int) -> bytes:
    """A packed value as the bytes a transfer carries (trailing zero bytes trimmed)."""
    data = payload.to_bytes(channel.value_bytes, "big").rstrip(b"\0")
    return data or b"\0"


def from_bytes(channel: ChannelCodec, data: bytes) -> int:
    """The packed value back from a transfer's bytes (zero-padded to the full size)."""
    data = data[:channel.value_bytes].ljust(channel.value_bytes, b"\0")
    return int.from_bytes(data, "big")


def transfer_ttl_s(channel: ChannelCodec, retry_s: float) -> float:
    """The default ``ttl_s`` of a fragmented channel: a stream's for each fragment of the
    largest value, the most its retry limit lets a transfer take."""
    fragments = -(-channel.value_bytes // channel.chunk_bytes)
    return fragments * stream_ttl_s(retry_s, channel.retries)


@dataclass(eq=False)
class Transfer:
    """One value on its way, at the sender; ``tid`` is its id on the wire."""

    id: int
    tid: int
    data: bytes
    created: float
    key: str | None
    ref: str | None
    chunk_bytes: int
    dests: tuple[str, ...]
    base: dict[str, int] = field(default_factory=dict)  # per receiver: first fragment missing
    held: dict[str, set[int]] = field(default_factory=dict)  # per receiver, past base
    attempts: dict[int, int] = field(default_factory=dict)
    next_send: dict[int, float] = field(default_factory=dict)
    first_sent: dict[int, float] = field(default_factory=dict)  # when each went out first
    last_sent: dict[int, float] = field(default_factory=dict)  # and last
    started: bool = False

    @property
    def count(self) -> int:
        return -(-len(self.data) // self.chunk_bytes)

    def chunk(self, index: int) -> bytes:
        piece = self.data[index * self.chunk_bytes:(index + 1) * self.chunk_bytes]
        return piece.ljust(self.chunk_bytes, b"\0")

    def done_by(self, dst: str) -> int:
        return self.base.get(dst, 0)

    def complete(self) -> bool:
        return all(self.done_by(d) >= self.count for d in self.dests)

    def lacks(self, dst: str, index: int) -> bool:
        """Receiver ``dst`` does not hold fragment ``index`` yet."""
        return index >= self.done_by(dst) and index not in self.held.get(dst, ())

    def needed(self, index: int) -> bool:
        """Some receiver still lacks fragment ``index``."""
        return any(self.lacks(d, index) for d in self.dests)


class TransferSender:
    """The sending side of one fragmented channel at one node."""

    def __init__(self, channel: ChannelCodec, dests: Iterable[str], retry_s: float,
                 first_seq: int = 0) -> None:
        """``first_seq``: this run's first transfer id on the wire (random at runtime, so a
        restarted sender's first transfer is rarely taken for the one receivers completed last)."""
        self.channel = channel
        self.dests = tuple(dests)
        self.retry_s = channel.retry_s or retry_s
        self.ttl_s = channel.ttl_s or transfer_ttl_s(channel, self.retry_s)
        self.round_trips: dict[str, RoundTrips] = {}
        """Per receiver behind a relay: its round trips (:meth:`behind_relays`)."""
        self.current: Transfer | None = None
        self.queue: deque[Transfer] = deque()
        self.ids = Ids()
        self.changed = False
        """Whether the last :meth:`offer` or :meth:`refuse` changed what a restart must resume
        (a refusal does only when its id starts a new block: :mod:`bridge.core.ids`)."""
        self._tid_offset = first_seq % TID_MOD
        self.holds: dict[str, int] = {}
        """Per receiver: the transfer id its last acknowledgement named (the transfer it
        holds, finished or not): a new transfer does not take it (:meth:`offer_bytes`)."""

    def offer(self, payload: int, now: float, key: str | None = None,
              ref: str | None = None) -> list[Delivery]:
        """A new value: queued (reliable) or replacing an unfinished transfer (latest wins)."""
        return self.offer_bytes(to_bytes(self.channel, payload), now, key, ref)

    def offer_bytes(self, data: bytes, now: float, key: str | None = None,
                    ref: str | None = None) -> list[Delivery]:
        """:meth:`offer` of bytes as they are (an image stream's)."""
        reports: list[Delivery] = []
        if self.channel.reliable and \
                len(self.queue) + (self.current is not None) >= self.channel.queue:
            return self.refuse(now, key, ref, f"queue full ({self.channel.queue} values)")
        tid = self._fresh_tid()
        item = Transfer(self.ids.take(), tid, data, now, key, ref, self.channel.chunk_bytes,
                        self.dests)
        self.changed = True
        if not self.channel.reliable:
            for old in [*([self.current] if self.current else []), *self.queue]:
                reports += self._report(old, "failed", now, "cancelled by a newer value")
            self.current, self.queue = None, deque()
        self.queue.append(item)
        reports += self._report(item, "queued", now)
        self._start(now)
        return reports

    def _fresh_tid(self) -> int:
        """The next transfer id on the wire, past any a receiver holds: ids wrap at 16, and
        a receiver given the id of the transfer it finished takes the new one's fragments for
        that one's (duplicates, ignored) and acknowledges it whole. Where every id is held
        (more receivers than ids), the next one as numbered."""
        held = {tid for dst, tid in self.holds.items() if dst in self.dests}
        for _ in range(TID_MOD):
            tid = (self.ids.next + self._tid_offset) % TID_MOD
            if tid not in held:
                return tid
            self._tid_offset = (self._tid_offset + 1) % TID_MOD
        return (self.ids.next + self._tid_offset) % TID_MOD

    def refuse(self, now: float, key: str | None, ref: str | None, reason: str
               ) -> list[Delivery]:
        """A new value not taken: reported ``failed`` with ``reason`` (it uses up an id)."""
        item_id, self.changed = self.ids.take_refused()
        return [Delivery(now, self.channel.name, item_id, dst, "failed", reason=reason,
                         attempts=0, key=key, ref=ref) for dst in self.dests]

    def _start(self, now: float) -> None:
        if self.current is None and self.queue:
            self.current = self.queue.popleft()

    def _window(self, item: Transfer) -> range:
        low = min(item.done_by(d) for d in item.dests)
        return range(low, min(item.count, low + WINDOW + 1))

    def due(self, now: float) -> list[int]:
        """Fragment indices to put in a frame sent at ``now``, lowest first."""
        item = self.current
        if item is None:
            return []
        return [i for i in self._window(item)
                if item.needed(i) and item.next_send.get(i, float("-inf")) <= now + 1e-9]

    def next_time(self) -> float | None:
        item = self.current
        if item is None:
            return None
        times = [item.next_send.get(i, float("-inf")) for i in self._window(item)
                 if item.needed(i)]
        return min(times, default=None)

    def entry(self, index: int) -> int:
        """The entry bits of fragment ``index`` of the current transfer."""
        item = self.current
        assert item is not None
        fbits = self.channel.fragment_bits
        header = (((item.tid << fbits) | index) << fbits) | item.count
        return (header << (8 * self.channel.chunk_bytes)) | int.from_bytes(item.chunk(index),
                                                                           "big")

    def sent(self, indices: Iterable[int], now: float) -> list[Delivery]:
        item = self.current
        assert item is not None
        reports: list[Delivery] = []
        for i in indices:
            n = item.attempts[i] = item.attempts.get(i, 0) + 1
            item.next_send[i] = now + self._wait(item, i, n)
            item.first_sent.setdefault(i, now)
            item.last_sent[i] = now
        if not item.started:
            item.started = True
            reports += self._report(item, "sent", now)
        return reports

    def confirmed(self, indices: Iterable[int], dst: str) -> None:
        """The modem confirmed fragments ``indices`` reached ``dst``: do not resend them."""
        if self.current is not None and dst in self.current.dests:
            self.current.held.setdefault(dst, set()).update(indices)

    def on_ack(self, dst: str, tid: int, base: int, bitmap: int, now: float) -> list[Delivery]:
        self.holds[dst] = tid  # (whatever it acknowledges: what it holds)
        item = self.current
        if item is None or tid != item.tid or dst not in item.dests:
            return []
        reports: list[Delivery] = []
        was, had = item.done_by(dst), item.held.get(dst, set())
        if base > was:
            item.base[dst] = min(base, item.count)
        item.held[dst] = {item.done_by(dst) + 1 + i for i in range(WINDOW) if bitmap >> i & 1}
        if dst in self.round_trips:
            self._timed(item, dst, {*range(was, item.done_by(dst)), *item.held[dst]} - had,
                        now)
        if was < item.count <= item.done_by(dst):
            reports.append(self._one(item, dst, "delivered", now))
        if item.complete():
            self.current = None
            self._start(now)
        return reports

    def behind_relays(self, dests: Iterable[str]) -> None:
        """Receivers reached through relays: the wait before sending a fragment again
        learns from their acknowledgements (:mod:`bridge.core.round_trips`: what a relay's
        queue adds is not known before the dive). A neighbour's stays ``retry_s``: its MAC
        bounds the round trip."""
        self.round_trips = {d: RoundTrips(self.retry_s, BACKOFF_CAP * self.retry_s)
                            for d in dests if d in self.dests}

    def _wait(self, item: Transfer, index: int, attempts: int) -> float:
        """How long fragment ``index`` waits after its ``attempts``-th copy: the longest
        wait of the receivers behind relays that lack it, else ``retry_s``'s."""
        return max((trips.wait(attempts) for dst, trips in self.round_trips.items()
                    if dst in item.dests and item.lacks(dst, index)),
                   default=retry_wait(self.retry_s, attempts))

    def _timed(self, item: Transfer, dst: str, acknowledged: set[int], now: float) -> None:
        """Fragments newly ``acknowledged`` by ``dst``: the round trip of the last one sent,
        where it was sent once (Karn), and the timers of those in flight moved out to a
        longer wait."""
        once = [item.first_sent[i] for i in acknowledged
                if item.attempts.get(i) == 1 and i in item.first_sent]
        if not once:
            return
        trips = self.round_trips[dst]
        timeout = trips.timeout
        trips.sample(now - max(once))
        if trips.timeout > timeout:
            for i, last in item.last_sent.items():
                if i in item.next_send and item.lacks(dst, i):
                    item.next_send[i] = max(item.next_send[i],
                                            last + self._wait(item, i, item.attempts[i]))

    def resync(self, dst: str) -> None:
        """``dst`` started afresh (a new epoch): it holds nothing; send it every fragment."""
        item = self.current
        if item is not None and dst in item.dests:
            item.base.pop(dst, None)
            item.held.pop(dst, None)
            item.next_send.clear()

    def pending(self) -> int:
        """Values not yet finished (queued or being sent)."""
        return len(self.queue) + (self.current is not None)

    def state(self) -> dict[str, Any]:
        """Everything a restart must resume: numbering and every unfinished transfer."""
        items = [*([self.current] if self.current else []), *self.queue]
        return {"next_id": self.ids.state(), "tid_offset": self._tid_offset,
                "holds": dict(self.holds), "items": [_transfer_state(i) for i in items]}

    def restore(self, state: dict[str, Any]) -> None:
        """Resume from :meth:`state`: the transfer under way starts its fragments again."""
        self.ids = Ids.restore(state["next_id"])
        self._tid_offset = int(state["tid_offset"])
        self.holds = {str(d): int(t) for d, t in (state.get("holds") or {}).items()}
        items = [_transfer_from(s, self.channel.chunk_bytes) for s in state["items"]]
        self.current, self.queue = None, deque(items)
        self._start(0.0)

    def progress(self) -> dict[str, Any] | None:
        """The current transfer's progress, for ``…/transfer/<channel>``."""
        item = self.current
        if item is None:
            return None
        done = min(item.done_by(d) for d in item.dests)
        return {"channel": self.channel.name, "id": item.id, "peer": list(item.dests),
                "fragments_done": done, "fragments_total": item.count,
                "bytes": len(item.data), "state": "sending"}

    def expire(self, now: float) -> list[Delivery]:
        item = self.current
        if item is None:
            return []
        ttl, retries = self.ttl_s, self.channel.retries
        reason = None
        if now - item.created > ttl:
            reason = f"older than ttl_s={ttl:g}"
        elif retries is not None and any(
                n > retries and item.needed(i) and item.next_send.get(i, float("-inf")) <= now
                for i, n in item.attempts.items()):
            reason = f"a fragment was not acknowledged after {retries + 1} attempts"
        if reason is None:
            return []
        self.current = None
        self._start(now)
        return [self._one(item, d, "failed", now, reason) for d in item.dests
                if item.done_by(d) < item.count]

    def _report(self, item: Transfer, state: str, now: float,
                reason: str | None = None) -> list[Delivery]:
        return [self._one(item, d, state, now, reason) for d in item.dests]

    def _one(self, item: Transfer, dst: str, state: str, now: float,
             reason: str | None = None) -> Delivery:
        attempts = max(item.attempts.values(), default=0)
        return Delivery(now, self.channel.name, item.id, dst, state, reason=reason,
                        attempts=attempts, key=item.key, ref=item.ref)


def _transfer_state(item: Transfer) -> dict[str, Any]:
    return {"id": item.id, "tid": item.tid, "data": item.data, "created": item.created,
            "key": item.key, "ref": item.ref, "dests": list(item.dests), "base": item.base,
            "attempts": max(item.attempts.values(), default=0), "started": item.started}


def _transfer_from(state: dict[str, Any], chunk_bytes: int) -> Transfer:
    item = Transfer(int(state["id"]), int(state["tid"]), bytes(state["data"]),
                    float(state["created"]), state["key"], state["ref"], chunk_bytes,
                    tuple(state["dests"]), {k: int(v) for k, v in state["base"].items()})
    item.started = bool(state["started"])
    if state["attempts"]:  # keep the retry budget spent: restarts do not reset it
        item.attempts = dict.fromkeys(range(item.count), int(state["attempts"]))
    return item


class TransferReceiver:
    """The receiving side of one fragmented channel from one sender."""

    def __init__(self, channel: ChannelCodec) -> None:
        self.channel = channel
        self.tid: int | None = None
        self.count = 0
        self.chunks: dict[int, bytes] = {}
        self.complete = False
        self.cancelled = 0
        self.duplicates = 0
        self.whole: bytes | None = None
        """The transfer completed last, while it is the one held (not saved: a restarted
        receiver takes a fragment of its id and count for a copy, as ever)."""

    def on_fragment(self, tid: int, index: int, count: int, chunk: bytes) -> bytes | None:
        """A fragment arrived; returns the transfer's bytes when it just completed. A
        fragment of the id held whose bytes differ from those held at its place is another
        transfer's (ids wrap at 16): that one starts afresh."""
        held = self.chunks.get(index)
        if self.complete and self.whole is not None:
            size = len(chunk)
            held = self.whole[index * size:(index + 1) * size]
        other = held is not None and held != chunk
        if tid != self.tid or count != self.count or other:
            if self.tid is not None and not self.complete and self.chunks:
                self.cancelled += 1
            self.tid, self.count, self.chunks, self.complete = tid, count, {}, False
            self.whole = None
        if self.complete or index in self.chunks:
            self.duplicates += 1
            return None
        self.chunks[index] = chunk
        if len(self.chunks) < self.count:
            return None
        self.complete = True
        data = self.whole = b"".join(self.chunks[i] for i in range(self.count))
        self.chunks = {}
        return data

    def state(self) -> dict[str, Any]:
        """What a restarted receiver needs: the transfer under way and whether it completed
        (a completed one is never published twice)."""
        return {"tid": self.tid, "count": self.count, "complete": self.complete,
                "chunks": [[i, c] for i, c in self.chunks.items()]}

    @classmethod
    def from_state(cls, channel: ChannelCodec, state: dict[str, Any]) -> TransferReceiver:
        receiver = cls(channel)
        receiver.tid, receiver.count = state["tid"], int(state["count"])
        receiver.complete = bool(state["complete"])
        receiver.chunks = {int(i): bytes(c) for i, c in state["chunks"]}
        return receiver

    def prefix(self) -> bytes:
        """The fragments held from the first on, without a gap (a progressive stream's
        decodable part)."""
        if self.complete:
            return b""  # handed out whole already
        return b"".join(self.chunks[i] for i in range(self.base))

    @property
    def base(self) -> int:
        if self.complete:
            return self.count
        return next(i for i in range(self.count + 1) if i not in self.chunks)

    def ack(self) -> tuple[int, int, int]:
        """``(tid, base, bitmap)`` for the acknowledgement entry."""
        base = self.base
        bitmap = 0
        for i in range(WINDOW):
            if base + 1 + i in self.chunks:
                bitmap |= 1 << i
        return self.tid or 0, base, bitmap

    def progress(self) -> dict[str, Any]:
        return {"channel": self.channel.name, "id": self.tid,
                "fragments_done": self.count if self.complete else len(self.chunks),
                "fragments_total": self.count,
                "state": "complete" if self.complete else "receiving"}
