"""The simulated ocean: a pure, event-driven model of a shared acoustic channel.

No asyncio, no sockets, no clock: the caller passes ``now`` (float seconds, never decreasing) to
:meth:`Ocean.transmit` and :meth:`Ocean.advance`, and sleeps until :meth:`Ocean.next_event_time`
(or jumps there with a fake clock, faster than real time). Given the same seed and the same calls
the outcome is the same.

What it models, per frame:

- the sender's intrinsic delay: ``max(0, gauss(intrinsic_delay_s, jitter_s))`` between the
  :meth:`~Ocean.transmit` call and the moment the signal enters the water; the sender is busy
  (cannot transmit, cannot receive) from the call until the signal ends;
- airtime from the preset (:meth:`Preset.airtime`);
- propagation ``distance / sound_speed`` from 3-D positions ``(x, y, depth)`` in metres, taken at
  the moment of transmission; distances under ``min_range_m`` count as ``min_range_m``; a node
  is where it was put (:meth:`~Ocean.set_position`; told the time, it moves on at the velocity
  of its last two positions for up to :data:`GLIDE_S`, as a vehicle whose navigation reports it
  now and then keeps going between reports) or where its scripted
  :class:`~bridge.mission.path.Path` has taken it (:meth:`~Ocean.set_path`);
- a broadcast medium: every other node hears every frame (promiscuous); ``dest`` is metadata only;
- a reception is decided when it ends, in this order of reasons:
  ``out_of_range`` (beyond ``max_range_m``: never delivered, and it does not interfere),
  ``half_duplex`` (the receiver was busy transmitting during any part of it),
  ``collision`` (another audible frame overlapped it at that receiver: both are lost),
  ``range_loss`` (probability from ``loss_curve(distance, max_range)``, ~0 near, rising at range),
  ``loss`` (uniform extra loss probability), ``bit_errors`` (``1 - (1 - ber) ** (8 * n_bytes)``).

What it does NOT model: multipath and reverberation, Doppler, noise, SNR per frequency band,
capture effect (the stronger of two colliding frames surviving), partial corruption (a frame is
delivered whole or lost whole), movement during a frame, sound-speed profiles and ray bending,
modem buffers filling up, and the modem's own acknowledgements. Intervals that merely touch do
not overlap.
"""

from __future__ import annotations

import heapq
import math
import random
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from bridge.frozen import direct_init
from bridge.mission.path import Path
from bridge.mission.presets import Preset

__all__ = [
    "LOSS_REASONS",
    "Delivery",
    "Event",
    "LinkStats",
    "Loss",
    "LossCurve",
    "Ocean",
    "Position",
    "TransmitRefused",
    "TxDone",
]

Position = tuple[float, float, float]
"""``(x, y, depth)`` in metres."""

GLIDE_S = 5.0
"""How long a node put somewhere with the time moves on at its last velocity (and how far
apart its last two positions may be for that velocity to count)."""

PRUNE_SLACK_S = 1e-6
"""Pruning keeps intervals this much longer, so float rounding of a reception's start and end
never forgets one that still touches an undecided reception."""

LOSS_REASONS = (
    "out_of_range",
    "half_duplex",
    "collision",
    "range_loss",
    "loss",
    "bit_errors",
)


@dataclass(frozen=True)
class LossCurve:
    """Loss probability against distance: ``edge_loss * (distance / max_range) ** exponent``.

    With the defaults the loss is under 1 % up to half the range and 20 % at the edge.
    """

    edge_loss: float = 0.2
    exponent: float = 6.0

    def __call__(self, distance_m: float, max_range_m: float) -> float:
        if max_range_m <= 0:
            return 0.0
        share = float(self.edge_loss * (distance_m / max_range_m) ** self.exponent)
        return 1.0 if share > 1.0 else share if share > 0.0 else 0.0


NO_RANGE_LOSS = LossCurve(edge_loss=0.0)


class TransmitRefused(ValueError):
    """The ocean refused a transmission; ``reason`` is ``busy``, ``too_long``, ``empty`` or
    ``unknown_node``."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


@direct_init
@dataclass(frozen=True)
class TxDone:
    """The transmission ``frame_id`` of ``src`` has left the modem: it may transmit again."""

    src: int
    time: float
    frame_id: int


@direct_init
@dataclass(frozen=True)
class Delivery:
    """Node ``dst`` received ``data`` from ``src``; ``end`` is when the reception ended.

    ``meta`` holds ``dest``, ``frame_id``, ``sent_at``, ``tx_start``, ``airtime_s``,
    ``travel_time_s`` and ``distance_m``.
    """

    dst: int
    src: int
    data: bytes
    start: float
    end: float
    meta: dict[str, Any]  # (made for this delivery: its receiver may add to it)

    @property
    def time(self) -> float:
        return self.end


@direct_init
@dataclass(frozen=True)
class Loss:
    """The frame ``frame_id`` from ``src`` was not received by ``dst`` (see ``LOSS_REASONS``);
    ``dest`` is the frame's destination metadata, as a :class:`Delivery` would have had it."""

    dst: int
    src: int
    reason: str
    time: float
    frame_id: int
    dest: int | None = None


Event = TxDone | Delivery | Loss


@dataclass
class LinkStats:
    """Counters of one directed link ``src -> dst``."""

    sent: int = 0
    delivered: int = 0
    lost: dict[str, int] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return {"sent": self.sent, "delivered": self.delivered, "lost": dict(self.lost)}


@dataclass(slots=True)
class _Rx:
    frame_id: int
    src: int
    dst: int
    data: bytes
    dest: int | None
    sent_at: float
    tx_start: float
    start: float
    end: float
    distance_m: float
    travel_s: float
    audible: bool
    link: LinkStats


class Ocean:
    """A shared acoustic channel between addressed nodes (see the module docstring).

    ``loss`` is an extra uniform frame-loss probability; ``loss_curve`` maps
    ``(distance_m, max_range_m)`` to a loss probability (default :class:`LossCurve`).
    """

    def __init__(
        self,
        preset: Preset,
        seed: int | None = 0,
        positions: Mapping[int, Position] | None = None,
        *,
        loss: float = 0.0,
        loss_curve: Callable[[float, float], float] | None = None,
    ) -> None:
        if not 0.0 <= loss <= 1.0:
            raise ValueError("loss must be in [0, 1]")
        self.preset = preset
        self.loss = loss
        self.loss_curve: Callable[[float, float], float] = (
            loss_curve if loss_curve is not None else LossCurve()
        )
        self._rng = random.Random(seed)
        self._now = -math.inf
        self._positions: dict[int, Position] = {}
        self._paths: dict[int, tuple[Path, float]] = {}  # addr -> (path, start time)
        # addr -> (time, position, velocity): put there then, moving on (:meth:`set_position`)
        self._glides: dict[int, tuple[float, Position, Position]] = {}
        self._busy_until: dict[int, float] = {}
        self._tx_intervals: dict[int, list[tuple[float, float]]] = {}
        self._rx_intervals: dict[int, list[_Rx]] = {}
        self._queue: list[tuple[float, int, TxDone | _Rx]] = []
        # the end of the reception being decided (:meth:`_prune`'s horizon counts back from it)
        self._deciding = math.inf
        # the longest a reception lasts (the airtime of a whole frame), and a little more
        self._longest_s = preset.airtime(preset.frame_bytes) + PRUNE_SLACK_S
        self._seq = 0
        self._next_frame = 1
        self._links: dict[tuple[int, int], LinkStats] = {}
        self._tx_count: dict[int, int] = {}
        self._refused: dict[int, int] = {}
        for addr, pos in (positions or {}).items():
            self.add_node(addr, pos)

    # -- nodes ---------------------------------------------------------------------------------

    @property
    def nodes(self) -> dict[int, Position]:
        """Current positions by address (a copy)."""
        return {addr: self.position(addr) for addr in self._positions}

    def position(self, addr: int, t: float | None = None) -> Position:
        """Where ``addr`` is at time ``t`` (default: now), following its path if it has one."""
        if addr not in self._positions:
            raise KeyError(f"unknown node {addr}")
        scripted = self._paths.get(addr)
        if scripted is None:
            glide = self._glides.get(addr)
            if glide is None:
                return self._positions[addr]
            since, (x, y, z), (vx, vy, vz) = glide
            dt = min(max((self._now if t is None else t) - since, 0.0), GLIDE_S)
            return (x + vx * dt, y + vy * dt, z + vz * dt)
        path, start = scripted
        elapsed = (self._now if t is None else t) - start
        return path.position_at(elapsed if math.isfinite(elapsed) else 0.0)

    def add_node(self, addr: int, position: Position = (0.0, 0.0, 0.0)) -> None:
        """Put a modem in the water (or move it, if it is already there, ending its path)."""
        self._positions[addr] = _position(position)
        self._paths.pop(addr, None)
        self._glides.pop(addr, None)
        self._busy_until.setdefault(addr, -math.inf)
        self._tx_intervals.setdefault(addr, [])
        self._rx_intervals.setdefault(addr, [])

    def set_position(self, addr: int, position: Position, now: float | None = None) -> None:
        """Move a node (and end its path); frames already in the water keep their distance.
        With ``now`` (this ocean's clock) the node moves on from there at the velocity since
        the position it was last put at, if that came within :data:`GLIDE_S`, for up to
        :data:`GLIDE_S` (a vehicle's navigation samples its motion, the vehicle keeps going)."""
        if addr not in self._positions:
            raise KeyError(f"unknown node {addr}")
        here = _position(position)
        before = self._glides.pop(addr, None)
        self._positions[addr] = here
        self._paths.pop(addr, None)
        if now is None:
            return
        velocity = (0.0, 0.0, 0.0)
        if before is not None and 0.0 < now - before[0] <= GLIDE_S:
            dt = now - before[0]
            (x, y, z), (x0, y0, z0) = here, before[1]
            velocity = ((x - x0) / dt, (y - y0) / dt, (z - z0) / dt)
        self._glides[addr] = (now, here, velocity)

    def set_path(self, addr: int, path: Path, start: float) -> None:
        """Move ``addr`` along ``path`` from time ``start`` on (it waits at the first waypoint
        until then); each frame takes the positions of the moment it is transmitted."""
        if addr not in self._positions:
            raise KeyError(f"unknown node {addr}")
        if not math.isfinite(start):
            raise ValueError(f"path start must be a finite time, not {start}")
        self._paths[addr] = (path, float(start))
        self._glides.pop(addr, None)
        self._positions[addr] = path.waypoints[0]

    def remove_node(self, addr: int) -> None:
        """Take a modem out: later frames are not heard by it (frames in flight still end)."""
        self._positions.pop(addr, None)
        self._paths.pop(addr, None)
        self._glides.pop(addr, None)

    def distance(self, a: int, b: int) -> float:
        """Straight-line distance between two nodes in metres, now."""
        return math.dist(self.position(a), self.position(b))

    @property
    def last_frame_id(self) -> int:
        """Id of the frame most recently accepted by :meth:`transmit` (0 before any)."""
        return self._next_frame - 1

    def busy_until(self, addr: int) -> float:
        """Time at which ``addr`` may transmit again."""
        return self._busy_until.get(addr, -math.inf)

    # -- time ----------------------------------------------------------------------------------

    @property
    def now(self) -> float:
        """The latest time passed to :meth:`transmit` or :meth:`advance` (``-inf`` before)."""
        return self._now

    def _set_now(self, now: float) -> None:
        if now < self._now:
            raise ValueError(f"time went backwards: {now} < {self._now}")
        self._now = now

    def next_event_time(self) -> float | None:
        """When :meth:`advance` next has something to report, or ``None`` if the water is quiet."""
        return self._queue[0][0] if self._queue else None

    def transmit(self, now: float, src: int, data: bytes, dest: int | None = None) -> float:
        """Start sending ``data`` from ``src``; returns the time the transmission ends.

        Raises :class:`TransmitRefused` if ``src`` is unknown or still busy with an earlier frame
        (like a modem answering BUSY: nothing is queued), or if ``data`` is empty or longer than
        the preset's ``frame_bytes``.
        """
        self._set_now(now)
        if src not in self._positions:
            raise TransmitRefused("unknown_node", f"node {src} is not in the water")
        if not data:
            raise TransmitRefused("empty", "cannot transmit an empty frame")
        if len(data) > self.preset.frame_bytes:
            raise TransmitRefused(
                "too_long",
                f"frame of {len(data)} B exceeds {self.preset.frame_bytes} B ({self.preset.name})",
            )
        if now < self._busy_until[src]:
            self._refused[src] = self._refused.get(src, 0) + 1
            raise TransmitRefused(
                "busy", f"node {src} is transmitting until t={self._busy_until[src]:.3f}"
            )
        p = self.preset
        delay = p.intrinsic_delay_s
        if p.jitter_s > 0:
            delay = max(0.0, self._rng.gauss(p.intrinsic_delay_s, p.jitter_s))
        frame_id = self._next_frame
        self._next_frame += 1
        tx_start = now + delay
        airtime = p.airtime(len(data))
        tx_end = tx_start + airtime
        self._busy_until[src] = tx_end
        self._prune(src)
        self._tx_intervals[src].append((now, tx_end))
        self._tx_count[src] = self._tx_count.get(src, 0) + 1
        data = bytes(data)
        here = self.position(src)
        min_range, max_range, sound_speed = p.min_range_m, p.max_range_m, p.sound_speed_mps
        queue, seq = self._queue, self._seq
        positions, links, filed = self._positions, self._links, self._rx_intervals
        moving = self._paths.keys() | self._glides.keys() if self._glides else self._paths
        for dst in sorted(positions):
            if dst == src:
                continue
            there = positions[dst] if dst not in moving else self.position(dst)
            dist = math.dist(here, there)
            travel = max(dist, min_range) / sound_speed  # (p.propagation_s, inlined)
            link = links.get((src, dst)) or self._link(src, dst)
            start = tx_start + travel
            rx = _Rx(frame_id, src, dst, data, dest, now, tx_start, start, tx_end + travel,
                     dist, travel, dist <= max_range, link)
            link.sent += 1
            seq += 1
            heapq.heappush(queue, (rx.end, seq, rx))
            if rx.audible:
                filed.setdefault(dst, []).append(rx)
        self._seq = seq
        self._push(tx_end, TxDone(src=src, time=tx_end, frame_id=frame_id))
        return tx_end

    def advance(self, now: float) -> list[Event]:
        """Settle everything that has happened up to ``now``; events come in time order."""
        self._set_now(now)
        events: list[Event] = []
        queue = self._queue
        while queue and queue[0][0] <= now:
            item = heapq.heappop(queue)[2]
            events.append(item if item.__class__ is TxDone else self._decide(item))  # type: ignore[arg-type]
        return events

    # -- statistics ----------------------------------------------------------------------------

    def link_stats(self, src: int, dst: int) -> LinkStats:
        """Counters of the link ``src -> dst`` (zeros if nothing was sent)."""
        return self._links.get((src, dst), LinkStats())

    def stats(self) -> dict[str, Any]:
        """All counters as a JSON-able dict: per link, per node and in total."""
        total = LinkStats()
        links = []
        lost = total.lost
        for (src, dst), ls in sorted(self._links.items()):
            links.append({"src": src, "dst": dst, **ls.as_dict()})
            total.sent += ls.sent
            total.delivered += ls.delivered
            for reason, n in ls.lost.items():
                lost[reason] = lost.get(reason, 0) + n
        addrs = sorted(set(self._tx_count) | set(self._refused))
        nodes = {
            str(a): {"tx": self._tx_count.get(a, 0), "refused": self._refused.get(a, 0)}
            for a in addrs
        }
        return {
            "preset": self.preset.name,
            "links": links,
            "nodes": nodes,
            "total": total.as_dict(),
        }

    # -- internals -----------------------------------------------------------------------------

    def _push(self, t: float, item: TxDone | _Rx) -> None:
        self._seq += 1
        heapq.heappush(self._queue, (t, self._seq, item))

    def _link(self, src: int, dst: int) -> LinkStats:
        ls = self._links.get((src, dst))
        if ls is None:
            ls = self._links[(src, dst)] = LinkStats()
        return ls

    def _reason(self, rx: _Rx) -> str | None:
        if not rx.audible:
            return "out_of_range"
        start, end = rx.start, rx.end
        for a, b in self._tx_intervals.get(rx.dst, ()):
            if a < end and start < b:
                return "half_duplex"
        frame_id = rx.frame_id
        for other in self._rx_intervals.get(rx.dst, ()):
            if other.start < end and start < other.end and other.frame_id != frame_id:
                return "collision"
        p, rng = self.preset, self._rng
        if rng.random() < self.loss_curve(rx.distance_m, p.max_range_m):
            return "range_loss"
        if self.loss > 0 and rng.random() < self.loss:
            return "loss"
        if p.ber > 0 and rng.random() < 1.0 - (1.0 - p.ber) ** (8 * len(rx.data)):
            return "bit_errors"
        return None

    def _decide(self, rx: _Rx) -> Delivery | Loss:
        self._deciding = rx.end
        self._prune(rx.dst)
        self._deciding = math.inf
        reason = self._reason(rx)
        ls = rx.link
        if reason is not None:
            ls.lost[reason] = ls.lost.get(reason, 0) + 1
            return Loss(rx.dst, rx.src, reason, rx.end, rx.frame_id, rx.dest)
        ls.delivered += 1
        start, end = rx.start, rx.end
        return Delivery(rx.dst, rx.src, rx.data, start, end, {
            "dest": rx.dest,
            "frame_id": rx.frame_id,
            "sent_at": rx.sent_at,
            "tx_start": rx.tx_start,
            "airtime_s": end - start,
            "travel_time_s": rx.travel_s,
            "distance_m": rx.distance_m,
        })

    def _prune(self, addr: int) -> None:
        """Forget the intervals of ``addr`` that no undecided reception can overlap any more.

        Only a speed-up: a forgotten interval ends before every undecided reception starts, so
        :meth:`_reason` would never count it. Each node is pruned when it is about to be looked
        at (a reception it decides) or added to (a frame it sends), so the cost follows the
        node's own traffic, not the size of the fleet. The horizon: an undecided reception
        ends no earlier than the first event still queued (or the one being decided), and
        starts at most a whole frame's airtime before it ends.
        """
        queue, horizon = self._queue, self._now
        if queue and queue[0][0] < horizon:
            horizon = queue[0][0]
        if self._deciding < horizon:
            horizon = self._deciding
        horizon -= self._longest_s
        spans = self._tx_intervals.get(addr)
        if spans and spans[0][1] < horizon:
            self._tx_intervals[addr] = [s for s in spans if s[1] >= horizon]
        rxs = self._rx_intervals.get(addr)
        if rxs and rxs[0].end < horizon:  # the oldest filed; later ones go with it
            self._rx_intervals[addr] = [r for r in rxs if r.end >= horizon]


def _position(pos: Iterable[float]) -> Position:
    x, y, z = (float(v) for v in pos)
    return (x, y, z)
