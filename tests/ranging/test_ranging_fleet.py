"""DLBL ranges and fixes from the frames the simulated MORPH fleet sends anyway."""

from __future__ import annotations

import math
import time

import yaml

from tests.conftest import MISSIONS, on_free_ports
from tests.harness import Inbox, outside_session, running_fleet

CLOCKS = {  # unsynchronised modem clocks: offset (s) and drift (ppm) per node
    "ssv": (0.0, 0.0), "gcv": (0.37, 25.0), "lsv": (-1.2, -30.0), "cv1": (2.5, 45.0),
    "cv2": (-0.8, -12.0),
}


def test_dlbl_ranges_and_position_over_the_simulated_ocean() -> None:
    data = yaml.safe_load((MISSIONS / "morph.yaml").read_text())
    data["mac"]["slot_s"], data["mac"]["guard_s"] = 0.8, 0.1  # a 4 s cycle keeps the test short
    for name, (offset, drift) in CLOCKS.items():
        data["nodes"][name]["modem"] = {"options": {"clock_offset_s": offset,
                                                    "clock_drift_ppm": drift}}
    loaded = on_free_ports(yaml.safe_dump(data), "morph-ranging.yaml")
    positions = {n: (p.x, p.y, p.depth) for n, node in loaded.mission.nodes.items()
                 if (p := node.position) is not None}
    with running_fleet(loaded):
        app = outside_session(loaded, "cv1")
        try:
            ranges, fixes = Inbox(), Inbox()
            app.declare_subscriber("@zab/morph/cv1/range/*", ranges)
            app.declare_subscriber("@zab/morph/cv1/position", fixes)
            got = {}
            # (four 4 s cycles quiet; a loaded machine loses late frames)
            deadline = time.time() + 45
            while time.time() < deadline and len(got) < 4:
                key, value, _ = ranges.get(timeout=deadline - time.time())
                got[key.rsplit("/", 1)[1]] = value
            assert set(got) == {"ssv", "gcv", "lsv", "cv2"}
            for peer, value in got.items():
                true = math.dist(positions["cv1"], positions[peer])
                assert value["method"] == "dlbl"
                assert abs(value["range_m"] - true) < 0.3, (peer, value, true)
                assert 1500 < value["sound_speed_mps"] < 1520  # UNESCO at 16 °C, 38 PSU
                assert {"range_m", "time", "travel_time_s", "sound_speed_mps"} <= set(value)
            _, fix, _ = fixes.get(timeout=30)
            while not fix["fix"]:  # "no fix" reports until ranges to both anchors are in
                assert fix["reason"] == "too_few_anchors" and set(fix["anchors"]) < {"ssv", "gcv"}
                _, fix, _ = fixes.get(timeout=30)
            assert math.dist((fix["x"], fix["y"]), positions["cv1"][:2]) < 1.0, fix
            assert set(fix["anchors"]) == {"ssv", "gcv"} and fix["sigma_m"] > 0
        finally:
            app.close()
