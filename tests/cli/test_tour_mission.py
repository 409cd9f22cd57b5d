"""The tour's variant of every shipped mission (``zab demo --mission``): it loads, and the
vehicle it surfaces stays within the water's range of the surface node."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest

from bridge.cli.demo import tour_mission
from bridge.core.outputs import Status
from bridge.mission.presets import node_preset
from bridge.runtime.virtual_fleet import FastFleet
from tests.conftest import MISSIONS


@pytest.mark.parametrize("path", sorted(MISSIONS.glob("*.yaml")), ids=lambda p: p.stem)
def test_the_tour_keeps_its_surfacing_vehicle_in_range(path: Path, mission_key: str) -> None:
    loaded, changes = tour_mission(path, 0.1, 70.0)
    mission = loaded.mission
    surface = next((n for n, v in mission.nodes.items() if v.role == "surface"), None)
    moving = [n for n, v in mission.nodes.items() if v.path is not None]
    if surface is None or not any("surfaces about" in c for c in changes):
        return  # (no surfacing in this tour, or the mission's own path)
    ocean = FastFleet(loaded, seed=1).ocean
    for name in moving:
        ranges = [p.max_range_m for p in (node_preset(mission, name),
                                          node_preset(mission, surface)) if p is not None]
        if not ranges:
            continue
        reach = min(ranges)
        at = [ocean.position(mission.nodes[n].address, 0.0) for n in (name, surface)]
        if math.dist(*at) > reach:
            continue  # out of direct range by design (a relay line)
        for t in range(0, 71, 5):
            here = ocean.position(mission.nodes[name].address, float(t))
            there = ocean.position(mission.nodes[surface].address, float(t))
            assert math.dist(here, there) <= reach, (name, t, here, there, reach)


def test_a_mission_that_cannot_take_a_tour_part_tours_without_it(mission_key: str) -> None:
    """goby's wire format has no image channels and no queries: the tour leaves the camera
    and the get out, not the whole demo ('cannot make the tour's variant'), nor does it
    start a bridge that stops at its first request ('?health is not a DCCL channel')."""
    loaded, changes = tour_mission(MISSIONS / "goby_dccl.yaml", 0.1, 70.0)
    assert not loaded.mission.images and not loaded.mission.queries
    assert not any("camera" in c or "queryable" in c for c in changes)
    assert any("surfaces about" in c for c in changes)


def test_an_rf_tank_vehicle_surfaces_where_it_is(mission_key: str) -> None:
    """bluerov_images: RF modems of 5 m range; the ROV rises and dives in place."""
    loaded, _ = tour_mission(MISSIONS / "bluerov_images.yaml", 0.1, 70.0)
    path = loaded.mission.nodes["rov"].path
    assert path is not None
    assert {(w.x, w.depth) for w in path.waypoints} == {(1.0, 0.8), (1.0, 0.0)}
    assert max(w.y for w in path.waypoints) < 1.0


def test_the_tour_s_picture_crosses_whole_beside_the_telemetry(mission_key: str) -> None:
    """MORPH's tour on the virtual clock with every key fed as the tour's programs publish:
    the camera's fragments fit beside lsv's telemetry, so the picture is whole within the
    tour (with 28 B fragments it was in one run of six)."""
    import random

    from bridge.cli.demo import default_demo_mission
    from bridge.cli.sim_fast import feed

    loaded, _ = tour_mission(default_demo_mission(), 0.1, 70.0)
    whole = []
    for seed in range(4):
        fleet = FastFleet(loaded, seed=seed, keep_outputs=True)
        feed(fleet, random.Random(seed), 70.0)
        fleet.run_until(70.0)
        whole += [t.time for t in fleet.outputs if t.node == "ssv"
                  and isinstance(t.output, Status) and t.output.topic == "images/camera/lsv"
                  and t.output.payload.get("final")][:1]
    assert len(whole) == 4 and max(whole) < 60.0, whole


@pytest.mark.parametrize("path", sorted(MISSIONS.glob("*.yaml")), ids=lambda p: p.stem)
def test_the_tour_s_variant_runs_on_the_virtual_clock(path: Path, mission_key: str) -> None:
    """Each tour variant's fleet, every key fed, for 60 virtual s: it ends, and frames go
    (hippocampus's tour with a query never sent its sensors, and its fleet on the virtual
    clock did not end)."""
    import random

    from bridge.cli.sim_fast import feed

    loaded, _ = tour_mission(path, 0.0, 70.0)
    fleet = FastFleet(loaded, seed=1)
    feed(fleet, random.Random(1), 60.0)
    acts = 0
    for core in fleet.cores.values():
        act = core.act

        def counted(*args: object, act: Any = act) -> Any:
            nonlocal acts
            acts += 1
            assert acts < 100_000, "a core asked to act without end"
            return act(*args)

        core.act = counted  # type: ignore[method-assign]
    fleet.run_until(60.0)
    sent = {c for core in fleet.cores.values() for c, n in core.stats.sent_per_channel.items()
            if n}
    assert sent, path
    if path.stem == "hippocampus":
        assert "sensors" in sent


@pytest.mark.parametrize("name", ["morph_evologics", "remus_micromodem"])
def test_a_real_modem_mission_tours_on_simulated_modems(name: str, mission_key: str) -> None:
    """zab demo --mission morph_evologics.yaml started EvoLogics backends on serial ports
    nobody had made: a screen of 'modem unavailable' warnings and nothing crossed."""
    loaded, changes = tour_mission(MISSIONS / f"{name}.yaml", 0.1, 70.0)
    mission = loaded.mission
    assert mission.modem.backend == "sim"
    assert all(mission.node_modem(n).backend == "sim" for n in mission.nodes)
    assert any("simulated ones with the same timings" in c for c in changes)


@pytest.mark.parametrize("path", sorted(MISSIONS.glob("*.yaml")), ids=lambda p: p.stem)
def test_the_tour_s_programs_put_what_their_bridges_take(path: Path, mission_key: str) -> None:
    """Every put of the tour's programs is taken by the vehicle's core: remus_ccl's apps put
    bathymetry without the fields its layout file holds ('depth: missing', every second),
    ros2_odometry's put msgpack on the ROS 2 topic's key expression ('unknown ROS 2 type *')
    and its odometry never crossed."""
    import zenoh

    from bridge.cli.demo import VehicleApps

    loaded, _ = tour_mission(path, 0.1, 70.0)
    apps = VehicleApps(loaded, print)
    puts: list[tuple[str, str, bytes, str]] = []

    class Session:
        def __init__(self, node: str) -> None:
            self.node = node

        def put(self, key: str, payload: bytes, encoding: Any = None, **_: object) -> None:
            assert "*" not in key, key  # a put goes on a key, not a key expression
            puts.append((self.node, key, payload, str(encoding or "")))

    apps.sessions = {node: Session(node) for node in loaded.mission.nodes}  # type: ignore[misc]
    apps.publish_once(100.0)
    cores = FastFleet(loaded, seed=1).cores
    for node, key, payload, encoding in puts:
        core = cores[node]
        members = core.families.feed_keys()  # (a key family's members go in as they are)
        taken = key if key in members else next(
            (k for k in core.bindings if zenoh.KeyExpr(k).intersects(key)), None)
        assert taken is not None, (node, key)
        core.ingest(taken, payload, encoding.split(";")[0] or "application/msgpack", 100.0,
                    sample_key=key)
        assert not core.stats.payloads_dropped, (node, key, core.take())
