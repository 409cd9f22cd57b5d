"""Distributed LBL (seed 000 II-D/E): two-way travel times from the frames the fleet sends anyway.

Each node timestamps every reception (its own clock) and, when it transmits, writes for every
foreign node the delay ``δ`` from its last reception from that node to this transmission's start,
in µs, 24 bits each (:mod:`bridge.wire.frame`). When B hears A's frame carrying A's delay for B, B
knows when it sent the frame A heard (``t_tx``, B's clock) and when A's frame arrived (``t_rx``,
B's clock), so::

    2·τ = (t_rx − t_tx) − δ_A           one-way travel time τ, no clock synchronisation

Each difference is taken on one clock. A does the same with B's delays, so both ends of every
exchange get a range (:meth:`DlblRanger.on_receive`).

Conventions (one :class:`DlblRanger` per node, times in seconds on that node's clock):

- Turnaround: ``tx_latency_s`` is the time from the recorded transmission start to the signal
  leaving the transducer; ``rx_latency_s`` from the signal's arrival to the modem's reception
  timestamp. The ranger removes its own latencies on both sides: the delays it sends run from
  true arrival to true emission, so a node only needs to know its own modem.
- Delays too long for 24 bits (over ``DELAY_MAX_US`` µs, about 16.8 s), stale (older than
  ``stale_s``) or negative are sent as ``None`` (``NO_DELAY`` on the wire), never
  clamped. A receiver may accept delays from senders that wrap modulo 2²⁴ µs (``max_wraps``).
- Matching: B keeps its recent transmission times and picks the one that gives a travel time in
  ``[0, max_travel_s]``; none or several (ambiguous) is a counted drop in :attr:`drops`.
  ``max_travel_s`` must be less than half the shortest interval between a node's transmissions.
- Clock drift: ``δ_A`` is counted on A's clock. A relative rate error ε between the clocks adds
  ``−ε·δ_A/2`` to B's travel time (100 ppm and a 4 s delay: 0.2 ms, 0.3 m) and the opposite sign,
  weighted by B's delay, to A's; :func:`two_sided` combines both ends' results and cancels it.
  A node alone can learn the rate of a peer that transmits once per TDMA cycle of its own clock
  (``cycle_s``) or be told it (:meth:`DlblRanger.set_clock_rate`).
"""

from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from bridge.wire.frame import DELAY_MAX_US

WRAP_US = 1 << 24  # a wrapping sender counts delays modulo 2²⁴ µs


@dataclass(frozen=True)
class Range:
    """A one-way travel time to ``peer``, measured at ``time``.

    ``time`` is this node's clock at the reception that completed the measurement (the
    arrival, latency removed); the runtime may map it to wall time with ``dataclasses.replace``.

    ``reply_s`` is the other end's turnaround the measurement subtracted (DLBL delay, TWR
    processing time), kept for :func:`two_sided`.
    """

    peer: str
    travel_time_s: float
    method: str = "dlbl"
    time: float = 0.0
    reply_s: float = 0.0

    def range_m(self, sound_speed_mps: float) -> float:
        """The distance in metres, ``c·τ``."""
        return sound_speed_mps * self.travel_time_s

    def payload(self, sound_speed_mps: float) -> dict[str, float | str]:
        """The map published on ``@zab/<mission>/<node>/range/<peer>``."""
        return {
            "peer": self.peer,
            "range_m": self.range_m(sound_speed_mps),
            "time": self.time,
            "travel_time_s": self.travel_time_s,
            "sound_speed_mps": sound_speed_mps,
            "method": self.method,
        }


def two_sided(a: Range, b: Range) -> float:
    """Travel time from both ends' results of one exchange, first-order free of clock drift.

    ``a`` is A's range to B (it subtracted B's delay) and ``b`` B's range to A (it subtracted
    A's delay). Their drift errors are ``+ε·δ_B/2`` and ``−ε·δ_A/2``; weighting each by the
    delay the *other* subtracted cancels them (the idea of double-sided two-way ranging).
    """
    wa, wb = b.reply_s, a.reply_s
    if wa + wb <= 0:
        return (a.travel_time_s + b.travel_time_s) / 2.0
    return (a.travel_time_s * wa + b.travel_time_s * wb) / (wa + wb)


class DlblRanger:
    """One node's DLBL bookkeeping; pure, with every time passed in.

    ``nodes`` is the mission's node order; each sender's delay vector lists the other nodes in
    that order. Call :meth:`on_transmit` with the start time of every transmission (the delays
    to put in that frame come back) and :meth:`on_receive` with every frame heard from another
    node (ranges come back).
    """

    def __init__(
        self,
        node: str,
        nodes: Sequence[str],
        *,
        tx_latency_s: float = 0.0,
        rx_latency_s: float = 0.0,
        stale_s: float = DELAY_MAX_US * 1e-6,
        max_travel_s: float = 1.0,
        tolerance_s: float = 100e-6,
        history: int = 16,
        max_wraps: int = 0,
        cycle_s: float | None = None,
        max_skew_ppm: float = 200.0,
        skew_window: int = 24,
    ) -> None:
        if node not in nodes:
            raise ValueError(f"node {node!r} is not in the mission's nodes {list(nodes)}")
        if len(set(nodes)) != len(nodes):
            raise ValueError(f"duplicate node names in {list(nodes)}")
        if max_travel_s <= 0 or stale_s <= 0 or history < 1 or max_wraps < 0:
            raise ValueError("max_travel_s, stale_s and history must be positive, max_wraps ≥ 0")
        self.node = node
        self.nodes = tuple(nodes)
        self.foreign = tuple(n for n in nodes if n != node)
        self.tx_latency_s = tx_latency_s
        self.rx_latency_s = rx_latency_s
        self.stale_s = stale_s
        self.max_travel_s = max_travel_s
        self.tolerance_s = tolerance_s
        self.max_wraps = max_wraps
        self.cycle_s = cycle_s
        self.max_skew = max_skew_ppm * 1e-6
        self.drops: Counter[str] = Counter()
        self._last_rx: dict[str, float] = {}  # peer -> true arrival of its last frame
        self._tx: deque[float] = deque(maxlen=history)  # true emissions of our frames
        self._rate: dict[str, float] = {}  # peer clock seconds per our second
        self._rate_fixed: set[str] = set()
        self._emissions: dict[str, deque[float]] = {
            n: deque(maxlen=skew_window) for n in self.foreign
        }

    # -- clocks --------------------------------------------------------------------------------

    def set_clock_rate(self, peer: str, ratio: float) -> None:
        """Tell the ranger ``peer``'s clock runs ``ratio`` seconds per second of ours."""
        self._rate[peer] = float(ratio)
        self._rate_fixed.add(peer)

    def clock_rate(self, peer: str) -> float:
        """The rate of ``peer``'s clock relative to ours in use (1.0 if unknown)."""
        return self._rate.get(peer, 1.0)

    # -- transmit ------------------------------------------------------------------------------

    def delay_vector(self, t_start: float) -> list[int | None]:
        """The delays (µs or None) for a transmission starting at ``t_start``, in mission order."""
        emission = t_start + self.tx_latency_s
        out: list[int | None] = []
        for peer in self.foreign:
            rx = self._last_rx.get(peer)
            if rx is None:
                out.append(None)
                continue
            delay = emission - rx
            us = round(delay * 1e6)
            out.append(us if 0 <= us <= DELAY_MAX_US and delay <= self.stale_s else None)
        return out

    def on_transmit(self, t_start: float) -> list[int | None]:
        """Record a transmission starting at ``t_start``; return its delay vector."""
        delays = self.delay_vector(t_start)
        self._tx.append(t_start + self.tx_latency_s)
        return delays

    def forget_transmit(self, t_start: float) -> None:
        """Drop a recorded transmission that did not go out after all."""
        emission = t_start + self.tx_latency_s
        if emission in self._tx:
            self._tx.remove(emission)

    # -- receive -------------------------------------------------------------------------------

    def delays_of(self, src: str, vector: Sequence[int | None]) -> dict[str, int | None]:
        """Name the entries of ``src``'s delay vector (mission order without ``src``)."""
        order = [n for n in self.nodes if n != src]
        if len(vector) != len(order):
            raise ValueError(f"{src!r} sends {len(order)} delays, got {len(vector)}")
        return dict(zip(order, vector, strict=True))

    def on_receive(
        self,
        src: str,
        t_rx_start: float,
        delays: Mapping[str, int | None] | Sequence[int | None],
    ) -> list[Range]:
        """A frame from ``src`` started arriving at ``t_rx_start``; return the ranges it gives.

        ``delays`` is the frame's delay vector, by node name or in mission order. The reception
        is recorded for the delays of our next transmission in either case.
        """
        if src == self.node or src not in self.foreign:
            self.drops["unknown sender"] += 1
            return []
        arrival = t_rx_start - self.rx_latency_s
        named = delays if isinstance(delays, Mapping) else self.delays_of(src, delays)
        ranges: list[Range] = []
        delay_us = named.get(self.node)
        if delay_us is not None:
            rng = self._match(src, arrival, delay_us)
            if rng is not None:
                ranges.append(rng)
                self._learn_rate(src, arrival - rng.travel_time_s)
        self._last_rx[src] = arrival
        return ranges

    def _match(self, src: str, arrival: float, delay_us: int) -> Range | None:
        if not 0 <= delay_us <= DELAY_MAX_US:
            self.drops["bad delay"] += 1
            return None
        rate = self.clock_rate(src)
        found: list[tuple[float, float]] = []  # (two-way, delay in our seconds)
        too_short = too_long = 0
        if delay_us * 1e-6 > self.stale_s:
            self.drops["stale"] += 1
            return None
        for k in range(self.max_wraps + 1):
            delay = (delay_us + k * WRAP_US) * 1e-6 / rate
            for emission in self._tx:
                two_way = arrival - emission - delay
                if two_way < -self.tolerance_s:
                    too_short += 1
                elif two_way > 2 * self.max_travel_s:
                    too_long += 1
                else:
                    found.append((two_way, delay))
        if len(found) == 1:
            two_way, delay = found[0]
            return Range(src, max(two_way, 0.0) / 2.0, "dlbl", arrival, delay)
        if found:
            self.drops["ambiguous"] += 1
        elif not self._tx:
            self.drops["no transmission"] += 1
        elif too_long and not too_short:
            self.drops["too long"] += 1
        elif too_short and not too_long:
            self.drops["negative"] += 1
        else:
            self.drops["no match"] += 1
        return None

    # -- clock rate from a periodic sender ------------------------------------------------------

    def _learn_rate(self, peer: str, emission: float) -> None:
        """Fit ``peer``'s emission times (our clock) against its cycle count (its clock)."""
        if self.cycle_s is None or peer in self._rate_fixed:
            return
        history = self._emissions[peer]
        history.append(emission)
        if len(history) < 3:
            return
        e0, cycle = history[0], self.cycle_s
        ks = [round((e - e0) / cycle) for e in history]
        if ks[-1] - ks[0] < 2 or len(set(ks)) != len(ks):
            return
        n = len(ks)
        mk, me = sum(ks) / n, sum(history) / n
        skk = sum((k - mk) ** 2 for k in ks)
        slope = sum((k - mk) * (e - me) for k, e in zip(ks, history, strict=True)) / skk
        resid = [e - me - slope * (k - mk) for k, e in zip(ks, history, strict=True)]
        rms = math.sqrt(sum(r * r for r in resid) / n)
        ratio = cycle / slope  # peer seconds per our second
        if abs(ratio - 1.0) <= self.max_skew and rms < 1e-3:
            self._rate[peer] = ratio
