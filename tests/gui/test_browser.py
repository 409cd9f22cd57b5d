"""``zab gui`` in a real browser (Debian's headless Chromium, driven by Playwright) against a
simulated fleet on loopback: vehicles appear, values and ages update, a command reaches the
vehicle's key, a stopped vehicle turns down. Leaves a screenshot in ``artifacts/gui.png``."""

from __future__ import annotations

import contextlib
import re
import shutil
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.conftest import CHROMIUM, REPO, needs_browser, on_free_ports
from tests.gui.fleet import MISSION, VehicleApps, mission_text
from tests.harness import Inbox, outside_session, running_fleet

CHROMIUM_ARGS = ["--no-sandbox", "--headless", "--disable-gpu",
                 "--disable-background-networking", "--disable-component-update",
                 "--disable-sync", "--no-first-run"]
WAIT_MS = 20_000  # an upper bound for things the fleet does within a few TDMA cycles

pytestmark = needs_browser

@contextlib.contextmanager
def gui_process(path: Path, node: str | None = None) -> Iterator[str]:
    """``zab gui MISSION --port 0`` (at ``node``: default the surface) in a subprocess;
    yields the page's URL."""
    process = subprocess.Popen(
        [sys.executable, "-m", "bridge", "gui", str(path), "--port", "0",
         *(("--node", node) if node else ())],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=REPO)
    assert process.stdout is not None
    drain = threading.Thread(target=process.stdout.read, daemon=True)  # (after the URL)
    try:
        lines = []
        for line in process.stdout:
            lines.append(line)
            found = re.search(r"(http://127\.0\.0\.1:\d+/)", line)
            if found:
                break
        else:
            raise AssertionError("zab gui printed no URL:\n" + "".join(lines))
        drain.start()
        yield found.group(1)
    finally:
        process.terminate()
        try:
            process.wait(10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(5)
        if drain.is_alive():
            drain.join(5)  # (the pipe ends with the process)
        process.stdout.close()


def open_page(stack: contextlib.ExitStack, url: str, height: int = 900
              ) -> tuple[Any, list[str]]:
    """Headless Chromium at ``url`` (closed with ``stack``; a viewport 1280 wide, ``height``
    tall), and the page's errors."""
    from playwright.sync_api import sync_playwright

    playwright = stack.enter_context(sync_playwright())
    browser = playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
    stack.callback(browser.close)
    page = browser.new_page(viewport={"width": 1280, "height": height})
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    page.goto(url)
    return page, errors


@pytest.fixture(scope="module")
def stage(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict]:
    """The fleet (auv2 in its own Fleet, so it can be stopped), apps, `zab gui`, a page."""
    loaded = on_free_ports(MISSION, "guitest.yaml")
    folder = tmp_path_factory.mktemp("gui")
    path = folder / "guitest.yaml"
    path.write_text(mission_text(MISSION, loaded))
    with contextlib.ExitStack() as stack:
        main = stack.enter_context(running_fleet(loaded, only=["ssv", "auv1"]))
        assert main.water is not None and main.water.port is not None
        auv2 = contextlib.ExitStack()
        stack.callback(auv2.close)
        auv2.enter_context(running_fleet(loaded, only=["auv2"],
                                         water=f"127.0.0.1:{main.water.port}"))
        stack.enter_context(VehicleApps(loaded))
        page, errors = open_page(stack, stack.enter_context(gui_process(path)))
        yield {"page": page, "loaded": loaded, "stop_auv2": auv2.close, "errors": errors,
               "folder": folder}
        shot = folder / "gui.png"
        page.screenshot(path=str(shot), full_page=True)
        artifacts = REPO / "artifacts"
        artifacts.mkdir(exist_ok=True)
        shutil.copy(shot, artifacts / "gui.png")
        print(f"GUI screenshot: {artifacts / 'gui.png'}")
        assert errors == [], f"errors in the page: {errors}"


def test_vehicles_appear_on_the_map(stage):
    page = stage["page"]
    for name in ("auv1", "auv2"):
        page.wait_for_selector(f'#map .vehicle[data-node="{name}"]', timeout=WAIT_MS)
    page.wait_for_selector('#map .track[data-node="auv1"]', timeout=WAIT_MS)
    assert page.is_visible('#map .vehicle[data-node="ssv"]')  # the surface, where it is moored
    page.wait_for_selector('#map .range[data-peer="auv1"]', timeout=WAIT_MS)  # DLBL range
    assert page.inner_text("#connection") == "connected to ssv"


def test_a_channel_value_and_its_age_update(stage):
    page = stage["page"]
    row = '.vehicle-card[data-node="auv1"] tr[data-channel="status"]'
    page.wait_for_selector(row, timeout=WAIT_MS)
    first_value = page.inner_text(f"{row} .value")
    first_count = int(page.get_attribute(row, "data-count"))
    assert first_value.startswith("battery ")
    age = page.inner_text(f"{row} .age")
    page.wait_for_function(
        "([sel, age]) => document.querySelector(sel + ' .age').textContent !== age",
        arg=[row, age], timeout=WAIT_MS)  # the age ticks by itself
    page.wait_for_function(
        "([sel, count]) => Number(document.querySelector(sel).dataset.count) > count",
        arg=[row, first_count], timeout=WAIT_MS)  # and a new value arrives
    assert page.inner_text(f"{row} .value") != first_value
    assert page.inner_text(f"{row} .interval").endswith(" s")


def test_a_command_from_the_page_reaches_the_vehicle_key(stage):
    page, loaded = stage["page"], stage["loaded"]
    auv1 = outside_session(loaded, "auv1")
    try:
        inbox = Inbox()
        auv1.declare_subscriber("ssv/command", inbox)
        page.wait_for_selector('#connection[data-state="up"]', timeout=WAIT_MS)
        page.select_option("#command-vehicle", "auv1")
        page.select_option("#command-channel", "command")
        page.select_option('#command-fields [data-path="action"]', "start")
        page.fill('#command-fields [data-path="leg"]', "99")
        page.click("#command-send")
        assert "63" in page.inner_text("#command-error")  # out of bounds: never sent
        page.fill('#command-fields [data-path="leg"]', "7")
        page.click("#command-send")
        page.wait_for_selector('#commands li[data-vehicle="auv1"]', timeout=WAIT_MS)
        key, value, _ = inbox.get(timeout=WAIT_MS / 1000)
        assert (key, value) == ("ssv/command", {"action": "start", "leg": 7})
        # best effort: no delivery report, so it shows "sent" after a few seconds
        page.wait_for_selector('#commands li[data-vehicle="auv1"][data-state="sent"]',
                               timeout=WAIT_MS)
        assert page.inner_text("#command-error") == ""
    finally:
        auv1.close()


def test_a_stopped_vehicle_turns_down(stage):
    page = stage["page"]
    card = '.vehicle-card[data-node="auv2"]'
    page.wait_for_selector(f'{card}[data-state="up"]', timeout=WAIT_MS)
    stage["stop_auv2"]()
    page.wait_for_selector(f'{card}[data-state="down"]', timeout=WAIT_MS)
    assert page.get_attribute('#map .vehicle[data-node="auv2"]', "data-state") == "down"
    assert page.get_attribute('.vehicle-card[data-node="auv1"]', "data-state") == "up"
    events = page.inner_text("#events")
    assert "link ssv ↔ auv2: down" in events
