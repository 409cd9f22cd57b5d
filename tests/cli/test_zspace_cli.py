"""Issue 15's features through `zab check` and `zab sim --fast` as processes: a query reply
that can never fit is refused; the fast simulation asks its queries and reports them."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import yaml

from bridge.core.loaded import load_mission
from bridge.core.queries import deadline_s
from tests.conftest import MISSIONS, REPO

ZSPACE = MISSIONS / "zspace.yaml"


def test_check_refuses_a_reply_that_can_never_fit(tmp_path: Path) -> None:
    data = yaml.safe_load(ZSPACE.read_text())
    data["queries"][0]["reply"].append({"field": "log", "type": "string", "length": 60})
    path = tmp_path / "big.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    done = subprocess.run([sys.executable, "-m", "bridge", "check", str(path)], cwd=REPO,
                          capture_output=True, text=True, timeout=60,
                          env={**os.environ, "COLUMNS": "200"})
    assert done.returncode == 1 and "entry '!info'" in done.stdout
    assert "can never fit" in done.stdout


def test_zab_sim_fast_asks_the_queries_and_reports_them(tmp_path: Path) -> None:
    report = tmp_path / "r.json"
    done = subprocess.run([sys.executable, "-m", "bridge", "sim", str(ZSPACE), "--fast",
                           "--duration", "200", "--report", str(report)], cwd=REPO,
                          capture_output=True, text=True, timeout=120,
                          env={**os.environ, "COLUMNS": "200"})
    assert done.returncode == 0, done.stderr
    queries = json.loads(report.read_text())["queries"]
    assert queries["asked"] >= 10 and queries["errors"] == {}
    assert queries["answered"] >= queries["asked"] - 2  # the last ones may still be open
    bound = deadline_s(load_mission(ZSPACE).mission, load_mission(ZSPACE).table.queries[0],
                       "top", "auv1")
    assert queries["max_round_trip_s"] <= bound
    assert "queries: " in done.stdout and "answered" in done.stdout
