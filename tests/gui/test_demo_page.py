"""The GUI as a newcomer first sees it: `zab demo` (the MORPH fleet) in headless Chromium.

Range-circle labels never overlap, the command form opens on the command channel, channel
names never wrap mid-word, and the surface card shows the mission's intervals. Leaves a
screenshot in ``artifacts/gui-demo.png``."""

from __future__ import annotations

import re
import subprocess
import sys
import threading
from collections.abc import Iterator
from typing import Any

import pytest

from tests.conftest import MISSIONS, REPO, mission_on_free_ports
from tests.gui.fleet import mission_text
from tests.gui.test_browser import CHROMIUM, CHROMIUM_ARGS, WAIT_MS

pytestmark = pytest.mark.skipif(not CHROMIUM.exists(),
                                reason="needs Debian's chromium (apt-get install chromium)")

# Every drawn range label and vehicle label, as boxes in the map's own units.
LABELS = """() => {
  const box = (e) => { const b = e.getBBox(); return [b.x, b.y, b.x + b.width, b.y + b.height]; };
  const svg = document.getElementById("map");
  const [, , width, height] = svg.getAttribute("viewBox").split(" ").map(Number);
  return { width, height,
           ranges: [...svg.querySelectorAll(".range text")].map((t) => [t.textContent, box(t)]),
           vehicles: [...svg.querySelectorAll(".vehicle text")].map(
             (t) => [t.textContent, box(t)]) };
}"""


@pytest.fixture(scope="module")
def page(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Any]:
    """`zab demo` on free ports with its GUI on any port; a page open on it."""
    from playwright.sync_api import sync_playwright

    path = tmp_path_factory.mktemp("demo-page") / "morph.yaml"
    path.write_text(mission_text((MISSIONS / "morph.yaml").read_text(),
                                 mission_on_free_ports(MISSIONS / "morph.yaml")))
    demo = subprocess.Popen(
        [sys.executable, "-m", "bridge", "demo", "--mission", str(path), "--no-live",
         "--duration", "120", "--gui-port", "0"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=path.parent)
    try:
        assert demo.stdout is not None
        lines = []
        for line in demo.stdout:
            lines.append(line)
            if found := re.search(r"(http://127\.0\.0\.1:\d+/)", line):
                break
        else:
            raise AssertionError("zab demo printed no GUI address:\n" + "".join(lines))
        threading.Thread(target=demo.stdout.read, daemon=True).start()  # keep it draining
        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=str(CHROMIUM),
                                                 args=CHROMIUM_ARGS)
            try:
                tab = browser.new_page(viewport={"width": 1280, "height": 900})
                errors: list[str] = []
                tab.on("pageerror", lambda exc: errors.append(str(exc)))
                tab.goto(found.group(1))
                yield tab
                artifacts = REPO / "artifacts"
                artifacts.mkdir(exist_ok=True)
                tab.screenshot(path=str(artifacts / "gui-demo.png"), full_page=True)
                assert errors == [], f"errors in the page: {errors}"
            finally:
                browser.close()
    finally:
        demo.terminate()
        try:
            demo.wait(30)
        except subprocess.TimeoutExpired:
            demo.kill()
            demo.wait(5)


def overlap(a: list[float], b: list[float]) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def test_range_labels_do_not_bunch_together(page: Any) -> None:
    page.wait_for_function("document.querySelectorAll('#map .range text').length >= 4",
                           timeout=WAIT_MS * 3)
    page.wait_for_timeout(1500)  # a few more renders, positions moving
    drawn = page.evaluate(LABELS)
    ranges = drawn["ranges"]
    assert len(ranges) >= 4
    for i, (text, box) in enumerate(ranges):
        assert re.fullmatch(r"\w+ \d+\.\d m", text)
        assert box[0] >= 0 and box[2] <= drawn["width"] and box[1] >= 0 \
            and box[3] <= drawn["height"], (text, box)
        for other, other_box in ranges[i + 1:]:
            assert not overlap(box, other_box), (text, other, box, other_box)
        for vehicle, vehicle_box in drawn["vehicles"]:
            assert not overlap(box, vehicle_box), (text, vehicle)


def test_the_command_form_opens_on_the_command_channel(page: Any) -> None:
    page.wait_for_selector("#command-channel option", state="attached", timeout=WAIT_MS)
    assert page.input_value("#command-channel") == "mission_command"
    paths = page.eval_on_selector_all("#command-fields [data-path]",
                                      "(es) => es.map((e) => e.dataset.path)")
    assert paths == ["action", "leg"]


def test_channel_names_do_not_wrap_mid_word(page: Any) -> None:
    cell = '.vehicle-card[data-node="ssv"] tr[data-channel="mission_command"] td.channel'
    page.wait_for_selector(cell, timeout=WAIT_MS)
    lines = page.eval_on_selector(cell, """(td) => {
      const range = document.createRange();
      range.setStartBefore(td.firstChild);
      range.setEndBefore(td.querySelector(".key"));
      return new Set([...range.getClientRects()].map((r) => Math.round(r.top))).size;
    }""")
    assert lines == 1
    assert page.inner_text(cell).splitlines()[0] == "mission_command"


def test_the_surface_card_shows_the_mission_intervals(page: Any) -> None:
    card = '.vehicle-card[data-node="ssv"]'
    row = f'{card} tr[data-channel="surface_fix"]'
    page.wait_for_selector(row, timeout=WAIT_MS)
    page.wait_for_function("(sel) => Number(document.querySelector(sel).dataset.count) > 2",
                           arg=row, timeout=WAIT_MS)  # published every second meanwhile
    assert page.inner_text(f"{row} .interval") == "5 s"
    row = f'{card} tr[data-channel="mission_command"]'  # once the tour's operator commands
    page.wait_for_selector(row, timeout=WAIT_MS * 3)
    assert page.inner_text(f"{row} .interval") == "20 s"
    # a vehicle across the water shows the time between arrivals, as before
    remote = '.vehicle-card[data-node="lsv"] tr[data-channel="nav"]'
    page.wait_for_function("(sel) => Number(document.querySelector(sel)?.dataset.count) > 1",
                           arg=remote, timeout=WAIT_MS * 2)
    assert page.inner_text(f"{remote} .interval").endswith(" s")
