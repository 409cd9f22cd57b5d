"""``zab gui`` at a relay, in a real browser (issue 29): the links it is heard on drawn by
kind (acoustic to the surface, RF to ROV2), each peer's route, and the frames it carries.
Leaves a screenshot in ``artifacts/gui-relay.png``."""

from __future__ import annotations

import contextlib
import shutil
import threading
import time
from collections.abc import Iterator
from pathlib import Path

from tests.conftest import REPO, needs_browser, on_free_ports
from tests.gui.fleet import mission_text
from tests.gui.test_browser import WAIT_MS, gui_process, open_page
from tests.harness import outside_session, put, running_fleet

pytestmark = needs_browser

MISSION = """
mission: relaygui
wire: {auth: off}
links:
  acoustic:
    modem: {backend: sim, frame_bytes: 64, options: {preset: evologics-s2c-im, seed: 3}}
    mac: {type: tdma, slot_s: 1.0, guard_s: 0.2, order: [surface, rov1]}
    nodes: [surface, rov1]
    link: {degraded_after_s: 4, down_after_s: 8}
  rf:
    kind: rf
    modem: {backend: sim, frame_bytes: 64, options: {preset: s100-rf, seed: 4}}
    mac: {type: polled, master: rov1}
    nodes: [rov1, rov2]
    link: {degraded_after_s: 3, down_after_s: 6}
nodes:
  surface: {address: 1, role: surface, position: {x: 0, y: 0, depth: 0.5},
            routes: {rov2: rov1}}
  rov1: {address: 2, position: {x: 60, y: 20, depth: 8}, nav_key: nav}
  rov2: {address: 3, position: {x: 62, y: 21, depth: 8}, nav_key: nav,
         routes: {surface: rov1}}
channels:
  - name: nav
    from: rov2
    to: [rov1, surface]
    elements:
      - in: nav
        out: "{src}/nav"
        fields:
          - {field: x, resolution: 0.1, min: -500, max: 500}
          - {field: y, resolution: 0.1, min: -500, max: 500}
          - {field: depth, resolution: 0.1, min: 0, max: 100}
"""


@contextlib.contextmanager
def navigating(loaded, names: tuple[str, ...]) -> Iterator[None]:  # type: ignore[no-untyped-def]
    """An application on each of ``names`` publishing its navigation every half second."""
    sessions = {name: outside_session(loaded, name) for name in names}
    stop = threading.Event()

    def run() -> None:
        while not stop.wait(0.5):
            for name, session in sessions.items():
                p = loaded.mission.nodes[name].position
                put(session, "nav", {"x": p.x, "y": p.y, "depth": p.depth})

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join(5)
        for session in sessions.values():
            session.close()


def test_the_relays_page_draws_its_links_by_kind_routes_and_what_it_carries(
        tmp_path: Path) -> None:
    loaded = on_free_ports(MISSION, "relaygui.yaml")
    path = tmp_path / "relaygui.yaml"
    path.write_text(mission_text(MISSION, loaded))
    with contextlib.ExitStack() as stack:
        stack.enter_context(running_fleet(loaded))
        stack.enter_context(navigating(loaded, ("rov1", "rov2")))
        page, errors = open_page(stack, stack.enter_context(gui_process(path, "rov1")))
        page.wait_for_selector('#map .hop.acoustic[data-nodes="rov1 surface"]', timeout=WAIT_MS)
        page.wait_for_selector('#map .hop.rf[data-nodes="rov1 rov2"]', timeout=WAIT_MS)
        surface = '.vehicle-card[data-node="surface"] .route'
        page.wait_for_function("sel => document.querySelector(sel).textContent.includes("
                               "'route rov1 → surface over acoustic')", arg=surface,
                               timeout=WAIT_MS)
        relay = '.vehicle-card[data-node="rov1"] .route'
        page.wait_for_function("sel => /relay: [1-9]\\d* frames carried/.test("
                               "document.querySelector(sel).textContent)", arg=relay,
                               timeout=WAIT_MS)
        time.sleep(0.5)
        shot = tmp_path / "gui-relay.png"
        page.screenshot(path=str(shot), full_page=True)
        artifacts = REPO / "artifacts"
        artifacts.mkdir(exist_ok=True)
        shutil.copy(shot, artifacts / "gui-relay.png")
        assert errors == [], f"errors in the page: {errors}"
