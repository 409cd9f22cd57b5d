"""``zab gui`` in a real browser on the zspace mission run by a real ``zab sim``: the surface's
card says which channels its applications want; a vehicle that surfaces is shown as reached
over IP, and goes back when it dives."""

from __future__ import annotations

import contextlib
from pathlib import Path

import yaml

from bridge.runtime.surface_wifi import access_point
from tests.conftest import MISSIONS, needs_browser
from tests.gui.test_browser import WAIT_MS, gui_process, open_page
from tests.zsim import app as plain_app
from tests.zsim import mission_file, zab_sim

pytestmark = needs_browser


def test_wants_and_surfacing_show_on_the_page(tmp_path: Path) -> None:

    data = yaml.safe_load((MISSIONS / "zspace.yaml").read_text())
    for name in ("top", "auv1"):
        data["nodes"][name]["zenoh"] = {"mode": "router", "scouting/gossip/enabled": False,
                                        "scouting/delay": 0}
    mission, endpoints = mission_file(yaml.safe_dump(data, sort_keys=False), tmp_path)
    with contextlib.ExitStack() as stack:
        stack.enter_context(zab_sim(mission, endpoints))
        top = plain_app(endpoints["top"])
        stack.callback(top.close)
        top.declare_subscriber("auv1/status", lambda s: None)
        page, errors = open_page(stack, stack.enter_context(gui_process(mission)))
        own = '.vehicle-card[data-node="top"] .zspace'
        page.wait_for_function(f"document.querySelector('{own}')?.textContent"
                               ".includes('wants:')", timeout=WAIT_MS)
        assert "status" in page.inner_text(own)
        wifi = access_point(endpoints["top"] + endpoints["auv1"])
        try:
            page.wait_for_selector('.vehicle-card[data-node="auv1"] .zspace',
                                   timeout=WAIT_MS)
            assert "surfaced" in page.inner_text('.vehicle-card[data-node="auv1"] .zspace')
        finally:
            wifi.close()
        page.wait_for_selector('.vehicle-card[data-node="auv1"] .zspace', state="detached",
                               timeout=WAIT_MS)
        assert errors == []
