"""The Zenoh side on two real loopback sessions: publishers, attachments, tokens and cleanup."""

from __future__ import annotations

import json
import queue
import time
from collections.abc import Iterator

import pytest
import zenoh

from bridge.core.loaded import parse_mission
from bridge.ros2.attachment import Attachment, from_bridge
from bridge.runtime.ros2_graph import Ros2Graph
from tests.conftest import free_port
from tests.ros2.test_mission import MISSION, ODOM_KEY


def _session(listen: list[str], connect: list[str]) -> zenoh.Session:
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("listen/endpoints", json.dumps(listen))
    config.insert_json5("connect/endpoints", json.dumps(connect))
    config.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(config)


@pytest.fixture
def pair() -> Iterator[tuple[zenoh.Session, zenoh.Session]]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    bridge = _session([endpoint], [])
    app = _session([], [endpoint])
    try:
        yield bridge, app
    finally:
        app.close()
        bridge.close()


def test_publish_attach_announce_and_leave(pair: tuple[zenoh.Session, zenoh.Session]) -> None:
    bridge, app = pair
    table = parse_mission(MISSION, "rostest.yaml").table
    element = table.by_name("odom").elements[0]
    assert element.ros2 is not None
    samples: queue.Queue[zenoh.Sample] = queue.Queue()
    app.declare_subscriber(ODOM_KEY, samples.put)
    changes: queue.Queue[tuple[str, str]] = queue.Queue()
    app.liveliness().declare_subscriber(
        "@ros2_lv/0/**", lambda s: changes.put((str(s.kind), str(s.key_expr))))
    time.sleep(0.3)

    graph = Ros2Graph(bridge, "rostest", "ship")
    graph.announce(table, "ship")
    announced = {changes.get(timeout=3)[1] for _ in range(2)}
    zid = str(bridge.info.zid())
    assert announced == {
        f"@ros2_lv/0/{zid}/0/0/NN/%/%/zab_ship",
        f"@ros2_lv/0/{zid}/0/1/MP/%/%/zab_ship/%auv1%odom/nav_msgs::msg::dds_::Odometry_/"
        + ODOM_KEY.rsplit("/", 1)[1] + "/::,:,:,:,,"}

    value = {"pose": {"pose": {"position": {"x": 1.0, "y": 2.0}}}}
    for _ in range(3):
        graph.publish(ODOM_KEY, value, element.ros2, 1_700_000_000.5)
    got = [samples.get(timeout=3) for _ in range(3)]
    attachments = [Attachment.unpack(s.attachment.to_bytes()) for s in got]
    assert [a.sequence_number for a in attachments] == [1, 2, 3]
    assert {a.source_timestamp_ns for a in attachments} == {1_700_000_000_500_000_000}
    assert len({a.gid for a in attachments}) == 1
    assert all(from_bridge(s.attachment.to_bytes()) for s in got)

    graph.close()
    graph.close()  # safe twice
    gone = {changes.get(timeout=3) for _ in range(2)}
    assert {kind for kind, _ in gone} == {"SampleKind.DELETE"}
    assert {key for _, key in gone} == announced
