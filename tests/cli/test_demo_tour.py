"""`zab demo` as a newcomer runs it, and the README's commands beside it.

Two demos start at once, each from an empty folder with a bare environment (no frame key):
`uv run zab demo` and `uv run zab demo --mission deploy/missions/zspace.yaml`, as the README
writes them (`uv run` is the venv this suite runs in; when someone else's demo holds the
ports, the same mission on free ports, and the README's endpoints follow). While they run,
the README's `listen` and `put` lines and its program run verbatim against the first, and a
browser watches its GUI; then each tour's text is read whole. One demo serves every test of
this module (they run in file order, on one worker: the live ones first)."""

from __future__ import annotations

import asyncio
import json
import os
import re
import shlex
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import aiohttp
import pytest
import yaml

from bridge.cli.demo import default_demo_mission
from tests.conftest import MISSIONS, REPO, free_port
from tests.zsim import interrupt

BIN = Path(sys.executable).parent  # what `uv run` runs: this venv's programs
ZSPACE = MISSIONS / "zspace.yaml"
LONG = True  # two demos of 70 s and what runs beside them: handed out first
WAIT_S = 40.0  # a few TDMA cycles of the MORPH fleet (7.5 s each) and a margin for load

def readme() -> str:
    return (REPO / "README.md").read_text(encoding="utf-8")


def readme_block(marker: str) -> str:
    """The code block after the README's ``<!-- marker: ... -->`` comment."""
    found = re.search(rf"<!-- {marker}:.*?-->\n```\w+\n(.*?)```", readme(), re.S)
    assert found, f"README has no block marked {marker}"
    return found.group(1)


def readme_command(text: str) -> str:
    """The README line starting with ``text``."""
    return next(line.split("  #")[0].strip() for line in readme().splitlines()
                if line.startswith(text))


def as_run(line: str, endpoints: dict[str, str]) -> list[str]:
    """A README line as this suite runs it: `uv run zab` is this venv's `zab`, and each
    README endpoint is where that vehicle listens in this run."""
    for written, actual in endpoints.items():
        line = line.replace(written, actual)
    words = shlex.split(line)
    assert words[:2] == ["uv", "run"], line
    return [str(BIN / words[2]), *words[3:]]


def ports_free(mission: Path) -> bool:
    """Every Zenoh port of ``mission`` is free right now (nobody else's demo runs)."""
    for node in yaml.safe_load(mission.read_text())["nodes"].values():
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", int(node["zenoh"]["listen"][0].rsplit(":", 1)[1]))) \
                    == 0:
                return False
    return True


@dataclass
class Demo:
    """A `zab demo` process; its output gathered as it comes."""

    args: list[str]
    folder: Path
    endpoints: dict[str, str]  # the mission file's endpoint -> where it listens in this run
    lines: list[str] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    took: float | None = None

    def __post_init__(self) -> None:
        env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "HOME": str(self.folder),
               "LANG": "C.UTF-8"}
        self.changed = threading.Condition()
        self.started = time.monotonic()
        self.proc = subprocess.Popen(self.args, cwd=self.folder, env=env, text=True,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        self.readers = [threading.Thread(target=self._read, args=(stream, into), daemon=True)
                        for stream, into in ((self.proc.stdout, self.lines),
                                             (self.proc.stderr, self.errors))]
        for reader in self.readers:
            reader.start()

    def _read(self, stream: Any, into: list[str]) -> None:
        for line in stream:
            with self.changed:
                into.append(line)
                self.changed.notify_all()

    @classmethod
    def of(cls, mission: Path, folder: Path, *args: str) -> Demo:
        """`zab demo` of ``mission`` (as given in ``args``); on free ports if its are taken,
        now or by the time it binds them (another suite's demo on this machine)."""
        if ports_free(mission):
            demo = cls([str(BIN / "zab"), "demo", *args], folder, {})
            if not demo.refused():
                return demo
            demo.stop()
        endpoints = {}
        data = yaml.safe_load(mission.read_text())
        for node in data["nodes"].values():
            was = node["zenoh"]["listen"][0]
            node["zenoh"]["listen"] = [f"tcp/127.0.0.1:{free_port()}"]
            endpoints[was] = node["zenoh"]["listen"][0]
        moved = folder / mission.name
        moved.write_text(yaml.safe_dump(data, sort_keys=False))
        return cls([str(BIN / "zab"), "demo", "--mission", str(moved)], folder, endpoints)

    def refused(self) -> bool:
        """Whether it stopped at once because one of its ports was taken meanwhile (else it
        runs: its GUI line comes once every node listens)."""
        deadline = time.monotonic() + 30
        while self.proc.poll() is None and time.monotonic() < deadline \
                and not re.search(r"^(GUI: |1\. Values)", self.text, re.M):
            time.sleep(0.2)
        if self.proc.poll() is None:
            return False
        time.sleep(0.2)  # the readers' last lines
        return self.proc.returncode == 2 and "is already in use" in "".join(self.errors)

    @property
    def text(self) -> str:
        with self.changed:
            return "".join(self.lines)

    def wait_for(self, pattern: str, timeout: float = WAIT_S) -> re.Match[str]:
        """The first match of ``pattern`` in the output, waiting for it."""
        deadline = time.monotonic() + timeout
        with self.changed:
            while (found := re.search(pattern, "".join(self.lines), re.M)) is None:
                left = deadline - time.monotonic()
                assert left > 0 and self.proc.poll() is None, \
                    f"no {pattern!r} in:\n{''.join(self.lines)}{''.join(self.errors)}"
                self.changed.wait(min(left, 1.0))
        return found

    def finish(self) -> str:
        """The whole output once it ends by itself (its wall time in :attr:`took`)."""
        try:
            self.proc.wait(timeout=240)
        finally:
            if self.took is None:
                self.took = time.monotonic() - self.started
        time.sleep(0.2)  # the readers' last lines
        return self.text

    def stop(self) -> None:
        interrupt(self.proc, timeout=30)
        for reader in self.readers:  # (the pipes end with the process)
            reader.join(5)
        for stream in (self.proc.stdout, self.proc.stderr):
            if stream is not None:
                stream.close()


@pytest.fixture(scope="module")
def demos(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Demo]]:
    """Both README demos, started together."""
    assert readme_command("uv run zab demo ") == "uv run zab demo"
    zspace = re.search(r"`(uv run zab demo --mission \S+)`", readme())
    assert zspace and zspace.group(1) == "uv run zab demo --mission deploy/missions/zspace.yaml"
    running = {
        "morph": Demo.of(default_demo_mission(), tmp_path_factory.mktemp("morph")),
        "zspace": Demo.of(ZSPACE, tmp_path_factory.mktemp("zspace"), "--mission", str(ZSPACE)),
    }
    try:
        yield running
    finally:
        for demo in running.values():
            demo.stop()


@pytest.fixture(scope="module")
def morph(demos: dict[str, Demo]) -> Demo:
    demo = demos["morph"]
    demo.wait_for(r"^1\. Values crossing the water")  # the fleet and its programs are up
    return demo


# -- the README beside the demo ----------------------------------------------------------------

def test_the_readme_listen_and_put_lines_work_as_written(morph: Demo) -> None:
    listen, put = readme_block("readme-poke").strip().splitlines()
    with subprocess.Popen(as_run(listen, morph.endpoints), cwd=REPO, text=True,
                          env={**os.environ, "PYTHONFAULTHANDLER": "1"},
                          stdout=subprocess.PIPE, stderr=subprocess.PIPE) as listener:
        try:
            assert listener.stderr is not None and listener.stdout is not None
            assert "listening on ssv/* at" in listener.stderr.readline()
            done = subprocess.run(as_run(put, morph.endpoints), cwd=REPO, capture_output=True,
                                  text=True, timeout=30)
            assert done.returncode == 0, done.stderr
            assert re.fullmatch(r"put command \(\d+ B msgpack, ref put-[0-9a-f]{8}\) at "
                                r"tcp/127\.0\.0\.1:\d+\n", done.stdout)
            # the demo's programs see the operator's put (and leave the key alone)
            morph.wait_for(r'ssv ← operator: command \{"action": "surface", "leg": 3\}', 10)
            # it crosses in the ssv's next slots, acknowledged, whatever the water loses
            expected = readme_arrival()
            arrived = []
            deadline = time.monotonic() + WAIT_S
            while time.monotonic() < deadline and (not arrived or arrived[-1] != expected):
                arrived.append(listener.stdout.readline().strip())
            assert arrived[-1] == expected, arrived
            for line in arrived:  # the GPS fix to its channel's step, no float noise; the
                # tour's own command (part 3) may come first
                assert re.fullmatch(r'ssv/gps \{"lat": \d+\.\d{1,6}, "lon": \d+\.\d{1,6}\}|'
                                    r'ssv/command \{"action": "\w+", "leg": \d+\}', line), line
        finally:
            interrupt(listener)  # the README's listen runs until Ctrl-C
        # Ctrl-C ends it at once (the shell says 130); one that outlived it would be stopped
        # with SIGABRT, its stacks on stderr
        assert listener.returncode == -signal.SIGINT, listener.stderr.read()


def readme_arrival() -> str:
    """What the README says `listen` prints at the gcv once the `put` has crossed."""
    found = re.search(r"\(`(ssv/command \{.*?\})` at the gcv\)", " ".join(readme().split()))
    assert found, "the README shows no arrival of the put"
    return found.group(1)


def test_the_readme_program_runs_as_written(morph: Demo, tmp_path: Path) -> None:
    program = tmp_path / "first.py"
    program.write_text(readme_block("readme-program"), encoding="utf-8")
    args = [sys.executable, str(program)]
    if morph.endpoints:  # someone else's demo holds the README's port
        args.append(morph.endpoints["tcp/127.0.0.1:7502"])
    done = subprocess.run(args, capture_output=True, text=True, timeout=90)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert len(lines) == 5
    for line in lines:
        assert re.fullmatch(r"(lsv|cv1|cv2|gcv)/nav: x -?\d+\.\d m, y -?\d+\.\d m, "
                            r"depth \d+\.\d m", line), line


# -- the GUI the demo serves, in a browser -------------------------------------------------------

# Every drawn range label and vehicle label, as boxes in the map's own units, and the circles.
LABELS = """() => {
  const box = (e) => { const b = e.getBBox(); return [b.x, b.y, b.x + b.width, b.y + b.height]; };
  const svg = document.getElementById("map");
  const [, , width, height] = svg.getAttribute("viewBox").split(" ").map(Number);
  const circle = (t) => {
    const g = t.closest("g");
    const c = svg.querySelector(`g.range[data-observer="${g.dataset.observer}"]` +
                                `[data-peer="${g.dataset.peer}"] circle`);
    return [Number(c.getAttribute("cx")), Number(c.getAttribute("cy")),
            Number(c.getAttribute("r"))];
  };
  return { width, height,
           ranges: [...svg.querySelectorAll(".range text")].map(
             (t) => [t.textContent, box(t), circle(t)]),
           vehicles: [...svg.querySelectorAll(".vehicle text")].map(
             (t) => [t.textContent, box(t)]) };
}"""


@pytest.fixture(scope="module")
def page(morph: Demo) -> Iterator[Any]:
    """A browser tab on the demo's GUI (Debian's Chromium, driven by Playwright)."""
    from tests.conftest import CHROMIUM, browser_missing
    from tests.gui.test_browser import CHROMIUM_ARGS

    if reason := browser_missing():
        pytest.skip(reason)
    from playwright import sync_api
    url = morph.wait_for(r"open (http://127\.0\.0\.1:\d+/) in a browser").group(1)
    with sync_api.sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        try:
            tab = browser.new_page(viewport={"width": 1280, "height": 900})
            errors: list[str] = []
            tab.on("pageerror", lambda exc: errors.append(str(exc)))
            tab.goto(url)
            yield tab
            artifacts = REPO / "artifacts"
            artifacts.mkdir(exist_ok=True)
            tab.screenshot(path=str(artifacts / "gui-demo.png"), full_page=True)
            assert errors == [], f"errors in the page: {errors}"
        finally:
            browser.close()


def test_the_page_says_the_surface_bridge_runs(page: Any) -> None:
    page.wait_for_selector('.vehicle-card[data-node="ssv"]', timeout=20_000)
    page.wait_for_function("document.getElementById('connection').dataset.state === 'up'",
                           timeout=10_000)  # its stats arrive every second
    assert page.inner_text("#connection") == "connected to ssv"
    assert page.inner_text('.vehicle-card[data-node="ssv"] .link') == \
        "this node: bridge running"


def overlap(a: list[float], b: list[float]) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def test_range_labels_do_not_bunch_together_or_sit_on_their_circles(page: Any) -> None:
    page.wait_for_function("document.querySelectorAll('#map .range text').length >= 4",
                           timeout=60_000)
    page.wait_for_timeout(1500)  # a few more renders, positions moving
    drawn = page.evaluate(LABELS)
    ranges = drawn["ranges"]
    assert len(ranges) >= 4
    for i, (text, box, (cx, cy, r)) in enumerate(ranges):
        assert re.fullmatch(r"\w+ \d+\.\d m", text)
        assert box[0] >= 0 and box[2] <= drawn["width"] and box[1] >= 0 \
            and box[3] <= drawn["height"], (text, box)
        for other, other_box, _ in ranges[i + 1:]:
            assert not overlap(box, other_box), (text, other, box, other_box)
        for vehicle, vehicle_box in drawn["vehicles"]:
            assert not overlap(box, vehicle_box), (text, vehicle)
        # its own circle's dashes do not cross it: the box lies outside the circle
        nearest = (min(max(cx, box[0]), box[2]), min(max(cy, box[1]), box[3]))
        assert ((nearest[0] - cx) ** 2 + (nearest[1] - cy) ** 2) ** 0.5 >= r - 0.5, \
            (text, box, (cx, cy, r))


def test_the_command_form_opens_on_the_command_channel(page: Any) -> None:
    page.wait_for_selector("#command-channel option", state="attached", timeout=20_000)
    assert page.input_value("#command-channel") == "mission_command"
    paths = page.eval_on_selector_all("#command-fields [data-path]",
                                      "(es) => es.map((e) => e.dataset.path)")
    assert paths == ["action", "leg"]


def test_channel_names_do_not_wrap_mid_word(page: Any) -> None:
    cell = '.vehicle-card[data-node="ssv"] tr[data-channel="mission_command"] td.channel'
    page.wait_for_selector(cell, timeout=60_000)  # once the tour's operator commands
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
    page.wait_for_function("(sel) => Number(document.querySelector(sel)?.dataset.count) > 2",
                           arg=row, timeout=20_000)  # published every second meanwhile
    assert page.inner_text(f"{row} .interval") == "5 s"
    row = f'{card} tr[data-channel="mission_command"]'
    page.wait_for_selector(row, timeout=60_000)
    assert page.inner_text(f"{row} .interval") == "20 s"
    # a vehicle across the water shows the time between arrivals, as before
    remote = '.vehicle-card[data-node="lsv"] tr[data-channel="nav"]'
    page.wait_for_function("(sel) => Number(document.querySelector(sel)?.dataset.count) > 1",
                           arg=remote, timeout=40_000)
    assert page.inner_text(f"{remote} .interval").endswith(" s")


def test_a_surfaced_vehicle_is_logged_in_words_and_adds_no_copies(page: Any) -> None:
    """cv2 surfaces about 30 s in: its Zenoh joins ssv's, so what cv2's bridge publishes
    (the gcv's nav it heard, ...) reaches the GUI too; those copies are not arrivals."""
    page.wait_for_function(
        "[...document.querySelectorAll('#events li')].some("
        "(li) => li.textContent.includes('ssv: cv2 reached over IP (one of them surfaced)'))",
        timeout=60_000)
    page.wait_for_timeout(9_000)  # more than a TDMA cycle of values while it is up
    events = page.inner_text("#events")
    assert "(peer cv2, ip True)" not in events
    # the start of a healthy demo has no red line: peers not heard yet are no fault
    first = page.eval_on_selector_all(
        "#events li", "(es) => es.filter((e) => e.textContent.includes('not heard yet'))"
        ".map((e) => e.className)")
    assert first and set(first) == {"info"}, events
    intervals = page.eval_on_selector_all(
        '.vehicle-card:not([data-node="ssv"]) td.interval', "(es) => es.map((e) => e.textContent)")
    assert intervals and "0.0 s" not in intervals, intervals


def test_a_command_from_the_gui_stands_against_the_demo_s_programs(morph: Demo) -> None:
    """A command sent from the page's websocket reaches the surface bridge; the demo's own
    publisher leaves that key alone."""
    url = morph.wait_for(r"open (http://127\.0\.0\.1:\d+/) in a browser").group(1)
    morph.wait_for(r"^\d\. Position fixes", 60)  # after the tour's own command

    async def operator() -> tuple[dict, dict]:
        async with aiohttp.ClientSession() as http, http.ws_connect(url + "ws") as ws:
            items = (await ws.receive_json(timeout=10))["items"]
            while not any(i["kind"] == "feed" and i["connected"] for i in items):
                items = (await ws.receive_json(timeout=10)).get("items", [])
            await ws.send_json({"type": "command", "request": 1, "channel": "mission_command",
                                "vehicle": "cv1", "values": {"action": "surface", "leg": 9}})
            while (reply := await ws.receive_json(timeout=10))["type"] != "reply":
                pass
            await asyncio.sleep(3)  # longer than the demo's programs' publishing period
            async with http.get(url + "state.json") as response:
                return reply, await response.json()

    with ThreadPoolExecutor(1) as thread:  # this thread runs the browser's loop
        reply, state = thread.submit(asyncio.run, operator()).result(timeout=60)
    assert reply["ok"], reply
    morph.wait_for(r'ssv ← operator: command \{"action": "surface", "leg": 9\}', 10)
    positions = {i["node"] for i in state["items"] if i["kind"] == "position"}
    assert {"gcv", "lsv", "cv1", "cv2"} <= positions
    command = next(i for i in state["items"]
                   if i["kind"] == "channel" and i["channel"] == "mission_command")
    assert command["value"] == {"action": "surface", "leg": 9}
    assert json.dumps(state, allow_nan=False)


# -- the tours, read whole ---------------------------------------------------------------------

FIRST_ARRIVAL = re.compile(r"^  \S+ → \S+: ", re.M)
"""A first arrival shown with its quantisation ("  auv1 → top: auv1/alarm ..."): part 1's."""


def parts(out: str, headings: list[str]) -> list[str]:
    """The intro, then each part's text, split at ``headings`` (which come in order)."""
    where = [out.find(h) for h in headings]
    assert all(i >= 0 for i in where) and where == sorted(where), out
    return [out[:where[0]], *(out[a:b] for a, b in zip(where, [*where[1:], len(out)],
                                                        strict=True))]


def test_zab_demo_tells_the_tour_and_writes_the_report(morph: Demo) -> None:
    out = morph.finish()
    errors = "".join(morph.errors)
    assert morph.proc.returncode == 0, errors + out
    assert "Traceback" not in errors + out
    assert morph.took is not None and 65 <= morph.took <= 160, morph.took  # ends by itself
    assert "WARNING" not in errors, errors  # what a newcomer cannot act on is not shown

    intro, values, latest, command, fixes, query, surfacing, picture, summary = parts(out, [
        "1. Values crossing the water, quantised", "2. Latest value, not a queue",
        "3. A reliable command over a lossy link", "4. Position fixes from acoustic ranges",
        "5. A Zenoh get across the water", "6. A vehicle surfaces, then dives",
        "7. A picture across the water, refining", "8. Summary"])
    assert "You will see, in order: 1. values crossing the water, quantised;" in \
        intro.replace("\n", " ")
    assert re.search(r"open http://127\.0\.0\.1:\d+/ in a browser", out)
    # 1: values as published and as delivered, with the step that explains the difference
    examples = re.findall(r"^  (\w+) → (\w+): (\S+) \((\w+), (\d+) bits\)$", values, re.M)
    assert len(examples) >= 2, values
    assert re.search(r"^\s+\S+\s+-?[\d.]+ → -?[\d.]+\s+\d+ bits, step [\d.]+$", values, re.M)
    assert not re.search(FIRST_ARRIVAL, out.replace(values, "")), out  # part 1's only
    # 2: latest-value semantics in words
    assert "superseded, not lost" in latest.replace("\n", " ")
    # 3: the acknowledged command and its delivery report
    assert "delivery/mission_command" in command.replace("\n", "")
    delivered = re.search(r"delivery report: (\d+) delivered, (\d+) failed", command)
    assert delivered and int(delivered.group(1)) >= 1, command
    assert re.search(r"delivered to \w+ after \d+ transmissions?, [\d.]+ s after the put",
                     command)
    # 4: the latest fix of each vehicle, beside the simulator's truth, and only here
    # (the anchors heard lately: both, or one while the other's range is not recent)
    fix = (r"^ *(\w+) position \((?:tracking|coasting \d+ s), \w+(?: \+ \w+)?\): x -?[\d.]+ m, "
           r"y -?[\d.]+ m, ±[\d.]+ m · truth x -?[\d.]+, y -?[\d.]+ · error [\d.]+ m$")
    assert sorted(re.findall(fix, fixes, re.M)) == ["cv1", "cv2", "lsv"], fixes
    assert " position (" not in out.replace(fixes, "")
    # 5: a plain get at the surface answered by a queryable on a submerged vehicle, with that
    # vehicle's own data (the gcv sails at 12 m), alone: the operator's gets came after it
    assert re.search(r'^  ssv get gcv/health → \{"battery": \d+, "depth_m": 12\.0\} '
                     r"\([\d.]+ s round trip, the request sent \d+ times?\)$", query, re.M), query
    assert len(re.findall(r" get \w+/health", out)) == 1, out
    # 6: the scripted surfacing, as the running system saw it
    flat = " ".join(surfacing.split())
    assert re.search(r"[\d.]+ s cv2 joined over IP \(its bridge token is visible at ssv\)",
                     flat), surfacing
    assert re.search(r"\d+ values arrived over IP, e\.g\. cv2/\w+ = ", flat), surfacing
    assert re.search(r"status: 0 values sent acoustically while up", flat), surfacing
    assert re.search(r"\b0 acoustic values of cv2 published at ssv while up", flat), surfacing
    assert re.search(r"[\d.]+ s cv2 dived: its bridge token is gone from ssv", flat), surfacing
    assert re.search(r"back over the water [\d.]+ s after the dive: cv2/\w+ = ", flat), \
        surfacing
    # 7: the picture put as the tour began, sharper at each fragment (one 28-byte
    # fragment goes every ~15 s below the other channels: on a loaded machine, with the tour's
    # 10 % loss, none may arrive in time, and the tour says so; tests/runtime/test_images_*
    # follow a picture to its end)
    shown = re.findall(r"^ +([\d.]+) s +(\d+) / (\d+) B  160×120, ≈[\d.]+ dB", picture, re.M)
    sizes = [int(got) for _, got, _ in shown]
    assert sizes == sorted(set(sizes)), picture  # each one sharper than the last
    assert shown or "not seen before the tour moved on" in picture, picture
    # 8: a summary a newcomer can read, and the report's path
    flat = " ".join(summary.split())
    for words in ("published", "sent in frames", "received", "mean age"):
        assert words in summary, words
    lost = re.search(r"lost (\d+) \(\d+%(?:: (\d+) to the tour's random loss)?\)\.", flat)
    assert lost and lost.group(2) == (lost.group(1) if lost.group(1) != "0" else None), flat
    assert re.search(r"\d+ acoustic ranges measured; median error against the simulated "
                     r"distance when each completed [\d.]+ m\. A range is two-way", flat), flat
    assert re.search(r"After part 5, an operator on ssv asked every vehicle every 20 s: "
                     r"\d+ answered, \d+ failed", flat), flat
    found = re.search(r"mission report \(plots, opens offline\): (\S+)", summary)
    assert found, summary
    report = Path(found.group(1))
    assert report == morph.folder / "zab-demo-report.html" and report.is_file()
    page = report.read_text(encoding="utf-8")
    assert all(f'data-plot="{name}"' in page
               for name in ("tracks", "age", "slots", "losses", "ranges"))
    # plausible numbers: no float noise, no battery jumping about, JSON not Python reprs
    assert not re.search(r"\d\.\d{8,}|\de-\d\d", out), out
    assert "{'" not in out and ": True" not in out


def test_the_zspace_tour_shows_what_the_readme_says(demos: dict[str, Demo]) -> None:
    demo = demos["zspace"]
    out = demo.finish()
    errors = "".join(demo.errors)
    assert demo.proc.returncode == 0, errors + out
    assert "Traceback" not in errors + out and "WARNING" not in errors, errors
    assert "nothing to show" not in out
    intro, values, latest, query, surfacing, _, summary = parts(out, [
        "1. Values crossing the water, quantised", "2. Latest value, not a queue",
        "3. A Zenoh get across the water", "4. A vehicle surfaces, then dives",
        "5. A picture across the water, refining", "6. Summary"])
    assert "You will see, in order: 1. values crossing the water, quantised; 2. latest value, " \
        "not a queue; 3. a zenoh get across the water; 4. a vehicle surfaces, then dives; " \
        "5. a picture across the water, refining; 6. summary." in " ".join(intro.split())
    # the README: members of its key families crossing on their own keys ...
    claim = " ".join(readme().split())
    assert "its key families crossing on their own keys (`auv1/sensors/a/temp` ...)" in claim
    assert re.search(r"^  temps: \d+ keys? so far: auv\d/sensors/[abc]/temp", values, re.M), \
        values
    # ... a get answered across the water, with the vehicle's own depth (auv1 at 10 m) ...
    assert re.search(r'^  top get auv1/info\?detail=0 → \{"depth_m": 10\.0, "state": "\w+", '
                     r'"detail": 0\}', query, re.M), query
    # ... and a vehicle surfacing and diving
    flat = " ".join(surfacing.split())
    assert re.search(r"auv\d joined over IP \(its bridge token is visible at top\)", flat), flat
    assert re.search(r"auv\d dived: its bridge token is gone from top", flat), flat
    assert "superseded, not lost" in " ".join(latest.split())
    assert "mission report (plots, opens offline)" in summary
    assert not re.search(FIRST_ARRIVAL, out.replace(values, "")), out  # part 1's only
