"""The GUI's pictures in a real browser (Debian's headless Chromium, Playwright) against a real
``zab sim``: a JPEG put on the ROV appears at the surface and refines, bytes against the
budget; an ROI drawn with the mouse goes to the camera and comes back on the next picture, and
so does a size typed in.
Leaves a screenshot in ``artifacts/gui-images.png``."""

from __future__ import annotations

import contextlib
import shutil
from pathlib import Path

import pytest
import zenoh

from bridge.image.formats import write_image
from bridge.image.synthetic import seabed
from tests.conftest import MISSIONS, REPO
from tests.gui.test_browser import CHROMIUM, CHROMIUM_ARGS, WAIT_MS, gui_process
from tests.zsim import app, mission_file, zab_sim

pytestmark = pytest.mark.skipif(not CHROMIUM.exists(),
                                reason="needs Debian's chromium (apt-get install chromium)")

FIGURE = 'figure.picture[data-channel="camera"][data-node="rov"]'


def test_a_picture_refines_and_the_roi_drawn_comes_back(tmp_path: Path) -> None:
    from playwright.sync_api import sync_playwright

    text = (MISSIONS / "bluerov_images.yaml").read_text().replace(
        "budget_bytes: 1600", "budget_bytes: 400").replace(
        "publish_interval_s: 1.0", "publish_interval_s: 0.0")
    mission, endpoints = mission_file(text, tmp_path)
    jpeg = write_image(seabed(240, 320, seed=7), "jpeg", quality=90)
    with contextlib.ExitStack() as stack:
        stack.enter_context(zab_sim(mission, endpoints))
        rov = app(endpoints["rov"])
        stack.callback(rov.close)
        url = stack.enter_context(gui_process(mission))
        playwright = stack.enter_context(sync_playwright())
        browser = playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        stack.callback(browser.close)
        page = browser.new_page(viewport={"width": 1280, "height": 1000})
        errors: list[str] = []
        page.on("pageerror", lambda exc: errors.append(str(exc)))
        page.goto(url)
        page.wait_for_selector(FIGURE, timeout=WAIT_MS)
        page.wait_for_selector('#connection[data-state="up"]', timeout=WAIT_MS)
        # before any picture: nothing of the budget is filled, and the budget box says bytes
        assert page.evaluate(f"document.querySelector('{FIGURE} .picture-bytes span')"
                             ".getBoundingClientRect().width") == 0
        assert page.inner_text(f"{FIGURE} .unit") == "B"
        rov.put("rov/camera", jpeg, encoding=zenoh.Encoding("image/jpeg"))
        page.wait_for_function(f"Number(document.querySelector('{FIGURE}').dataset.bytes) > 0",
                               timeout=WAIT_MS)
        first = int(page.get_attribute(FIGURE, "data-bytes") or 0)
        page.wait_for_function(
            f"document.querySelector('{FIGURE}').dataset.final === 'true'", timeout=WAIT_MS)
        assert int(page.get_attribute(FIGURE, "data-bytes") or 0) > first  # it refined
        assert " / " in page.inner_text(f"{FIGURE} figcaption")
        assert page.evaluate(f"document.querySelector('{FIGURE} .picture-bytes span')"
                             ".getBoundingClientRect().width") > 0
        page.wait_for_function(f"document.querySelector('{FIGURE} img').naturalWidth > 0",
                               timeout=WAIT_MS)

        page.locator(f"{FIGURE} img").scroll_into_view_if_needed()
        box = page.locator(f"{FIGURE} img").bounding_box()
        assert box is not None
        page.mouse.move(box["x"] + 0.5 * box["width"], box["y"] + 0.25 * box["height"])
        page.mouse.down()
        page.mouse.move(box["x"] + 0.9 * box["width"], box["y"] + 0.75 * box["height"],
                        steps=5)
        page.mouse.up()
        page.click(f"{FIGURE} button:has-text('Request now')")
        page.wait_for_function(
            f"(document.querySelector('{FIGURE}').dataset.roi || '').startsWith('0.5')",
            timeout=3 * WAIT_MS)
        x0, y0, x1, y1 = (float(v) for v in (page.get_attribute(FIGURE, "data-roi") or
                                              "").split(","))
        assert abs(x0 - 0.5) < 0.02 and abs(y0 - 0.25) < 0.02
        assert abs(x1 - 0.9) < 0.02 and abs(y1 - 0.75) < 0.02
        assert page.is_visible(f"{FIGURE} .roi")

        page.fill(f"{FIGURE} input.width", "80")
        page.fill(f"{FIGURE} input.height", "60")
        page.click(f"{FIGURE} button:has-text('Apply')")
        page.click(f"{FIGURE} button:has-text('Request now')")
        page.wait_for_function(
            f"document.querySelector('{FIGURE}').dataset.size === '80x60'", timeout=3 * WAIT_MS)
        shot = tmp_path / "gui-images.png"
        page.screenshot(path=str(shot), full_page=True)
        artifacts = REPO / "artifacts"
        artifacts.mkdir(exist_ok=True)
        shutil.copy(shot, artifacts / "gui-images.png")
        assert errors == [], f"errors in the page: {errors}"
