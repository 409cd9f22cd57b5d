"""The page shows issue 15's state from a node's real stats: channels wanted there, open
acoustic queries, and the vehicles reached over IP."""

from __future__ import annotations

import msgpack

from bridge.core.loaded import load_mission
from bridge.core.node import NodeCore
from bridge.gui.model import GuiModel
from bridge.runtime.virtual_fleet import FastFleet
from tests.conftest import MISSIONS


def test_stats_of_the_surface_show_wants_open_queries_and_surfaced_vehicles() -> None:
    loaded = load_mission(MISSIONS / "zspace.yaml")
    fleet = FastFleet(loaded, seed=1)
    fleet.subscribe("top", "auv1/status")
    fleet.run_until(10.0)
    fleet.queries.get("top", "auv2/info", {"detail": 1})  # open until auv2's slot
    fleet.ip_link("auv1", "top", True)
    stats = fleet.cores["top"].snapshot(fleet.now)
    model = GuiModel(loaded, "top")
    model.ingest("@zab/zspace/top/stats", msgpack.packb(stats), "application/msgpack", 5.0)
    item = next(i for i in model.take() if i["kind"] == "stats")
    assert item["wanted"] == ["status"]
    assert item["open_queries"] == ["info → auv2"]
    assert item["ip_reachable"] == ["auv1"]


def test_each_family_member_shows_as_its_own_row() -> None:
    loaded = load_mission(MISSIONS / "zspace.yaml")
    model = GuiModel(loaded, "top")
    for member, celsius in (("a", 10.0), ("b", 20.0)):
        model.ingest(f"auv1/sensors/{member}/temp", msgpack.packb({"celsius": celsius}),
                     "application/msgpack", 1.0)
    rows = {i["channel"]: i["value"] for i in model.take() if i["kind"] == "channel"}
    assert rows == {"temps:a": {"celsius": 10.0}, "temps:b": {"celsius": 20.0}}


def test_the_page_shows_the_puts_no_channel_reads_at_its_node() -> None:
    loaded = load_mission(MISSIONS / "zspace.yaml")
    core = NodeCore(loaded, "top")
    core.outbound.keyspace.unmapped("top/cmd", 1.0)
    model = GuiModel(loaded, "top")
    model.ingest("@zab/zspace/top/stats", msgpack.packb(core.snapshot(2.0)),
                 "application/msgpack", 2.0)
    item = next(i for i in model.take() if i["kind"] == "stats")
    assert item["unmapped"] == ["top/cmd ×1"]
