"""The mission report: `zab sim --report X.html` writes one page whose plots load offline."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml

from bridge.core.events import FrameReceived, FrameSent, Position, Range
from bridge.ranging.localise import Fix, NoFix
from bridge.report.html import channel_bounds
from bridge.report.recorder import MissionRecorder, age_series
from tests.conftest import CHROMIUM, MISSIONS, free_port, mission_on_free_ports, needs_browser
from tests.gui.test_browser import CHROMIUM_ARGS

LONG = True  # zab sim runs, one in real time, and Chromium: handed out first
PLOTS = ["tracks", "age", "slots", "losses", "ranges"]


def zab(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "bridge", *args], capture_output=True,
                          text=True, timeout=240)


def morph_on_free_ports(folder: Path, **options: Any) -> Path:
    data = yaml.safe_load((MISSIONS / "morph.yaml").read_text())
    for node in data["nodes"].values():
        node["zenoh"]["listen"] = [f"tcp/127.0.0.1:{free_port()}"]
    data["modem"]["options"].update(options)
    path = folder / "morph.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def open_offline(path: Path) -> dict[str, Any]:
    """Load ``path`` in headless Chromium with every non-file request refused; what drew."""
    from playwright.sync_api import sync_playwright

    asked: list[str] = []
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={"width": 1200, "height": 900})
            errors: list[str] = []
            page.on("pageerror", lambda exc: errors.append(str(exc)))
            page.route("**/*", lambda route: route.continue_()
                       if route.request.url.startswith("file:")
                       else (asked.append(route.request.url), route.abort()))
            page.goto(path.as_uri())
            page.wait_for_function("document.querySelectorAll('.js-plotly-plot .main-svg')"
                                   ".length >= 5", timeout=30_000)
            drawn = page.evaluate("""() => Object.fromEntries(
              [...document.querySelectorAll("section.plot")].map((s) => {
                const plot = s.querySelector(".js-plotly-plot");
                return [s.dataset.plot, {
                  traces: plot.data.length,
                  points: plot.data.reduce((n, t) => n + (t.x ? t.x.length : 0), 0),
                  title: plot.layout.title.text,
                  svg: plot.querySelectorAll(".main-svg").length,
                  annotations: (plot.layout.annotations || []).map((a) => a.text),
                  legend: plot.layout.showlegend,
                  names: plot.data.map((t) => t.name),
                  colours: plot.data.map((t) => t.marker && t.marker.color),
                  caption: s.querySelector("p.caption")?.textContent || null,
                  scroll: s.querySelector(".legend .scrollbar")?.getBBox().height || 0}];
              }))""")
            return {"plots": drawn, "asked": asked, "errors": errors,
                    "text": page.inner_text("body")}
        finally:
            browser.close()


def test_age_series_is_a_sawtooth() -> None:
    times, ages = age_series([1.0, 3.0, 4.0], 6.0)
    assert list(zip(times, ages, strict=True)) == [
        (1.0, 0.0), (1.0, 0.0), (3.0, 2.0), (3.0, 0.0), (3.0, 0.0), (4.0, 1.0),
        (4.0, 0.0), (4.0, 0.0), (6.0, 2.0)]


def test_a_long_age_series_keeps_its_worst_ages() -> None:
    arrivals = [float(t) for t in range(0, 1000, 2)]
    del arrivals[300]  # one arrival missed: a 4 s age among 2 s ones
    times, ages = age_series(arrivals, 1000.0, limit=50)
    assert len(times) <= 3 * 50 + 2
    assert max(ages) == pytest.approx(4.0)
    assert times[0] == 0.0 and times[-1] == 1000.0


def test_bounds_follow_interval_turns_and_airtime() -> None:
    loaded = mission_on_free_ports(MISSIONS / "morph.yaml")
    bounds = channel_bounds(loaded)
    # mission_command: every 20 s, from the ssv whose turn comes every 7.5 s, 0.49 s of air
    # (its largest frame, counter and tag included)
    assert bounds["mission_command"] == pytest.approx(20 + 7.5 + 0.488, abs=0.01)
    assert bounds["nav"] == pytest.approx(7.5 + 0.52, abs=0.05)


def test_recorder_keeps_range_errors_against_the_truth() -> None:
    where = {"a": (0.0, 0.0, 0.0), "b": (30.0, 40.0, 0.0)}
    recorder = MissionRecorder(truth=lambda t: where)
    recorder("a", FrameSent(100.0, 20, ["nav"], "b", b""))
    recorder("b", FrameReceived(100.5, "a", 20, ["nav"], b"", {}, {}))
    recorder("a", Range(101.0, "b", 50.2, 0.0335, 1500.0, "dlbl", "default"))
    recorder("a", Position(102.0, Fix(1.0, 2.0, 0.0, 0.5, ("b",), "circles")))
    recorder("a", Position(103.0, NoFix("too_few_anchors")))
    rec = recorder.recording
    assert rec.frames == [(0.0, "a", 20, ["nav"])]
    assert rec.arrivals[("nav", "b")] == [0.5]
    (t, observer, peer, measured, truth), = rec.ranges
    assert (t, observer, peer, measured) == (1.0, "a", "b", 50.2)
    assert truth == pytest.approx(50.0)
    assert rec.fixes["a"] == [(2.0, 1.0, 2.0, 0.5)]
    assert rec.tracks["b"] == [(0.0, 30.0, 40.0)]


@needs_browser
def test_fast_sim_writes_a_report_that_opens_offline(tmp_path: Path) -> None:
    mission = morph_on_free_ports(tmp_path, loss=0.2)  # some frames lost, so losses show
    report = tmp_path / "report.html"
    done = zab("sim", str(mission), "--fast", "--duration", "300", "--report", str(report))
    assert done.returncode == 0, done.stderr
    assert f"report written to {report}" in done.stdout.replace("\n", "")
    html = report.read_text(encoding="utf-8")
    assert "<script src=" not in html and "<link " not in html  # everything inline
    page = open_offline(report)
    assert page["asked"] == [] and page["errors"] == []
    plots = page["plots"]
    assert list(plots) == PLOTS
    assert all(p["svg"] >= 1 for p in plots.values())
    assert plots["tracks"]["traces"] >= 5  # a truth per node, fixes of the vehicles
    assert plots["age"]["traces"] >= 5 and plots["age"]["points"] > 100
    assert plots["slots"]["points"] >= 5
    assert plots["losses"]["traces"] >= 1 and plots["losses"]["annotations"] == []  # lost: loss
    # every cause has its own colour and a legend says which, even when there is one cause
    losses = plots["losses"]
    assert losses["legend"] is True and "loss" in losses["names"]
    assert len(set(losses["colours"])) == len(losses["names"]) and None not in losses["colours"]
    # each age plot says when its bound holds: latched channels are re-sent without news, one
    # sent on news only ages from its last value on; the caption says why ages pass a bound
    titles = plots["age"]["annotations"]
    assert "surface_fix: latched, re-sent without news (bound 13.0 s)" in titles, titles
    assert any(t.startswith("nav: sent on news only (bound ") for t in titles), titles
    assert "each lost frame adds a turn" in plots["age"]["caption"]
    assert "a command published once" in plots["age"]["caption"]
    assert "A DLBL range is two-way" in plots["ranges"]["caption"]
    assert plots["ranges"]["points"] > 10
    # every legend shows all its entries: none clipped into a scroll box (the ranges' was)
    assert {name: p["scroll"] for name, p in plots.items()} == dict.fromkeys(PLOTS, 0)
    assert "mission report: morph" in page["text"]
    assert "300 s simulated (virtual clock)" in page["text"]


@needs_browser
def test_real_time_sim_report_has_truth_and_json_stays_json(tmp_path: Path) -> None:
    mission = morph_on_free_ports(tmp_path)
    report = tmp_path / "report.html"
    done = zab("sim", str(mission), "--duration", "12", "--report", str(report), "--no-live")
    assert done.returncode == 0, done.stderr
    page = open_offline(report)
    assert page["asked"] == [] and page["errors"] == []
    assert page["plots"]["tracks"]["points"] >= 5  # the water's positions of every node
    assert page["plots"]["slots"]["points"] >= 5  # frames sent (DLBL only: nobody publishes)
    assert "no channel arrived anywhere: nothing was published on the vehicles' input keys" \
        in page["plots"]["age"]["annotations"]  # after the subplot titles
    as_json = tmp_path / "report.json"
    done = zab("sim", str(mission), "--fast", "--duration", "60", "--report", str(as_json))
    assert done.returncode == 0, done.stderr
    assert set(json.loads(as_json.read_text())["channels"]) >= {"nav", "mission_command"}


def test_frames_still_in_the_water_at_the_end_are_shown_as_such() -> None:
    import io

    from rich.console import Console

    from bridge.report.model import LinkFigures, MissionReport, print_report

    links = [LinkFigures("ssv->gcv", 1, 2, 481, 480, {"loss": 0}),
             LinkFigures("gcv->ssv", 2, 1, 80, 78, {"loss": 2})]
    assert [link.in_flight for link in links] == [1, 0]
    report = MissionReport("m", "virtual", 600.0, {}, {}, links, 561, 558)
    out = io.StringIO()
    print_report(Console(file=out, width=120), report)
    rows = [line.split("│")[1:-1] for line in out.getvalue().splitlines() if "->" in line]
    assert [[cell.strip() for cell in row] for row in rows] == [
        ["ssv->gcv", "481", "480", "0", "1"], ["gcv->ssv", "80", "78", "loss 2", "0"]]
    assert "in flight at the end" in out.getvalue()
    assert report.to_dict()["links"][0]["in_flight"] == 1


def test_a_big_fleet_s_report_has_a_repr_of_one_line() -> None:
    """``asyncio.run`` builds the repr of what its coroutine returns (restoring its Ctrl-C
    handler): a report's whole repr at 250 nodes took 0.3-0.5 s after every
    ``asyncio.run(run_fast(...))``."""
    import asyncio

    from bridge.report.model import LinkFigures, MissionReport

    links = [LinkFigures(f"n{a}->n{b}", a, b, 10, 9, {"loss": 1})
             for a in range(250) for b in range(250) if a != b]
    nodes = {f"n{a}": {"peers": {f"n{b}": {"state": "up"} for b in range(250)}}
             for a in range(250)}
    report = MissionReport("m", "virtual", 600.0, {}, nodes, links, 600, 148828)
    assert repr(report) == ("MissionReport(mission='m', clock='virtual', duration_s=600.0, "
                            "channels=0, nodes=250, links=62250, frames_sent=600, "
                            "frames_received=148828)")

    async def run() -> MissionReport:
        return report

    assert asyncio.run(run()) is report
