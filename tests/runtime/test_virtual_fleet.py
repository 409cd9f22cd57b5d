"""The virtual-clock fleet runs the same cores as ``zab sim``, deterministically and fast."""

from __future__ import annotations

from bridge.core.events import FrameSent, SendFailed
from bridge.core.loaded import LoadedMission, load_mission, parse_mission
from bridge.core.node import Publish
from bridge.runtime.virtual_fleet import FastFleet
from bridge.sim.ocean import TransmitRefused
from tests.conftest import MISSIONS


def morph(auth: bool = True) -> LoadedMission:
    """The MORPH mission as shipped (authenticated), or with ``auth: off``."""
    text = (MISSIONS / "morph.yaml").read_text()
    if not auth:
        text = text.replace("auth: {tag_bytes: 4}", "auth: off")
    return parse_mission(text, "morph.yaml")


def run_morph(seed: int, auth: bool = True) -> FastFleet:
    fleet = FastFleet(morph(auth), seed=seed)
    for i in range(40):
        fleet.put("lsv", "target_reference", {"vector": {"x": 0.1 * i, "y": 0.0}}, at=i * 15.0)
    fleet.run_until(600.0)
    return fleet


def test_ten_minutes_of_slots_and_deliveries_on_a_virtual_clock() -> None:
    fleet = run_morph(seed=3)
    got = fleet.published("gcv", "lsv/target_reference")
    assert len(got) >= 30  # one value per 15 s; a few frames are lost at sea
    times = [t for t, _ in got]
    assert times == sorted(times) and all(0 < t <= 600 for t in times)
    # TDMA: 5 nodes × 1.5 s slots → each node sends once per 7.5 s cycle
    assert all(abs(core.stats.frames_sent - 80) <= 1 for core in fleet.cores.values())
    ranges = [o for o in fleet.outputs if o.node == "gcv" and o.output.__class__.__name__
              == "Status" and o.output.topic.startswith("range/")]
    assert ranges, "DLBL ranges come from the frames"


def test_same_seed_same_run() -> None:
    a, b = run_morph(seed=5), run_morph(seed=5)
    assert [(t, p.value) for t, p in a.published("gcv")] == \
        [(t, p.value) for t, p in b.published("gcv")]


def test_a_stopped_node_goes_down_and_comes_back() -> None:
    fleet = FastFleet(load_mission(MISSIONS / "morph.yaml"), seed=1)
    fleet.run_until(60.0)
    assert fleet.cores["ssv"].link_states["gcv"].value == "up"
    fleet.stop("gcv")
    fleet.run_until(120.0)
    assert fleet.cores["ssv"].link_states["gcv"].value == "down"
    fleet.resume("gcv")
    fleet.run_until(140.0)
    assert fleet.cores["ssv"].link_states["gcv"].value == "up"
    assert not any(isinstance(o.output, Publish) for o in fleet.outputs if o.node == "gcv"
                   and 60.0 < o.time < 120.0)


def test_synthetic_values_are_valid_and_uniform_over_valid_codes() -> None:
    """Every input layout of every shipped mission gets values it encodes; a bounded float's
    codes are drawn evenly over its valid range only (no failed draws, no zero fallback)."""
    import random

    from bridge.cli.sim_fast import synthetic_value
    from bridge.codec import Layout

    rng = random.Random(1)
    for path in sorted(MISSIONS.glob("*.yaml")):
        for channel in load_mission(path).table.channels:
            for element in channel.elements:
                for _ in range(20):
                    element.layout.pack(synthetic_value(element.layout, rng))
    layout = Layout.from_fields([{"field": "x", "resolution": 0.1, "min": -500, "max": 500}])
    codes = [layout.pack(synthetic_value(layout, rng)) for _ in range(4000)]
    assert max(codes) <= 10000 and abs(sum(codes) / len(codes) - 5000) < 200
    assert codes.count(0) < 5


def test_receivers_sharing_a_frames_decoding_see_what_their_own_decoding_gives() -> None:
    import pytest

    from bridge.errors import FrameError
    from bridge.runtime.virtual_fleet import SharedDecoder

    shared = run_morph(seed=4, auth=False)  # authenticated frames are decoded by each core
    fleet = FastFleet(morph(auth=False), seed=4)
    for core in fleet.cores.values():
        del core.codec.decode  # back to each core's own FrameCodec.decode
    for i in range(40):
        fleet.put("lsv", "target_reference", {"vector": {"x": 0.1 * i, "y": 0.0}}, at=i * 15.0)
    fleet.run_until(600.0)
    assert [repr(t) for t in shared.outputs] == [repr(t) for t in fleet.outputs]
    decode = SharedDecoder(fleet.cores["gcv"].codec.decode)
    for _ in range(2):  # a refused frame is refused for every receiver, with its reason
        with pytest.raises(FrameError) as refused:
            decode(bytes(20), 3)
        assert refused.value.reason == "check"


REFUSED = """
mission: refused
mac: {type: none}
link: {heartbeat_s: 1000}  # b stays silent: a frame heard is news too
nodes:
  a: {address: 1}
  b: {address: 2}
channels:
  - name: x
    from: a
    to: b
    elements: [{in: x, out: a/x, fields: [{field: v, type: int, min: 0, max: 100}]}]
"""


def test_a_refused_frame_is_tried_again_after_a_pause_or_news_not_at_once() -> None:
    """Under mac: none a node whose frame the modem refused asked again at once: while the
    refusal lasted (a Goby heartbeat, which was empty, for ever) the virtual clock stood
    still, and a real node's transmit loop spun without yielding. Now the next try waits
    IDLE_S, or a new sample."""
    fleet = FastFleet(parse_mission(REFUSED, "refused.yaml"), seed=1)
    transmit, refused = fleet.ocean.transmit, []

    def busy_until_25(now: float, src: int, data: bytes, dest: int | None = None) -> float:
        if src == 1 and now < 25.5:
            refused.append(now)
            assert len(refused) < 1000, "asked again at once"
            raise TransmitRefused("busy", "the modem stays busy")
        return transmit(now, src, data, dest)

    fleet.ocean.transmit = busy_until_25  # type: ignore[method-assign]
    fleet.put("a", "x", {"v": 7}, at=5.0)
    fleet.put("a", "x", {"v": 8}, at=12.25)  # news: tried at once
    fleet.run_until(40.0)
    assert refused == [5.0 + i for i in range(8)] + [12.25 + i for i in range(14)]
    failed = [o for o in fleet.outputs if isinstance(o.output, SendFailed)]
    assert len(failed) == len(refused)
    sent = [o.time for o in fleet.outputs if isinstance(o.output, FrameSent)]
    assert sent[0] == 26.25 and [p.value for _, p in fleet.published("b", "a/x")] == [{"v": 8}]
