"""`zab demo` as a newcomer runs it: from an empty folder with a bare environment, one
command, ending by itself in about a minute, telling each part of the tour and writing the
mission report."""

from __future__ import annotations

import itertools
import os
import re
import socket
import subprocess
import sys
import time
from pathlib import Path

import yaml

from bridge.cli.demo import default_demo_mission
from tests.conftest import free_port

ZAB = Path(sys.executable).parent / "zab"


def demo_ports_free() -> bool:
    """The MORPH mission's Zenoh ports (what `zab demo` listens on) are free right now."""
    data = yaml.safe_load(default_demo_mission().read_text())
    for node in data["nodes"].values():
        port = int(node["zenoh"]["listen"][0].rsplit(":", 1)[1])
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return False
    return True


def test_zab_demo_tells_the_tour_and_writes_the_report(tmp_path: Path) -> None:
    args = [str(ZAB), "demo", "--gui-port", "0"]
    if not demo_ports_free():  # someone else's demo is running: same tour, other ports
        data = yaml.safe_load(default_demo_mission().read_text())
        for node in data["nodes"].values():
            node["zenoh"]["listen"] = [f"tcp/127.0.0.1:{free_port()}"]
        (tmp_path / "morph.yaml").write_text(yaml.safe_dump(data, sort_keys=False))
        args += ["--mission", "morph.yaml"]
    env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "HOME": str(tmp_path),
           "LANG": "C.UTF-8"}
    started = time.monotonic()
    done = subprocess.run(args, cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=240)
    took = time.monotonic() - started
    out = done.stdout
    assert done.returncode == 0, done.stderr + out
    assert "Traceback" not in done.stderr + out
    assert 65 <= took <= 160, took  # ends by itself, in about a minute

    headings = ["1. Values crossing the water, quantised", "2. Latest value, not a queue",
                "3. A reliable command over a lossy link",
                "4. Position fixes from acoustic ranges", "5. A Zenoh get across the water",
                "6. A vehicle surfaces, then dives", "7. A vehicle reached through another",
                "8. Summary"]
    where = [out.find(h) for h in headings]
    assert all(i >= 0 for i in where) and where == sorted(where), out
    intro, values, latest, command, fixes, query, surfacing, relay, summary = (
        out[:where[0]], *(out[a:b] for a, b in zip(where, [*where[1:], len(out)], strict=True)))

    assert "You will see, in order: 1. values crossing the water, quantised;" in \
        intro.replace("\n", " ")
    assert re.search(r"open http://127\.0\.0\.1:\d+/ in a browser", out)
    # 1: values as published and as delivered, with the step that explains the difference
    examples = re.findall(r"^  (\w+) → (\w+): (\S+) \((\w+), (\d+) bits\)$", values, re.M)
    assert len(examples) >= 2, values
    assert re.search(r"^\s+\S+\s+-?[\d.]+ → -?[\d.]+\s+\d+ bits, step [\d.]+$", values, re.M)
    # 2: latest-value semantics in words
    assert "superseded, not lost" in latest.replace("\n", " ")
    # 3: the acknowledged command and its delivery report
    assert "delivery/mission_command" in command.replace("\n", "")
    delivered = re.search(r"delivery report: (\d+) delivered, (\d+) failed", command)
    assert delivered and int(delivered.group(1)) >= 1, command
    assert re.search(r"delivered to \w+ after \d+ transmissions?, [\d.]+ s after the put",
                     command)
    # 4: fixes from the acoustic ranges
    assert re.search(r"position \((tracking|coasting \d+ s), \w+ \+ \w+\): x -?[\d.]+ m, "
                     r"y -?[\d.]+ m, ±[\d.]+ m · truth x -?[\d.]+, y -?[\d.]+ · "
                     r"error [\d.]+ m", fixes), fixes  # each fix beside the simulator's truth
    # 5: a plain get at the surface answered by a queryable on a submerged vehicle
    # (alone: the operators' gets, printed as they end, wait for it)
    assert re.search(r"^  ssv get \w+/health → \{'battery': \d+, 'depth_m': [\d.]+\} "
                     r"\([\d.]+ s round trip, the request sent \d+ times?\)$", query, re.M), query
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
    # 7: MORPH is a star: the tour names the mission that shows a relay
    assert "no relay to show" in relay and "umci_relay.yaml" in relay.replace("\n", "")
    # 8: a summary a newcomer can read, and the report's path
    for words in ("published", "sent in frames", "received", "mean age",
                  "acoustic ranges measured"):
        assert words in summary, words
    assert re.search(r"lost \d+ \(\d+%\)", summary)
    found = re.search(r"mission report \(plots, opens offline\): (\S+)", summary)
    assert found, summary
    report = Path(found.group(1))
    assert report == tmp_path / "zab-demo-report.html" and report.is_file()
    page = report.read_text(encoding="utf-8")
    assert all(f'data-plot="{name}"' in page
               for name in ("tracks", "age", "slots", "losses", "ranges"))
    # plausible numbers: no float noise, no battery jumping about
    assert not re.search(r"\d\.\d{8,}|\de-\d\d", out), out


def test_numbers_print_to_their_step_without_float_noise() -> None:
    from bridge.cli.tour import number

    assert number(9.536743164062498e-08, 0.1) == "0.0"
    assert number(3.2350001, 0.0246) == "3.235"
    assert number(14, 1.0) == "14"
    assert number(0.825, 0.05) == "0.825"


def test_synthetic_status_varies_slowly_and_plausibly() -> None:
    from bridge.cli.demo import synthetic_value
    from bridge.codec import FieldSpec

    battery = FieldSpec(field="battery", type="int", min=0, max=100)
    mode = FieldSpec(field="mode", type="enum", values=["idle", "transit", "survey", "abort"])
    levels = [synthetic_value(battery, t, 1.0) for t in range(0, 600)]
    assert all(80 <= b <= 100 for b in levels)
    assert all(0 <= a - b <= 1 for a, b in itertools.pairwise(levels))  # drains
    assert levels[0] - levels[-1] <= 11  # about 1 % a minute
    assert {synthetic_value(mode, t, 2.0) for t in range(0, 600, 7)} == {"transit"}
    depth = FieldSpec(field="depth", min=0, max=100, resolution=0.1)
    values = [synthetic_value(depth, t, 0.5) for t in range(0, 120)]
    assert max(abs(a - b) for a, b in itertools.pairwise(values)) < 0.5


def test_the_wait_after_a_dive_covers_enough_turns_for_the_loss() -> None:
    from bridge.cli.demo_surfacing import turns_to_wait

    assert turns_to_wait(0.0) == 1
    assert turns_to_wait(0.1) == 3  # all three lost: 1 in 1000
    assert turns_to_wait(0.3) == 6
    assert 0.3 ** turns_to_wait(0.3) <= 1e-3 < 0.3 ** (turns_to_wait(0.3) - 1)


def test_sends_while_up_count_frames_begun_between_the_vehicles_own_switches() -> None:
    from bridge.cli.demo_surfacing import SentAtSwitches
    from bridge.core.events import FrameSent, Surfaced

    def frame(at: float, *names: str) -> FrameSent:
        return FrameSent(at, 8, list(names), None, b"")

    sent = SentAtSwitches("cv2", "ssv")
    sent("cv2", frame(0.5, "nav", "status"))
    sent("cv2", Surfaced(1.0, "ssv", True))
    # begun before the switch (its contents chosen then), reported once on the water: before
    sent("cv2", frame(0.9, "nav", "status"))
    sent("cv2", frame(1.5, "nav"))
    assert sent.while_up() is None  # not dived yet
    sent("ssv", Surfaced(2.0, "cv2", False))  # the surface's view: not these
    sent("ssv", frame(2.5, "status"))  # nor the surface's frames
    sent("cv2", frame(3.0, "nav"))
    sent("cv2", Surfaced(5.0, "ssv", False))
    sent("cv2", frame(5.0, "nav", "status"))  # after the dive
    assert sent.while_up() == {"nav": 2}
