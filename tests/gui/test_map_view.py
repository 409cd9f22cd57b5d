"""Pan and zoom of the GUI's map in a real browser (Debian's headless Chromium, driven by
Playwright) against a simulated fleet on loopback, with mouse, keyboard and touch input.

Every check reads geometry drawn by the page: the screen positions of the vehicle markers, the
scale bar's length and label (pixels per metre), the grid, and the bounding box of what the
automatic fit must hold. The surface vehicle sits still at its mission position, so it is the
fixed world point the checks follow; the others keep moving."""

from __future__ import annotations

import contextlib
import itertools
import math
import time
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

import pytest

from tests.conftest import CHROMIUM, needs_browser, on_free_ports
from tests.gui.fleet import MISSION, VehicleApps, mission_text
from tests.gui.test_browser import CHROMIUM_ARGS, WAIT_MS, gui_process
from tests.harness import running_fleet

if TYPE_CHECKING:
    from playwright.sync_api import Browser, CDPSession, Page

pytestmark = needs_browser

PAD = 36  # the automatic fit's margin in app.js
MIN_SPAN_M, MAX_SPAN_M = 5, 200000  # mapview.js's zoom range, across the map's short side

# window.mapGeometry(): what the last render drew. Screen positions are client pixels (where
# the mouse is); "fit" is in the SVG's own units (its viewBox is the map's size in pixels).
GEOMETRY = """
window.mapGeometry = () => {
  const svg = document.getElementById("map");
  const box = svg.getBoundingClientRect();
  const [, , width, height] = svg.getAttribute("viewBox").split(" ").map(Number);
  const bar = svg.querySelector(".scale line");
  const step = bar ? parseFloat(svg.querySelector(".scale text").textContent) : null;
  const scale = bar ? (bar.x2.baseVal.value - bar.x1.baseVal.value) / step : null;
  const markers = {};
  for (const g of svg.querySelectorAll(".vehicle")) {
    const r = g.querySelector("circle, rect").getBoundingClientRect();
    const title = g.querySelector("title").textContent;
    const m = title.match(/x (-?[0-9.]+) m, y (-?[0-9.]+) m/);
    markers[g.dataset.node] = { x: r.left + r.width / 2, y: r.top + r.height / 2,
                                wx: Number(m[1]), wy: Number(m[2]), title };
  }
  const grid = [...svg.querySelectorAll(".grid line")]
    .filter((l) => l.x1.baseVal.value === l.x2.baseVal.value)
    .map((l) => l.x1.baseVal.value);
  // what the automatic fit holds: vehicles and fixes (their centres), tracks, range circles
  const boxes = [...svg.querySelectorAll(".track, .range circle")].map((e) => e.getBBox());
  for (const e of svg.querySelectorAll(".vehicle circle, .vehicle rect, .fix path")) {
    const b = e.getBBox();
    boxes.push({ x: b.x + b.width / 2, y: b.y + b.height / 2, width: 0, height: 0 });
  }
  const fit = boxes.length ? {
    x0: Math.min(...boxes.map((b) => b.x)), y0: Math.min(...boxes.map((b) => b.y)),
    x1: Math.max(...boxes.map((b) => b.x + b.width)),
    y1: Math.max(...boxes.map((b) => b.y + b.height)) } : null;
  return { view: svg.dataset.view, left: box.left, top: box.top, right: box.right,
           bottom: box.bottom, width, height, step, scale, markers, grid, fit,
           fitDisabled: document.getElementById("map-fit").disabled };
};
"""


@pytest.fixture(scope="module")
def browser_and_url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Browser, str]]:
    """The whole fleet, its applications, ``zab gui`` and a headless Chromium."""
    from playwright.sync_api import sync_playwright

    loaded = on_free_ports(MISSION, "guitest.yaml")
    path = tmp_path_factory.mktemp("gui-map") / "guitest.yaml"
    path.write_text(mission_text(MISSION, loaded))
    with contextlib.ExitStack() as stack:
        stack.enter_context(running_fleet(loaded))
        stack.enter_context(VehicleApps(loaded))
        url = stack.enter_context(gui_process(path))
        playwright = stack.enter_context(sync_playwright())
        browser = playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        stack.callback(browser.close)
        yield browser, url


def open_page(browser: Browser, url: str, **context_options: Any) -> Iterator[Page]:
    """A page of the GUI in a fresh browser context, once every vehicle is on the map."""
    context = browser.new_context(viewport={"width": 1280, "height": 900}, **context_options)
    try:
        page = context.new_page()
        errors: list[str] = []
        page.on("pageerror", lambda exc: errors.append(str(exc)))
        page.add_init_script(script=GEOMETRY)
        page.goto(url)
        for name in ("ssv", "auv1", "auv2"):
            page.wait_for_selector(f'#map .vehicle[data-node="{name}"]', timeout=WAIT_MS)
        page.wait_for_selector("#map .scale line", state="attached", timeout=WAIT_MS)
        yield page
        assert errors == [], f"errors in the page: {errors}"
    finally:
        context.close()


@pytest.fixture(scope="module")
def page(browser_and_url: tuple[Browser, str]) -> Iterator[Page]:
    yield from open_page(*browser_and_url)


@pytest.fixture
def touch_page(browser_and_url: tuple[Browser, str]) -> Iterator[Page]:
    yield from open_page(*browser_and_url, has_touch=True)


def geometry(page: Page) -> dict:
    return page.evaluate("mapGeometry()")


def wait_for(page: Page, condition: str, arg: Any = None) -> dict:
    """The geometry once ``condition`` (a JS expression of ``g``, the geometry, and ``arg``)
    holds after a render."""
    page.wait_for_function(f"(arg) => {{ const g = mapGeometry(); return {condition}; }}",
                           arg=arg, timeout=WAIT_MS)
    return geometry(page)


def frozen(page: Page) -> dict:
    """Leave the automatic fit (the + button: zoom in about the centre) so that the view no
    longer changes by itself; the geometry of that view."""
    if page.get_attribute("#map", "data-view") == "user":
        page.click("#map-fit")
        wait_for(page, 'g.view === "auto"')
    page.click("#map-zoom-in")
    return wait_for(page, 'g.view === "user"')


def ssv(g: dict) -> tuple[float, float]:
    """The surface vehicle's marker on the screen: it is moored, still at its mission position."""
    marker = g["markers"]["ssv"]
    assert marker["title"].endswith("(mission position)")
    return marker["x"], marker["y"]


def assert_near(actual: tuple[float, float], expected: tuple[float, float], px: float) -> None:
    assert math.dist(actual, expected) <= px, f"{actual} is not within {px} px of {expected}"


def zoomed_about(point: tuple[float, float], before: tuple[float, float],
                 factor: float) -> tuple[float, float]:
    """Where a screen point ``before`` goes when the map zooms by ``factor`` about ``point``."""
    return (point[0] + (before[0] - point[0]) * factor,
            point[1] + (before[1] - point[1]) * factor)


def assert_scale_bar_is_true(g: dict, markers: bool = True) -> None:
    """The scale bar's pixels per metre match the grid's spacing and (when they are far enough
    apart to measure) the markers' spacing."""
    if markers:
        a, b = g["markers"]["ssv"], g["markers"]["auv1"]
        metres = math.dist((a["wx"], a["wy"]), (b["wx"], b["wy"]))
        pixels = math.dist((a["x"], a["y"]), (b["x"], b["y"]))
        assert pixels / metres == pytest.approx(g["scale"], rel=0.01)
    grid = sorted(g["grid"])
    assert len(grid) >= 2
    for left, right in itertools.pairwise(grid):
        assert right - left == pytest.approx(g["step"] * g["scale"], rel=1e-6)


def assert_fits_everything(g: dict) -> None:
    """Everything the fit holds is inside the margins, and fills them along one axis."""
    fit, width, height = g["fit"], g["width"], g["height"]
    assert fit["x0"] >= PAD - 1 and fit["x1"] <= width - PAD + 1, (fit, width)
    assert fit["y0"] >= PAD - 1 and fit["y1"] <= height - PAD + 1, (fit, height)
    assert (fit["x1"] - fit["x0"] >= width - 2 * PAD - 2
            or fit["y1"] - fit["y0"] >= height - 2 * PAD - 2), (fit, width, height)


def test_the_map_starts_on_the_automatic_fit_of_everything(page: Page) -> None:
    g = geometry(page)
    assert g["view"] == "auto" and g["fitDisabled"]
    assert_fits_everything(g)
    assert_scale_bar_is_true(g)


def test_the_wheel_zooms_about_the_cursor(page: Page) -> None:
    g0 = frozen(page)
    # whole pixels: a wheel event's clientX and clientY are integers
    cursor = (round(g0["left"] + 0.25 * (g0["right"] - g0["left"])),
              round(g0["top"] + 0.3 * (g0["bottom"] - g0["top"])))
    page.mouse.move(*cursor)
    page.mouse.wheel(0, -400)  # one notch or more, toward the screen: in
    g1 = wait_for(page, "g.scale > arg * 1.2", g0["scale"])
    factor = g1["scale"] / g0["scale"]
    # the world point under the cursor stays under it: every point moves away from the cursor
    assert_near(ssv(g1), zoomed_about(cursor, ssv(g0), factor), 1.0)
    assert_scale_bar_is_true(g1)

    page.mouse.wheel(0, 400)  # and back out
    g2 = wait_for(page, "g.scale < arg * 0.9", g1["scale"])
    assert_near(ssv(g2), zoomed_about(cursor, ssv(g1), g2["scale"] / g1["scale"]), 1.0)
    assert g2["scale"] == pytest.approx(g0["scale"], rel=1e-6)
    assert_near(ssv(g2), ssv(g0), 1.0)


def test_a_drag_pans_the_view(page: Page) -> None:
    g0 = frozen(page)
    start = (g0["left"] + 300, g0["top"] + 200)
    page.mouse.move(*start)
    page.mouse.down()
    page.mouse.move(start[0] + 120, start[1] - 70, steps=6)
    page.mouse.up()
    x0, y0 = ssv(g0)
    g1 = wait_for(page, 'Math.abs(g.markers.ssv.x - arg[0]) > 100', [x0, y0])
    assert g1["scale"] == g0["scale"] and g1["view"] == "user"
    assert_near(ssv(g1), (x0 + 120, y0 - 70), 1.0)
    assert_scale_bar_is_true(g1)


def test_new_positions_do_not_move_the_users_view(page: Page) -> None:
    g0 = frozen(page)
    auv1 = g0["markers"]["auv1"]
    moved = "g.markers.auv1.wx !== arg[0] || g.markers.auv1.wy !== arg[1]"
    # a new position of auv1 arrives and is drawn, then another
    g1 = wait_for(page, moved, [auv1["wx"], auv1["wy"]])
    g2 = wait_for(page, moved, [g1["markers"]["auv1"]["wx"], g1["markers"]["auv1"]["wy"]])
    for g in (g1, g2):
        assert g["view"] == "user" and g["scale"] == g0["scale"]
        assert_near(ssv(g), ssv(g0), 0.01)
        moved = g["markers"]["auv1"]
        # drawn where it is, on the user's unchanged map (titles round to 0.1 m)
        expected = (auv1["x"] + (moved["wx"] - auv1["wx"]) * g0["scale"],
                    auv1["y"] - (moved["wy"] - auv1["wy"]) * g0["scale"])
        assert_near((moved["x"], moved["y"]), expected, 0.15 * g0["scale"] + 1)
        assert (moved["wx"], moved["wy"]) != (auv1["wx"], auv1["wy"])


def test_fit_returns_to_the_automatic_fit(page: Page) -> None:
    g0 = frozen(page)
    assert not g0["fitDisabled"]
    # zoom far into a corner, away from every vehicle
    corner = (g0["left"] + 20, g0["top"] + 20)
    page.mouse.move(*corner)
    for _ in range(4):
        page.mouse.wheel(0, -500)
    g1 = wait_for(page, "g.scale > arg * 10", g0["scale"])
    inside = [name for name, m in g1["markers"].items()
              if g1["left"] <= m["x"] <= g1["right"] and g1["top"] <= m["y"] <= g1["bottom"]]
    assert inside == []
    page.click("#map-fit")
    g2 = wait_for(page, 'g.view === "auto"')
    assert g2["fitDisabled"]
    assert_fits_everything(g2)
    assert_scale_bar_is_true(g2)


def test_keys_and_double_click(page: Page) -> None:
    g0 = frozen(page)
    page.focus("#map")
    page.keyboard.press("-")
    g1 = wait_for(page, "g.scale < arg * 0.9", g0["scale"])
    centre = ((g0["left"] + g0["right"]) / 2, (g0["top"] + g0["bottom"]) / 2)
    assert g1["scale"] == pytest.approx(g0["scale"] / 1.5, rel=1e-6)
    assert_near(ssv(g1), zoomed_about(centre, ssv(g0), 1 / 1.5), 1.0)
    page.keyboard.press("ArrowLeft")  # the map moves right, as if dragged right
    g2 = wait_for(page, "g.markers.ssv.x > arg + 10", ssv(g1)[0])
    assert_near(ssv(g2), (ssv(g1)[0] + 60, ssv(g1)[1]), 1.0)
    page.keyboard.press("0")
    g3 = wait_for(page, 'g.view === "auto"')
    assert_fits_everything(g3)
    page.keyboard.type("+")
    g4 = wait_for(page, 'g.view === "user"')
    page.dblclick("#map", position={"x": 200, "y": 150})
    g5 = wait_for(page, 'g.view === "auto"')
    assert g4["scale"] > g5["scale"]
    assert_fits_everything(g5)


def test_the_zoom_range_is_bounded(page: Page) -> None:
    g0 = frozen(page)
    short = min(g0["width"], g0["height"])
    page.mouse.move((g0["left"] + g0["right"]) / 2, (g0["top"] + g0["bottom"]) / 2)
    for _ in range(12):
        page.mouse.wheel(0, -1000)
    g1 = wait_for(page, "Math.abs(arg / g.scale - 5) < 1e-6", short)
    assert short / g1["scale"] == pytest.approx(MIN_SPAN_M)
    for _ in range(24):
        page.mouse.wheel(0, 1000)
    g2 = wait_for(page, "Math.abs(arg / g.scale - 200000) < 1e-3", short)
    assert short / g2["scale"] == pytest.approx(MAX_SPAN_M)
    assert_scale_bar_is_true(g2, markers=False)  # the fleet is a fraction of a pixel wide


def touch(cdp: CDPSession, kind: str, *points: tuple[float, float],
          at: float | None = None) -> None:
    """One touch event through the DevTools protocol, as a touch screen would send it (at
    time ``at``, in seconds since the epoch, if given)."""
    fingers = [{"x": x, "y": y, "id": i} for i, (x, y) in enumerate(points)]
    event = {"type": kind, "touchPoints": fingers}
    if at is not None:
        event["timestamp"] = at
    cdp.send("Input.dispatchTouchEvent", event)


def test_touch_drag_pinch_and_double_tap(touch_page: Page) -> None:
    page = touch_page
    cdp = page.context.new_cdp_session(page)
    page.tap("#map-zoom-in")
    g0 = wait_for(page, 'g.view === "user"')
    # one finger drags the map
    x, y = g0["left"] + 300, g0["top"] + 250
    touch(cdp, "touchStart", (x, y))
    for i in range(1, 7):
        touch(cdp, "touchMove", (x - 15 * i, y + 10 * i))
    touch(cdp, "touchEnd")
    g1 = wait_for(page, "g.markers.ssv.x < arg - 60", ssv(g0)[0])
    assert g1["scale"] == g0["scale"]
    assert_near(ssv(g1), (ssv(g0)[0] - 90, ssv(g0)[1] + 60), 1.0)

    # two fingers spread from 80 to 200 px apart about (mx, my): zoom by 2.5 about there
    mx, my = g1["left"] + 400, g1["top"] + 200
    touch(cdp, "touchStart", (mx - 40, my), (mx + 40, my))
    for i in range(1, 7):
        touch(cdp, "touchMove", (mx - 40 - 10 * i, my), (mx + 40 + 10 * i, my))
    touch(cdp, "touchEnd")
    g2 = wait_for(page, "g.scale > arg * 2", g1["scale"])
    assert g2["scale"] / g1["scale"] == pytest.approx(2.5, rel=0.01)
    assert_near(ssv(g2), zoomed_about((mx, my), ssv(g1), 2.5), 1.5)
    assert_scale_bar_is_true(g2)

    # a double tap returns to the automatic fit (time-stamped 0.1 s apart: a loaded machine
    # may take longer to send them)
    t = time.time()
    for start in (t, t + 0.1):
        touch(cdp, "touchStart", (mx, my), at=start)
        touch(cdp, "touchEnd", at=start + 0.05)
    g3 = wait_for(page, 'g.view === "auto"')
    assert_fits_everything(g3)
    cdp.detach()
