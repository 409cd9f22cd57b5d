"""The tracker's fixes in the GUI: the model keeps their state, age and ellipse (and a lost
track's reason), and the page draws the 95 % ellipse and the state (Debian's headless
Chromium, driven by Playwright, for the drawing)."""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import TYPE_CHECKING

import msgpack
import pytest

from bridge.core.loaded import LoadedMission, load_mission
from bridge.gui.model import GuiModel
from bridge.ranging.tracker import Estimate
from tests.conftest import MISSIONS, needs_browser
from tests.gui.test_map_view import browser_and_url, open_page

if TYPE_CHECKING:
    from playwright.sync_api import Browser, Page

__all__ = ["browser_and_url"]  # the fleet, its apps, `zab gui` and Chromium (module scope)
MSGPACK = "application/msgpack"
K95 = math.sqrt(5.991)


@pytest.fixture(scope="module")
def morph() -> LoadedMission:
    return load_mission(MISSIONS / "morph.yaml")


def tracked(state: str = "tracking", age: float = 0.4) -> Estimate:
    return Estimate(state, 50.0, 1.0, 60.0, 10.0, 0.1, 0.8, ((4.0, 1.0), (1.0, 1.0)), age,
                    anchors=("gcv", "ssv"), ranges={"gcv": 36.1, "ssv": 60.8})


def test_model_keeps_state_age_and_ellipse_and_a_lost_reason(morph: LoadedMission) -> None:
    model = GuiModel(morph, "ssv")
    model.ingest("@zab/morph/lsv/position", msgpack.packb(tracked().payload()), MSGPACK, 8.0)
    (item,) = [i for i in model.take() if i["kind"] == "position"]
    major, minor, angle = tracked().ellipse()
    assert item["state"] == "tracking" and item["age_s"] == 0.4 and item["source"] == "fix"
    assert item["ellipse"] == {"major_m": major, "minor_m": minor, "angle_deg": angle}
    lost = Estimate("lost", 60.0, reason="no_ranges", anchors=("ssv",)).payload()
    model.ingest("@zab/morph/lsv/position", msgpack.packb(lost), MSGPACK, 9.0)
    assert model.take() == [{"kind": "lost", "node": "lsv", "reason": "no_ranges", "time": 9.0}]
    assert {"kind": "lost", "node": "lsv", "reason": "no_ranges", "time": 9.0} in \
        model.snapshot()
    model.ingest("@zab/morph/lsv/position", msgpack.packb(tracked("coasting", 7.0).payload()),
                 MSGPACK, 10.0)
    (again,) = model.take()
    assert again["state"] == "coasting" and again["age_s"] == 7.0
    assert all(i["kind"] != "lost" for i in model.snapshot())  # a fix since: not lost any more
    broken = {**tracked().payload(), "ellipse": {"major_m": "wide"}}
    model.ingest("@zab/morph/cv1/position", msgpack.packb(broken), MSGPACK, 11.0)
    (odd,) = model.take()
    assert "ellipse" not in odd and odd["x"] == 1.0  # drawn without it, not refused


@pytest.fixture(scope="module")
def page(browser_and_url: tuple[Browser, str]) -> Iterator[Page]:
    yield from open_page(*browser_and_url)


def show(page: Page, item: dict) -> None:
    page.evaluate("(item) => { item.time = serverNow() - (item.ago || 0); apply(item); "
                  "mapDirty = true; }", item)


def drawn(page: Page) -> dict:
    page.wait_for_timeout(300)  # a frame or two
    return page.evaluate("""() => {
      const g = document.querySelector('#map g.fix[data-node="auv1"]');
      if (!g) return null;
      const e = g.querySelector("ellipse");
      const bar = document.querySelector("#map .scale line");
      const step = parseFloat(document.querySelector("#map .scale text").textContent);
      return { state: g.dataset.state, text: (g.querySelector(".fix-state") || {}).textContent,
               rx: e && e.rx.baseVal.value, ry: e && e.ry.baseVal.value,
               transform: e && e.getAttribute("transform"),
               scale: (bar.x2.baseVal.value - bar.x1.baseVal.value) / step };
    }""")


@needs_browser
def test_the_page_draws_the_ellipse_and_the_state(page: Page) -> None:
    fix = {"kind": "position", "node": "auv1", "source": "fix", "x": 40.0, "y": 30.0,
           "depth": 8.0, "sigma_m": 2.06, "state": "tracking", "age_s": 0.3,
           "ellipse": {"major_m": 2.0, "minor_m": 0.5, "angle_deg": 30.0}}
    show(page, fix)
    got = drawn(page)
    assert got["state"] == "tracking" and got["text"] is None
    assert got["rx"] == pytest.approx(max(2.0, K95 * 2.0 * got["scale"]), rel=0.02)
    assert got["rx"] / got["ry"] == pytest.approx(4.0, rel=0.05) or got["ry"] == 2.0
    assert got["transform"].startswith("rotate(-30.0 ")  # anticlockwise from east, on screen
    show(page, {**fix, "state": "coasting", "age_s": 12.0})
    got = drawn(page)
    assert got["state"] == "coasting" and got["text"].startswith("coasting 12")
    show(page, {"kind": "lost", "node": "auv1", "reason": "no_ranges", "ago": -1.0})
    got = drawn(page)
    assert got["state"] == "lost" and got["text"] == "lost: no ranges" and got["rx"] is None


@needs_browser
def test_a_peer_never_heard_is_not_heard_yet_not_down(page: Page) -> None:
    """At the start of a mission a link is 'down' until the peer's first frame: that is no
    fault, so the page shows it grey ('not heard yet'), and red only once it was heard."""
    states = page.evaluate("""() => {
      const v = vehicle("ghost"), key = state.mission.node + "/ghost";
      state.links[key] = { state: "down" };
      const before = linkState("ghost");
      v.heard = serverNow();
      const after = linkState("ghost");
      delete state.links[key]; delete state.nodes.ghost;
      return [before, after];
    }""")
    assert states == ["unknown", "down"]
