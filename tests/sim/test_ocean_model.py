"""The pure ocean model, driven by a fake clock."""

from __future__ import annotations

import json
import math

import pytest

from bridge.mission.presets import Preset, get_preset
from bridge.sim.ocean import Delivery, Loss, LossCurve, Ocean, TransmitRefused, TxDone

# 0.1 s overhead + 1 ms per byte; sound at 1500 m/s; heard up to 3 km.
FAST = Preset(
    name="fast",
    frame_bytes=64,
    bitrate_bps=8000.0,
    overhead_s=0.1,
    sound_speed_mps=1500.0,
    max_range_m=3000.0,
)
NO_RANGE_LOSS = LossCurve(edge_loss=0.0)


def line(*xs: float) -> dict[int, tuple[float, float, float]]:
    """Nodes 1, 2, ... on the x axis at the given metres."""
    return {i + 1: (x, 0.0, 0.0) for i, x in enumerate(xs)}


def run(ocean: Ocean, until: float = math.inf) -> list[TxDone | Delivery | Loss]:
    """Jump the fake clock from event to event until the water is quiet (or ``until``)."""
    events: list[TxDone | Delivery | Loss] = []
    while (t := ocean.next_event_time()) is not None and t <= until:
        events += ocean.advance(max(t, ocean.now))
    return events


def receptions(events: list[TxDone | Delivery | Loss]) -> list[Delivery | Loss]:
    return [e for e in events if not isinstance(e, TxDone)]


def test_airtime_and_propagation_arithmetic() -> None:
    ocean = Ocean(FAST, seed=1, positions=line(0, 1500), loss_curve=NO_RANGE_LOSS)
    end = ocean.transmit(0.0, 1, b"x" * 10, dest=2)
    assert end == pytest.approx(0.11)
    assert ocean.next_event_time() == pytest.approx(0.11)
    assert ocean.advance(0.05) == []
    (done,) = ocean.advance(0.2)
    assert isinstance(done, TxDone) and done.src == 1 and done.time == pytest.approx(0.11)
    assert ocean.next_event_time() == pytest.approx(1.11)
    (rx,) = ocean.advance(2.0)
    assert isinstance(rx, Delivery)
    assert (rx.dst, rx.src, rx.data) == (2, 1, b"x" * 10)
    assert rx.start == pytest.approx(1.0) and rx.end == pytest.approx(1.11)
    assert rx.meta["travel_time_s"] == pytest.approx(1.0)
    assert rx.meta["distance_m"] == pytest.approx(1500.0)
    assert rx.meta["dest"] == 2 and rx.meta["sent_at"] == 0.0
    assert ocean.next_event_time() is None


def test_broadcast_heard_by_all_with_3d_distance() -> None:
    ocean = Ocean(
        FAST,
        seed=1,
        positions={1: (0, 0, 0), 2: (300, 400, 0), 3: (0, 0, 1200)},
        loss_curve=NO_RANGE_LOSS,
    )
    ocean.transmit(0.0, 1, b"hi")
    got = {e.dst: e for e in receptions(run(ocean))}
    assert set(got) == {2, 3}
    assert all(isinstance(e, Delivery) for e in got.values())
    assert got[2].meta["travel_time_s"] == pytest.approx(500 / 1500)
    assert got[3].meta["travel_time_s"] == pytest.approx(0.8)
    assert got[2].meta["dest"] is None


def test_overlapping_frames_collide_both_lost() -> None:
    ocean = Ocean(FAST, seed=1, positions=line(0, 1500, 3000), loss_curve=NO_RANGE_LOSS)
    ocean.transmit(0.0, 1, b"a" * 10)
    ocean.transmit(0.05, 3, b"b" * 10)
    events = receptions(run(ocean))
    at2 = [e for e in events if e.dst == 2]
    assert len(at2) == 2 and all(isinstance(e, Loss) and e.reason == "collision" for e in at2)
    # the two ends hear each other: their own transmissions were long over
    assert {(e.src, e.dst) for e in events if isinstance(e, Delivery)} == {(1, 3), (3, 1)}
    assert ocean.link_stats(1, 2).lost == {"collision": 1}


def test_non_overlapping_frames_both_delivered() -> None:
    ocean = Ocean(FAST, seed=1, positions=line(0, 1500, 3000), loss_curve=NO_RANGE_LOSS)
    ocean.transmit(0.0, 1, b"a" * 10)
    ocean.advance(0.2)
    ocean.transmit(0.2, 3, b"b" * 10)
    at2 = [e for e in receptions(run(ocean)) if e.dst == 2]
    assert [type(e) for e in at2] == [Delivery, Delivery]
    assert [e.src for e in at2] == [1, 3]


def test_touching_frames_do_not_collide() -> None:
    ocean = Ocean(FAST, seed=1, positions=line(0, 1500, 3000), loss_curve=NO_RANGE_LOSS)
    ocean.transmit(0.0, 1, b"a" * 10)
    ocean.transmit(0.11, 3, b"b" * 10)  # arrives at 2 exactly when the first ends
    at2 = [e for e in receptions(run(ocean)) if e.dst == 2]
    assert all(isinstance(e, Delivery) for e in at2) and len(at2) == 2


def test_half_duplex_receiver_transmitting_loses_frame() -> None:
    ocean = Ocean(FAST, seed=1, positions=line(0, 150), loss_curve=NO_RANGE_LOSS)
    ocean.transmit(0.0, 1, b"a" * 10)  # reaches 2 during [0.1, 0.21]
    ocean.transmit(0.15, 2, b"b" * 10)  # 2 is transmitting [0.15, 0.26]
    events = receptions(run(ocean))
    lost = [e for e in events if isinstance(e, Loss)]
    assert [(e.src, e.dst, e.reason) for e in lost] == [(1, 2, "half_duplex")]
    # 2's frame reaches 1 at [0.25, 0.36], long after 1 finished sending
    assert [(e.src, e.dst) for e in events if isinstance(e, Delivery)] == [(2, 1)]


def test_refusals() -> None:
    ocean = Ocean(FAST, seed=1, positions=line(0, 100))
    ocean.transmit(0.0, 1, b"a")
    with pytest.raises(TransmitRefused) as info:
        ocean.transmit(0.05, 1, b"b")
    assert info.value.reason == "busy"
    ocean.advance(0.2)
    assert ocean.transmit(0.2, 1, b"c") > 0.2  # free again after TxDone
    cases = [(b"x" * 65, 2, "too_long"), (b"", 2, "empty"), (b"x", 9, "unknown_node")]
    for data, src, reason in cases:
        with pytest.raises(TransmitRefused) as info:
            ocean.transmit(0.3, src, data)
        assert info.value.reason == reason
    with pytest.raises(ValueError, match="backwards"):
        ocean.advance(0.1)


def test_beyond_max_range_never_delivered_and_silent() -> None:
    ocean = Ocean(FAST, seed=1, positions=line(0, 2000, 5100), loss_curve=NO_RANGE_LOSS)
    t = 0.0
    for _ in range(20):
        ocean.transmit(t, 1, b"far")  # node 3 is 5.1 km away
        ocean.transmit(t, 3, b"far")  # ... and its frames overlap 1's at node 2? no: out of range
        run(ocean)
        t += 10.0
    assert ocean.link_stats(1, 3).delivered == 0
    assert ocean.link_stats(1, 3).lost == {"out_of_range": 20}
    # 3 is 3.1 km from 2, also out of range, so it never collides with 1's frames at 2
    assert ocean.link_stats(1, 2).delivered == 20
    assert ocean.link_stats(3, 2).lost == {"out_of_range": 20}


def send_many(ocean: Ocean, n: int, size: int = 10) -> None:
    t = 0.0
    for _ in range(n):
        ocean.transmit(t, 1, b"z" * size)
        run(ocean)
        t = ocean.busy_until(1) + 2.0


def test_bit_error_rate_statistics() -> None:
    ocean = Ocean(FAST.replace(ber=1e-3), seed=7, positions=line(0, 100), loss_curve=NO_RANGE_LOSS)
    send_many(ocean, 2000)
    p = 1 - (1 - 1e-3) ** 80
    lost = ocean.link_stats(1, 2).lost.get("bit_errors", 0)
    assert abs(lost - 2000 * p) < 4 * math.sqrt(2000 * p * (1 - p))


def test_uniform_loss_statistics() -> None:
    ocean = Ocean(FAST, seed=3, positions=line(0, 100), loss=0.3, loss_curve=NO_RANGE_LOSS)
    send_many(ocean, 2000)
    stats = ocean.link_stats(1, 2)
    assert stats.sent == 2000 and stats.delivered + stats.lost["loss"] == 2000
    assert abs(stats.lost["loss"] - 600) < 4 * math.sqrt(2000 * 0.3 * 0.7)


def test_range_loss_rises_with_distance() -> None:
    curve = LossCurve()
    assert curve(100, 3000) < 1e-6
    assert curve(1500, 3000) < 0.01
    assert curve(3000, 3000) == pytest.approx(0.2)
    near = Ocean(FAST, seed=5, positions=line(0, 300))
    far = Ocean(FAST, seed=5, positions=line(0, 2950))
    send_many(near, 500)
    send_many(far, 500)
    assert near.link_stats(1, 2).delivered == 500
    assert 50 < far.link_stats(1, 2).lost.get("range_loss", 0) < 150


def test_same_seed_same_outcome_with_jitter() -> None:
    def trace(seed: int) -> list[tuple[object, ...]]:
        ocean = Ocean(get_preset("s2cr-burst"), seed=seed, positions=line(0, 700, 1400), loss=0.2)
        out: list[tuple[object, ...]] = []
        t = 0.0
        for i in range(60):
            src = 1 + i % 3
            if ocean.busy_until(src) <= t:
                ocean.transmit(t, src, bytes([i]) * 20)
            out += [(type(e).__name__, *vars(e).values()) for e in ocean.advance(t)]
            t += 0.4
        out += [(type(e).__name__, *vars(e).values()) for e in run(ocean)]
        return out

    assert trace(11) == trace(11)
    assert trace(11) != trace(12)


def test_jitter_is_truncated_at_zero() -> None:
    ocean = Ocean(get_preset("s2cr-burst"), seed=2, positions=line(0, 10))
    delays = []
    t = 0.0
    for _ in range(300):
        ocean.transmit(t, 1, b"q")
        delays += [
            e.meta["tx_start"] - e.meta["sent_at"] for e in run(ocean) if isinstance(e, Delivery)
        ]
        t = ocean.busy_until(1) + 1.0
    assert min(delays) >= 0.0
    assert 0.4 < sum(delays) / len(delays) < 0.6  # 443 ms mean, pushed up by the truncation


def test_moving_node_changes_travel_time_and_min_range() -> None:
    ocean = Ocean(get_preset("s100-rf"), seed=1, positions=line(0, 0.1))
    ocean.transmit(0.0, 1, b"rf")
    (rx,) = [e for e in run(ocean) if isinstance(e, Delivery)]
    assert rx.meta["distance_m"] == pytest.approx(0.1)  # closer than min range: still heard
    ocean.set_position(2, (10.0, 0.0, 0.0))
    ocean.transmit(ocean.busy_until(1) + 1.0, 1, b"rf")
    assert [e.reason for e in run(ocean) if isinstance(e, Loss)] == ["out_of_range"]


def test_a_node_put_with_the_time_moves_on_at_its_last_velocity() -> None:
    ocean = Ocean(FAST, seed=1, positions=line(0, 300), loss_curve=NO_RANGE_LOSS)
    ocean.set_position(2, (300.0, 0.0, 10.0), now=0.0)
    assert ocean.position(2, 3.0) == (300.0, 0.0, 10.0)  # one sample: no velocity yet
    ocean.set_position(2, (301.0, 2.0, 10.0), now=1.0)  # its navigation, a second later
    assert ocean.position(2, 1.5) == pytest.approx((301.5, 3.0, 10.0))
    assert ocean.position(2, 60.0) == pytest.approx((306.0, 12.0, 10.0))  # 5 s on at most
    # each frame takes the positions of the moment it is sent: 1.5 s of glide further
    ocean.transmit(2.5, 1, b"x")
    (rx,) = receptions(run(ocean))
    assert rx.meta["distance_m"] == pytest.approx(math.dist((0, 0, 0), (302.5, 5.0, 10.0)))
    ocean.set_position(2, (310.0, 5.0, 10.0), now=20.0)  # samples too far apart: it stops
    assert ocean.position(2, 22.0) == (310.0, 5.0, 10.0)
    ocean.set_position(2, (400.0, 0.0, 0.0))  # without the time: put there, and it stays
    assert ocean.position(2, 30.0) == (400.0, 0.0, 0.0)


def test_stats_are_json_able() -> None:
    ocean = Ocean(FAST, seed=1, positions=line(0, 1500, 3000), loss_curve=NO_RANGE_LOSS)
    ocean.transmit(0.0, 1, b"a")
    ocean.transmit(0.0, 3, b"b")
    run(ocean)
    stats = json.loads(json.dumps(ocean.stats()))
    assert stats["total"]["sent"] == 4
    assert stats["total"]["lost"] == {"collision": 2}
    assert stats["nodes"]["1"]["tx"] == 1
    assert {(s["src"], s["dst"]) for s in stats["links"]} == {(1, 2), (1, 3), (3, 1), (3, 2)}


def test_pruning_forgets_only_what_cannot_matter() -> None:
    """A busy channel (random senders, many collisions, out-of-range pairs) gives the same
    events with pruning as without, while each node keeps only a few intervals."""
    import random

    def busy(prune: bool) -> tuple[list[TxDone | Delivery | Loss], int]:
        ocean = Ocean(FAST, seed=5, positions=line(0, 400, 900, 2500, 3400, 5200),
                      loss_curve=NO_RANGE_LOSS)
        if not prune:
            ocean._prune = lambda addr: None  # type: ignore[method-assign]
        rng, events, now, most = random.Random(8), [], 0.0, 0
        for _ in range(600):
            now += rng.expovariate(4.0)
            events += run(ocean, now)
            src = rng.randint(1, 6)
            if ocean.busy_until(src) <= now:
                ocean.transmit(now, src, bytes(rng.randint(1, 64)))
            most = max(most, *(len(v) for v in ocean._rx_intervals.values()),
                       *(len(v) for v in ocean._tx_intervals.values()))
        return events + run(ocean), most

    pruned, most = busy(prune=True)
    kept, _ = busy(prune=False)
    assert pruned == kept
    assert {type(e).__name__ for e in pruned} == {"TxDone", "Delivery", "Loss"}
    assert {e.reason for e in pruned if isinstance(e, Loss)} >= {"collision", "out_of_range"}
    assert most < 30
