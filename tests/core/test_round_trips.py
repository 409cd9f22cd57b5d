"""The retransmission wait learnt from round trips (bridge.core.round_trips)."""

from __future__ import annotations

import pytest

from bridge.core.round_trips import RoundTrips


def test_the_wait_follows_the_round_trips_between_retry_s_and_four_times_it() -> None:
    trips = RoundTrips(floor=50.0, ceiling=200.0)
    assert trips.timeout == 50.0 and trips.wait(2) == 100.0 and trips.wait(5) == 200.0
    trips.sample(10.0)  # faster than retry_s: the mission's worst case stands
    assert trips.timeout == 50.0
    for seconds in (60.0, 90.0, 120.0, 130.0, 130.0, 130.0):  # a relay's queue fills
        trips.sample(seconds)
    assert 130.0 < trips.timeout <= 200.0
    assert trips.wait(2) == 200.0  # doubling, never past the ceiling
    for _ in range(40):
        trips.sample(1000.0)  # a link down for a while
    assert trips.timeout == 200.0


@pytest.mark.parametrize("seconds", [0.0, 3.0, 1e6])
def test_one_sample_gives_a_timeout_within_the_bounds(seconds: float) -> None:
    trips = RoundTrips(floor=3.0, ceiling=12.0)
    trips.sample(seconds)
    assert 3.0 <= trips.timeout <= 12.0
