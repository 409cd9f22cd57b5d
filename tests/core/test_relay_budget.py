"""``zab check``'s relay budget counts what a relay really sends (whole frames: headers,
acknowledgements, entries for others), and the fleet on the virtual clock agrees with it: a
relay's backlog stays bounded where the check says it fits and grows where it says it does
not. Found from outside: on umci_relay the check said "fits" (2.2 B/s carried of 7.1) while
rov1's backlog grew to its limit with RF up: every reliable value ROV2 acknowledged made four
frames for the surface (the ack and its three repeats), 25 bytes each over the acoustic hop,
none of them counted."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest

from bridge.core.events import FrameRelayed, SendFailed
from bridge.core.loaded import LoadedMission, parse_mission
from bridge.core.receivers import ACK_REPEATS
from bridge.core.routing import CARRIED_KEPT
from bridge.report.check import check_mission
from bridge.runtime.virtual_fleet import FastFleet
from bridge.wire.goby import frame_codec_for

MISSIONS = Path(__file__).resolve().parents[2] / "deploy" / "missions"
UMCI = (MISSIONS / "umci_relay.yaml").read_text()
LINE = (MISSIONS / "acoustic_line.yaml").read_text()
RUN_S = 1800.0


def rf_up(text: str) -> str:
    """umci_relay with ROV2 held 3 m from ROV1 (its drift out of RF range taken out)."""
    return re.sub(r"    path:.*?loop: true\n", "    position: {x: 403, y: 0, depth: 20}\n",
                  text, flags=re.S)


def relays(loaded: LoadedMission) -> dict[tuple[str, str], dict[str, Any]]:
    return {(r["node"], r["link"]): r
            for r in check_mission(loaded).data["network"]["relays"]}


def at_check_load(fleet: FastFleet, until: float) -> None:
    """Every input of every sender fed as the check assumes: each channel at its
    ``interval_s``, one at every opportunity once a second (faster than any turn)."""
    for channel in fleet.loaded.table.channels:
        period = channel.interval_s or 1.0
        for sender in channel.senders:
            for element in channel.elements:
                value = {f.name: 0 for f in element.layout.fields}
                for i in range(int(until / period)):
                    fleet.put(sender, element.input_key(sender), value, at=0.37 + i * period)


def backlog(fleet: FastFleet, node: str, link: str, until: float) -> list[int]:
    """What ``node`` holds to carry on ``link``, every 30 s of the run."""
    seen = []
    while fleet.now < until:
        fleet.run_until(fleet.now + 30.0)
        seen.append(len(fleet.cores[node].network.routing.waiting[link]))  # type: ignore[union-attr]
    return seen


def test_the_budget_counts_whole_frames_and_the_acknowledgements_they_carry() -> None:
    loaded = parse_mission(UMCI, "umci_relay.yaml")
    row = relays(loaded)[("rov1", "acoustic")]
    source = next(s for s in row["carried_from"] if s["origin"] == "rov2")
    assert source["for"] == ["surface"]
    # ROV2's frames for the surface: its status every 10 s, and one frame acknowledging each
    # of the surface's goto frames (at every surface turn: 2 slots of the 15-s cycle); the
    # ack's repeats ride in those frames, never in one of their own
    assert source["frames_per_s"] == pytest.approx(1 / 10 + 2 / 15, abs=1e-3)
    codec, net = frame_codec_for(loaded.table), loaded.table.net
    assert net is not None
    overhead = codec.frame_bytes_for(()) + net.routed_bytes + 1  # frame, header, bundle length
    assert source["Bps"] > source["frames_per_s"] * overhead
    assert row["capacity_Bps"] == pytest.approx(2 / 15 * (64 - 1), abs=1e-3)
    assert row["margin_Bps"] == pytest.approx(
        row["capacity_Bps"] - row["own_Bps"] - row["carried_Bps"], abs=2e-3)


@pytest.mark.parametrize(("name", "text", "node", "link", "fits"), [
    ("umci-as-shipped", rf_up(UMCI), "rov1", "acoustic", True),
    ("umci-status-every-4s", rf_up(UMCI).replace("interval_s: 10", "interval_s: 4"), "rov1",
     "acoustic", False),
    ("line-as-shipped", LINE, "n1", "modem", True),
], ids=["umci-as-shipped", "umci-status-every-4s", "line-as-shipped"])
def test_the_fleet_agrees_with_the_check_on_whether_a_relay_keeps_up(
        name: str, text: str, node: str, link: str, fits: bool) -> None:
    loaded = parse_mission(text, f"{name}.yaml")
    row = relays(loaded)[(node, link)]
    assert row["fits"] is fits, row
    fleet = FastFleet(loaded, seed=1)
    at_check_load(fleet, RUN_S)
    seen = backlog(fleet, node, link, RUN_S)
    dropped = fleet.cores[node].stats.frames_dropped["relay_full"]
    if fits:  # the relay empties its queue turn after turn
        assert max(seen) <= 4 and dropped == 0, (seen, dropped)
    else:  # it falls behind and stays behind, dropping what it cannot hold
        assert seen[-1] >= CARRIED_KEPT - 4 and dropped > 0, (seen, dropped)
        assert seen[len(seen) // 4] < seen[-1]


def test_repeated_acknowledgements_ride_only_frames_relayed_anyway() -> None:
    """Each goto frame of the surface costs the relay one frame of ROV2's acknowledgement,
    not one more per repeat (before: 800 frames queued in 30 minutes, the budget's 0.633 a
    second of 25 bytes, where its turns carry 8.4 bytes a second)."""
    loaded = parse_mission(rf_up(UMCI), "umci_relay.yaml")
    fleet = FastFleet(loaded, seed=1)
    at_check_load(fleet, RUN_S)
    fleet.run_until(RUN_S)
    carried = [t.output for t in fleet.outputs if isinstance(t.output, FrameRelayed)]
    from_rov2 = sum(e.origin == "rov2" for e in carried)
    gotos = sum(e.origin == "surface" for e in carried)
    statuses = RUN_S / 10
    assert from_rov2 <= (statuses + gotos) * 1.1
    assert from_rov2 < (statuses + (1 + ACK_REPEATS) * gotos) * 0.6


def test_a_relay_never_sends_a_bundle_larger_than_its_frame() -> None:
    """Its own frame first and a carried frame in the room left: that room counted neither
    the carried frame's length byte nor the bundle's count (66-byte bundles refused by a
    64-byte modem, a turn lost each time, 7 in 30 minutes of umci_relay)."""
    fleet = FastFleet(parse_mission(UMCI, "umci_relay.yaml"), seed=1)
    at_check_load(fleet, RUN_S)
    fleet.run_until(RUN_S)
    refused = [t.output for t in fleet.outputs if isinstance(t.output, SendFailed)]
    assert refused == []
    assert fleet.cores["rov1"].stats.send_errors == 0
