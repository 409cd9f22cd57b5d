"""Scripted paths: positions along the legs, loops, and nodes moving in the ocean model."""

from __future__ import annotations

import asyncio
import logging
import math
import time

import pytest

from bridge.mission.path import Path, rectangle
from bridge.mission.presets import Preset
from bridge.sim.ocean import Delivery, LossCurve, Ocean
from bridge.sim.protocol import pack, read_message
from bridge.sim.service import WaterService

FAST = Preset(name="fast", frame_bytes=64, bitrate_bps=8000.0, overhead_s=0.1,
              sound_speed_mps=1500.0, max_range_m=3000.0)


def test_seed001_rectangle_is_sailed_round_and_round() -> None:
    path = rectangle((5.0, 5.0), 10.0, 30.0, depth=1.0, speed_mps=2.0)
    assert path.length_m == pytest.approx(80.0) and path.duration_s == pytest.approx(40.0)
    assert path.position_at(-3.0) == (5.0, 5.0, 1.0)  # waits at the start
    assert path.position_at(0.0) == (5.0, 5.0, 1.0)
    assert path.position_at(2.5) == pytest.approx((10.0, 5.0, 1.0))  # half the first leg
    assert path.position_at(5.0) == pytest.approx((15.0, 5.0, 1.0))  # first corner
    assert path.position_at(12.5) == pytest.approx((15.0, 20.0, 1.0))
    assert path.position_at(22.5) == pytest.approx((10.0, 35.0, 1.0))
    assert path.position_at(37.5) == pytest.approx((5.0, 10.0, 1.0))  # closing leg, south
    assert path.position_at(42.5) == pytest.approx(path.position_at(2.5))  # second lap


def test_open_path_stops_at_the_last_waypoint_and_changes_depth() -> None:
    path = Path(((0, 0, 0), (0, 30, 0), (0, 30, 40)), speed_mps=1.0)
    assert path.length_m == pytest.approx(70.0)
    assert path.position_at(10.0) == pytest.approx((0.0, 10.0, 0.0))
    assert path.position_at(50.0) == pytest.approx((0.0, 30.0, 20.0))
    assert path.position_at(1e6) == (0.0, 30.0, 40.0)
    still = Path(((3, 4, 5),), speed_mps=1.0, loop=True)  # one waypoint: it stays there
    assert still.position_at(100.0) == (3.0, 4.0, 5.0)
    repeated = Path(((0, 0, 0), (0, 0, 0), (10, 0, 0)), speed_mps=1.0)  # a zero-length leg
    assert repeated.position_at(5.0) == pytest.approx((5.0, 0.0, 0.0))


@pytest.mark.parametrize("waypoints, speed, message", [
    ((), 1.0, "at least one waypoint"),
    (((0, 0, 0),), 0.0, "positive"),
    (((0, 0, 0),), math.nan, "positive"),
    (((0, 0),), 1.0, "three finite numbers"),
    (((0, math.inf, 0),), 1.0, "three finite numbers"),
])
def test_bad_paths_are_refused_clearly(waypoints: tuple, speed: float, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        Path(waypoints, speed)
    with pytest.raises(ValueError, match="finite"):
        Path(((0, 0, 0),), 1.0).position_at(math.nan)


def test_a_node_on_a_path_is_heard_from_where_it_is_when_a_frame_leaves() -> None:
    ocean = Ocean(FAST, seed=1, positions={1: (0.0, 0.0, 0.0), 2: (0.0, 0.0, 0.0)},
                  loss_curve=LossCurve(edge_loss=0.0))
    ocean.set_path(2, Path(((150.0, 0, 0), (1650.0, 0, 0)), speed_mps=100.0), start=10.0)
    assert ocean.position(2, 0.0) == (150.0, 0.0, 0.0)  # before the start: at waypoint 0
    assert ocean.position(2, 20.0) == pytest.approx((1150.0, 0.0, 0.0))
    ocean.transmit(20.0, 1, b"x" * 4)
    events = ocean.advance(22.0)
    assert ocean.nodes[2] == pytest.approx((1350.0, 0.0, 0.0))  # it kept moving
    ocean.transmit(22.0, 1, b"y" * 4)
    events += ocean.advance(30.0)
    heard = [e for e in events if isinstance(e, Delivery)]
    assert [e.meta["distance_m"] for e in heard] == pytest.approx([1150.0, 1350.0])
    assert heard[0].meta["travel_time_s"] == pytest.approx(1150.0 / 1500.0)
    ocean.set_position(2, (7.0, 0.0, 0.0))  # an explicit position ends the path
    assert ocean.position(2, 1e6) == (7.0, 0.0, 0.0)
    with pytest.raises(KeyError):
        ocean.set_path(9, Path(((0, 0, 0),), 1.0), 0.0)


def test_the_water_service_starts_paths_when_it_starts(
        caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, logger="bridge.sim.service")

    async def main() -> None:
        path = Path(((0.0, 0.0, 5.0), (1000.0, 0.0, 5.0)), speed_mps=10.0)
        water = WaterService(FAST, 1, {1: (0.0, 0.0, 0.0)}, paths={2: path})
        await water.start()
        try:
            assert water.started_at is not None and abs(water.started_at - time.time()) < 1.0
            with pytest.raises(KeyError):
                water.position(2)  # not in the water until its modem says hello
            reader, writer = await asyncio.open_connection("127.0.0.1", water.port)
            writer.write(pack({"t": "hello", "v": 1, "addr": 2, "name": "auv", "pos": None}))
            assert (await read_message(reader) or {}).get("t") == "welcome"
            said = [r.getMessage() for r in caplog.records if "modem 2 (auv) at" in r.getMessage()]
            assert len(said) == 1 and said[0].endswith(", 0.0, 5.0)")  # on its path, not at 0
            at = water.started_at + 3.0
            assert water.position(2, at) == pytest.approx((30.0, 0.0, 5.0))
            x_now = water.position(2)[0]
            assert x_now == pytest.approx(10.0 * (time.time() - water.started_at), abs=0.5)
            writer.close()
        finally:
            await water.stop()

    asyncio.run(asyncio.wait_for(main(), 10))
