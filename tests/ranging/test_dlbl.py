"""DLBL ranging in a tiny pure event simulation: TDMA, clock offsets and drift, jitter, loss."""

from __future__ import annotations

import heapq
import math
import random
from collections.abc import Callable
from dataclasses import dataclass, field

import pytest

from bridge.ranging.dlbl import WRAP_US, DlblRanger, Range, two_sided
from bridge.wire.frame import DELAY_MAX_US

C = 1500.0  # m/s, uniform water
Pos = tuple[float, float, float]


@dataclass
class Node:
    """A simulated vehicle: a clock ``local = offset + (1 + drift)·t`` and a position."""

    name: str
    where: Callable[[float], Pos]
    offset: float = 0.0
    drift: float = 0.0
    tx_latency: float = 0.0
    rx_latency: float = 0.0
    ranger: DlblRanger | None = None

    def local(self, t: float) -> float:
        return self.offset + (1.0 + self.drift) * t

    def true(self, local: float) -> float:
        return (local - self.offset) / (1.0 + self.drift)


@dataclass
class Measured:
    receiver: str
    range: Range
    truth_s: float  # true one-way travel time at reception
    cycle: int


@dataclass
class Sim:
    nodes: list[Node]
    slot_s: float = 1.0
    jitter_s: float = 0.0
    loss: float = 0.0
    seed: int = 1
    measured: list[Measured] = field(default_factory=list)

    @property
    def cycle_s(self) -> float:
        return self.slot_s * len(self.nodes)

    def run(self, cycles: int) -> list[Measured]:
        """Each node sends once per cycle at its slot start on its own clock."""
        rnd = random.Random(self.seed)
        events: list[tuple[float, int, str, tuple]] = []
        seq = 0
        for k in range(cycles):
            for i, node in enumerate(self.nodes):
                start = node.offset + k * self.cycle_s + i * self.slot_s  # local slot start
                heapq.heappush(events, (node.true(start), seq, "tx", (node, start, k)))
                seq += 1
        while events:
            t, _, kind, args = heapq.heappop(events)
            if kind == "tx":
                node, start, k = args
                assert node.ranger is not None
                delays = node.ranger.on_transmit(start)
                emitted = node.true(start + node.tx_latency)
                for other in self.nodes:
                    if other is node or rnd.random() < self.loss:
                        continue
                    tau = math.dist(node.where(emitted), other.where(emitted)) / C
                    arrival = emitted + tau
                    stamp = other.local(arrival) + other.rx_latency + rnd.gauss(0, self.jitter_s)
                    payload = (other, node.name, stamp, tuple(delays), k)
                    heapq.heappush(events, (arrival, seq, "rx", payload))
                    seq += 1
            else:
                other, src, stamp, delays, k = args
                assert other.ranger is not None
                for rng in other.ranger.on_receive(src, stamp, delays):
                    sender = next(n for n in self.nodes if n.name == src)
                    truth = math.dist(sender.where(t), other.where(t)) / C
                    self.measured.append(Measured(other.name, rng, truth, k))
        return self.measured


def fixed(p: Pos) -> Callable[[float], Pos]:
    return lambda _t: p


def fleet(specs: list[tuple[str, Pos, float, float]], **ranger_kw: object) -> list[Node]:
    """Nodes from (name, position, clock offset, drift) with rangers that know the order."""
    names = [s[0] for s in specs]
    nodes = []
    for name, pos, offset, drift in specs:
        node = Node(name, fixed(pos), offset, drift)
        node.ranger = DlblRanger(name, names, **ranger_kw)  # type: ignore[arg-type]
        nodes.append(node)
    return nodes


def errors_m(measured: list[Measured]) -> list[float]:
    return [abs(m.range.travel_time_s - m.truth_s) * C for m in measured]


def test_two_nodes_exact_without_drift() -> None:
    nodes = fleet([("a", (0, 0, 5), 1000.0, 0.0), ("b", (120.0, 35.0, 20), -7.5, 0.0)])
    measured = Sim(nodes, slot_s=2.0).run(cycles=5)
    # a's first frame carries nothing; every later frame gives its receiver a range
    assert [m.receiver for m in measured] == ["a", "b"] * 4 + ["a"]
    truth = math.dist((0, 0, 5), (120.0, 35.0, 20))
    for m in measured:
        assert m.range.range_m(C) == pytest.approx(truth, abs=1e-3)  # µs rounding
        assert m.range.method == "dlbl"
    assert {m.range.peer for m in measured} == {"a", "b"}


def test_turnaround_latencies_are_removed() -> None:
    specs = [("a", (0.0, 0.0, 1.0), 0.0, 0.0), ("b", (40.0, 0.0, 1.0), 0.0, 0.0)]
    lat = {"a": (0.012, 0.004), "b": (0.020, 0.007)}
    nodes = fleet(specs)
    for n in nodes:
        n.tx_latency, n.rx_latency = lat[n.name]
        n.ranger = DlblRanger(
            n.name, ["a", "b"], tx_latency_s=lat[n.name][0], rx_latency_s=lat[n.name][1]
        )
    measured = Sim(nodes).run(cycles=4)
    assert measured and all(e < 2e-3 for e in errors_m(measured))
    # the same modems with latencies unknown to the ranger: biased by half the turnarounds
    naive = fleet(specs)
    for n in naive:
        n.tx_latency, n.rx_latency = lat[n.name]
    biased = Sim(naive).run(cycles=4)
    bias = sum(sum(v) for v in lat.values()) / 2 * C
    assert all(m.range.range_m(C) - 40.0 == pytest.approx(bias, abs=2e-3) for m in biased)


def three_drifting(**ranger_kw: object) -> list[Node]:
    return fleet(
        [
            ("surface", (0.0, 0.0, 0.5), 50_000.0, +50e-6),
            ("auv1", (30.0, 40.0, 10.0), -3.25, -50e-6),
            ("auv2", (-80.0, 100.0, 25.0), 777.0, +20e-6),
        ],
        **ranger_kw,
    )


def test_three_nodes_drift_and_jitter_one_sided_bound() -> None:
    jitter = 20e-6
    nodes = three_drifting()
    measured = Sim(nodes, slot_s=1.0, jitter_s=jitter, seed=3).run(cycles=30)
    drift = {n.name: n.drift for n in nodes}
    # every ordered pair each cycle, but in the first only the later slots hear earlier ones
    assert len(measured) == 3 + 6 * 29
    for m in measured:
        # the peer's delay is counted on its clock: error ε·δ/2 plus jitter
        eps = drift[m.range.peer] - drift[m.receiver]
        bound = abs(eps) * m.range.reply_s / 2 + 5 * jitter
        assert abs(m.range.travel_time_s - m.truth_s) <= bound
    # with ±50 ppm and 1-2 s delays one side alone is off by up to ~10 cm
    assert max(errors_m(measured)) > 0.03


def pair_up(measured: list[Measured], cycles: int) -> list[float]:
    """Two-sided errors (m) from both ends' ranges of each pair in each cycle."""
    out = []
    for cyc in range(1, cycles):
        for a, b in (("surface", "auv1"), ("surface", "auv2"), ("auv1", "auv2")):
            ra = [m for m in measured if (m.receiver, m.range.peer, m.cycle) == (a, b, cyc)]
            rb = [m for m in measured if (m.receiver, m.range.peer, m.cycle) == (b, a, cyc)]
            if ra and rb:
                out.append(abs(two_sided(ra[0].range, rb[0].range) - ra[0].truth_s) * C)
    return out


def test_two_sided_cancels_drift() -> None:
    measured = Sim(three_drifting(), slot_s=1.0, seed=4).run(cycles=30)
    assert max(errors_m(measured)) > 0.1  # one side alone: drift error
    combined = pair_up(measured, 30)
    assert len(combined) == 3 * 29
    assert max(combined) < 0.006  # second order and µs rounding only
    noisy = pair_up(Sim(three_drifting(), slot_s=1.0, jitter_s=20e-6, seed=4).run(30), 30)
    assert sorted(noisy)[int(0.95 * len(noisy))] < 0.05  # jitter σ ≈ 2 cm


def test_periodic_peer_teaches_clock_rate() -> None:
    nodes = three_drifting(cycle_s=3.0)
    measured = Sim(nodes, slot_s=1.0, jitter_s=10e-6, seed=5).run(cycles=40)
    late = [m for m in measured if m.cycle >= 10]
    errs = sorted(errors_m(late))
    assert errs[int(0.95 * len(errs))] < 0.03
    surface = nodes[0].ranger
    assert surface is not None
    assert surface.clock_rate("auv1") == pytest.approx((1 - 50e-6) / (1 + 50e-6), abs=2e-6)


def test_missing_receptions_match_older_transmissions() -> None:
    nodes = three_drifting()
    for n in nodes:
        n.drift = 0.0
    measured = Sim(nodes, slot_s=1.5, jitter_s=10e-6, loss=0.35, seed=6).run(cycles=60)
    # delays then refer to frames one or more cycles old; the right one is still found
    assert any(m.range.reply_s > 4.5 for m in measured)
    assert len(measured) > 50
    assert max(errors_m(measured)) < 0.06


def test_delay_vector_24_bit_limit_and_stale() -> None:
    ranger = DlblRanger("a", ["a", "b", "c"], stale_s=60.0)
    ranger.on_receive("b", 100.0, [None, None])
    assert ranger.on_transmit(100.5) == [500_000, None]
    assert ranger.delay_vector(100.0 + DELAY_MAX_US * 1e-6) == [DELAY_MAX_US, None]
    # one µs more does not fit 24 bits: not sent (never clamped, never wrapped)
    assert ranger.delay_vector(100.0 + (DELAY_MAX_US + 1) * 1e-6) == [None, None]
    short = DlblRanger("a", ["a", "b", "c"], stale_s=5.0)
    short.on_receive("c", 10.0, {"a": None, "b": None})
    assert short.delay_vector(14.9) == [None, 4_900_000]
    assert short.delay_vector(15.1) == [None, None]  # stale
    assert short.delay_vector(9.0) == [None, None]  # reception after the transmission start


def test_wrapping_sender_unwrapped_when_allowed() -> None:
    tau, delay = 0.05, 20.0  # A answers B's frame 20 s later: more than 2²⁴ µs
    wrapped = round(delay * 1e6) - WRAP_US
    for wraps, expect in ((1, tau), (0, None)):
        b = DlblRanger("b", ["a", "b"], max_wraps=wraps, stale_s=30.0)
        b.on_transmit(1000.0)
        got = b.on_receive("a", 1000.0 + tau + delay + tau, {"b": wrapped})
        if expect is None:
            assert got == []
            assert b.drops["too long"] == 1
        else:
            assert got[0].travel_time_s == pytest.approx(expect, abs=1e-6)


def test_impossible_results_are_counted_drops() -> None:
    b = DlblRanger("b", ["a", "b", "c"], max_travel_s=0.5)
    assert b.on_receive("a", 5.0, {"b": 1000}) == []  # no transmission yet
    b.on_transmit(10.0)
    assert b.on_receive("a", 12.0, {"b": 2_500_000}) == []  # would be negative
    assert b.on_receive("a", 14.0, {"b": 100_000}) == []  # 1.9 s: longer than max travel
    assert b.on_receive("b", 14.0, {"a": 1}) == []  # our own frame
    assert b.on_receive("z", 14.0, {"b": 1}) == []  # not in the mission
    b.on_transmit(10.4)  # two transmissions closer than twice max travel
    assert b.on_receive("a", 11.2, {"b": 300_000}) == []
    assert dict(b.drops) == {
        "no transmission": 1,
        "negative": 1,
        "too long": 1,
        "unknown sender": 2,
        "ambiguous": 1,
    }
    b.forget_transmit(10.4)
    stale = DlblRanger("b", ["a", "b"], stale_s=2.0)
    stale.on_transmit(0.0)
    assert stale.on_receive("a", 3.1, {"b": 3_000_000}) == []  # a heard us too long ago
    assert stale.drops == {"stale": 1}
    (rng,) = b.on_receive("a", 11.2, {"b": 1_000_000})
    assert rng.travel_time_s == pytest.approx(0.1)


def test_delay_vector_order_and_payload() -> None:
    r = DlblRanger("b", ["a", "b", "c"])
    assert r.foreign == ("a", "c")
    assert r.delays_of("c", [7, None]) == {"a": 7, "b": None}
    with pytest.raises(ValueError, match="sends 2 delays"):
        r.delays_of("c", [7])
    with pytest.raises(ValueError, match="not in the mission"):
        DlblRanger("x", ["a", "b"])
    payload = Range("a", 0.02, "dlbl", 12.5, 1.0).payload(1500.0)
    assert payload["range_m"] == pytest.approx(30.0)
    assert set(payload) >= {"range_m", "time", "travel_time_s", "sound_speed_mps", "method"}


def test_two_sided_weights() -> None:
    # A's side off by +ε·δ_B/2, B's by −ε·δ_A/2, ε = 1e-4, δ_A = 1 s, δ_B = 3 s
    tau, eps = 0.04, 1e-4
    a = Range("b", tau + eps * 3.0 / 2, reply_s=3.0)
    b = Range("a", tau - eps * 1.0 / 2, reply_s=1.0)
    assert two_sided(a, b) == pytest.approx(tau, abs=1e-12)
