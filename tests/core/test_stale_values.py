"""A latest value older than one published already is not published (issue 29's relays): over
seed 002's UMCI mission a relay that fell behind delivered rov2's minutes-old status after
newer ones had come directly, rolling back what a subscriber at the surface holds (found from
outside: ages of 77, 98 and 121 s published after 1 s old ones)."""

from __future__ import annotations

from itertools import pairwise

import pytest

from bridge.core.loaded import parse_mission
from bridge.runtime.virtual_fleet import FastFleet
from tests.conftest import MISSIONS


@pytest.mark.parametrize("seed", [0, 1])
def test_a_relayed_status_older_than_the_one_published_is_not_published(seed: int) -> None:
    fleet = FastFleet(parse_mission((MISSIONS / "umci_relay.yaml").read_text(),
                                    "umci_relay.yaml"), seed=seed)
    for n in range(300):  # every 3 s, as the tester's programs: status and grip, and a goto
        at = 1.0 + 3.0 * n
        for rov in ("rov1", "rov2"):
            fleet.put(rov, f"{rov}/status", {"x": 1.0, "depth": 20.0, "battery": n % 101},
                      at=at)
            fleet.put(rov, f"{rov}/grip", {"force": 10.0}, at=at)
        if n % 2 == 0:
            fleet.put("surface", "rov2/goto", {"x": 1.0, "depth": 2.0}, at=at)
    fleet.run_until(900.0)  # (15 minutes: ROV2's drift out of RF and back, with late copies
    taken = [p.taken for _, p in fleet.published("surface", "rov2/status")]  # on the way)
    assert len(taken) > 20
    assert all(b >= a - 0.25 for a, b in pairwise(taken)), taken
    assert fleet.cores["surface"].stats.values_stale > 0  # (the relay's late copies)
