"""``zab sim`` on a mission of real modems, with no water of the user's (``--water``) for
emulators: the modems are simulated ones with the same timings, and values cross, as a
plain Zenoh application sees them."""

from __future__ import annotations

import time
from pathlib import Path

import msgpack
import yaml

from bridge.cli.sim import simulate_real_modems
from tests.conftest import REPO
from tests.zsim import Inbox, app, mission_file, zab_sim

MISSIONS = REPO / "deploy" / "missions"


def test_real_backends_of_links_and_nodes_become_simulated() -> None:
    data = yaml.safe_load((MISSIONS / "morph_evologics.yaml").read_text())
    data["nodes"]["cv2"]["modem"]["backend"] = "micromodem"  # a node's own
    assert simulate_real_modems(data) == ["evologics", "micromodem"]
    assert data["modem"]["backend"] == "sim"
    assert data["nodes"]["cv2"]["modem"]["backend"] == "sim"
    assert data["modem"]["options"]["preset"] == "evologics-s2c-im"  # same timings
    assert "baud" not in data["modem"]["options"]  # the real modem's own: no sim option
    assert "device" not in data["nodes"]["ssv"]["modem"]["options"]
    assert simulate_real_modems(data) == []


def test_zab_sim_simulates_the_real_modems_and_values_cross(tmp_path: Path) -> None:
    path, endpoints = mission_file((MISSIONS / "morph_evologics.yaml").read_text(), tmp_path)
    with zab_sim(path, endpoints, timeout=90):
        surface, lsv = app(endpoints["ssv"]), app(endpoints["lsv"])
        inbox = Inbox()
        subscriber = surface.declare_subscriber("lsv/nav", inbox)
        try:
            got: list[tuple[str, object]] = []
            deadline = time.time() + 60  # a TDMA cycle is 7.5 s
            while not got and time.time() < deadline:
                lsv.put("nav", msgpack.packb({"x": 12.3, "y": -4.5, "depth": 10.0,
                                              "heading": 90, "speed": 1.0}))
                got = inbox.drain(2.0)
            assert got, "no navigation crossed: were the EvoLogics modems simulated?"
            assert got[-1][1]["x"] == 12.3
        finally:
            subscriber.undeclare()
            surface.close()
            lsv.close()
