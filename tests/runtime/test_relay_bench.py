"""``bench/relay_bench.py`` keeps what it claims, on the virtual clock: over a line of relays
every value arrives within the age bound ``zab check`` prints, relaying costs airtime, the
failover and failback follow the RF link's thresholds, and a relay killed again and again
leaves every reliable command delivered once or reported failed."""

from __future__ import annotations

from types import ModuleType

import pytest

from tests.harness import bench_module


@pytest.fixture(scope="module")
def bench() -> ModuleType:
    return bench_module("relay_bench")


@pytest.mark.parametrize("hops", [1, 3])
def test_values_over_a_line_of_relays_arrive_within_the_bound(bench: ModuleType,
                                                              hops: int) -> None:
    row = bench.hops_run(hops, 0.1, 900.0, seed=2)
    assert 0.5 <= row["delivery"] < 1.0  # 10 % loss per hop, hop after hop
    assert row["value_age_max_s"] <= row["bound_s"]
    assert row["delivered"] + row["failed"] == row["commands"] and row["delivered"] > 0
    assert (row["relay_airtime_s"] > 0) is (hops > 1)


def test_failover_and_failback_follow_the_rf_thresholds(bench: ModuleType) -> None:
    rows = bench.failover_run(500.0, seed=1)
    assert [r["switch"] for r in rows][:3] == ["failover", "failback", "failover"]
    for row in rows:  # (the last RF frame heard may come up to a poll, ~1 s, before the
        # crossing; the policy looks once a second)
        limit = row["down_after_s"] if row["switch"] == "failover" else row["failback_s"]
        assert row["after_s"] is not None and limit - 1.2 <= row["after_s"] <= limit + 3.0


def test_a_relay_killed_again_and_again_delivers_once_or_reports(bench: ModuleType) -> None:
    chaos = bench_module("chaos")
    row = bench.chaos_virtual(300, 12, 0.3, seed=4)
    assert chaos.goal_met(row) and row["duplicates"] == 0 and row["delivered_once"] > 250


def test_a_relay_killed_again_and_again_is_routed_around_each_time(bench: ModuleType) -> None:
    row = bench.reroute_run(0.0, 3, seed=1)
    assert row["failovers"] == row["failbacks"] == 6  # at the surface and at far, each kill
    low, _, high = row["failover_s"]  # r1's last frame came within a cycle (12 s) of its kill
    assert row["down_after_s"] - 12.0 <= low and high <= row["down_after_s"] + 2.0
    low, _, high = row["failback_s"]  # heard again within a cycle or two of its restart
    assert row["failback_after_s"] <= low and high <= row["failback_after_s"] + 2 * 12.0 + 2.0
    assert bench_module("chaos").goal_met(row) and row["duplicates"] == 0
