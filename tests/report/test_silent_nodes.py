"""`zab check` refuses a node that has something to send but never a turn to send it under
the mission's MAC (TDMA without a slot for it, a polled slave never polled), and a reliable
channel whose receiver can never send its acknowledgements: before, both passed (exit 0)
and the values simply never left, or were all reported failed at sea."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from bridge.cli.app import app

RUNNER = CliRunner()

MISSION = """\
mission: quiet
nodes:
  a: {address: 1}
  b: {address: 2}
  c: {address: 3}
MAC
channels:
  - name: pose
    from: b
    to: a
    elements:
      - in: pose
        out: a/pose
        fields:
          - {field: x, bits: 8, min: 0, max: 10}
  - name: cmd
    from: a
    to: c
    reliable: true
    elements:
      - in: cmd
        out: a/cmd
        fields:
          - {field: x, bits: 8, min: 0, max: 10}
"""


def check(tmp_path: Path, mac: str, *options: str) -> tuple[int, str]:
    path = tmp_path / "quiet.yaml"
    path.write_text(MISSION.replace("MAC", mac))
    result = RUNNER.invoke(app, ["check", str(path), "--no-key", *options])
    return result.exit_code, result.output


@pytest.mark.parametrize(("mac", "why", "fix"), [
    ("mac: {type: tdma, slot_s: 2.0, order: [a]}", "it owns no TDMA slot (mac.order)",
     "add {node} to mac.order"),
    ("mac: {type: polled, master: a, ipg_s: 3, order: [c]}",
     "the master a never polls it", "add {node} to mac.order"),
    ("mac: {type: polled, master: a, ipg_s: 3, weights: {c: 2}}",
     "the master a never polls it", "add {node} to mac.weights"),
])
def test_a_sender_without_a_turn_is_an_error_naming_it(tmp_path: Path, mac: str, why: str,
                                                       fix: str) -> None:
    code, output = check(tmp_path, mac, "--json")
    data = json.loads(output)
    assert code == 2 and not data["ok"]
    silent = {(s["node"], s["as"]): s for s in data["silent"]}
    sender = silent[("b", "sender")]
    assert (sender["channel"], sender["path"], sender["line"]) == ("pose", "channels[0].from", 9)
    assert why in sender["why"] and fix.format(node="b") in sender["why"]
    assert any("quiet.yaml:9:5: channels[0].from: node b sends channel 'pose' but never gets a "
               "turn" in e for e in data["errors"])
    if "[a]" in mac:  # no slot for c either; polled, c is polled: its acknowledgements go
        assert silent[("c", "receiver")]["path"] == "channels[1].to"
    else:
        assert ("c", "receiver") not in silent


def test_a_reliable_receiver_without_a_turn_cannot_acknowledge(tmp_path: Path) -> None:
    code, output = check(tmp_path, "mac: {type: tdma, slot_s: 2.0, order: [a, b]}")
    assert code == 2
    text = " ".join(output.split())
    assert "quiet.yaml:18:5: channels[1].to: node c receives reliable channel 'cmd' but never " \
           "gets a turn to send, so it can never acknowledge" in text
    assert "add c to mac.order (or make the channel not reliable)" in text
    assert "node b" not in text


def test_every_node_with_a_turn_passes(tmp_path: Path) -> None:
    for mac in ("mac: {type: tdma, slot_s: 2.0, order: [a, b, c]}",
                "mac: {type: polled, master: a, ipg_s: 3}", "mac: {type: none}"):
        code, output = check(tmp_path, mac, "--json")
        assert code == 0 and json.loads(output)["silent"] == [], (mac, output)


QUERIES = """\
queries:
  - name: depth
    key: a/depth
    serve: b
    ASK
    reply:
      - {field: d, bits: 8, min: 0, max: 100}
"""


@pytest.mark.parametrize(("order", "ask", "silent"), [
    ("[a, c]", "", {("b", "server", "queries[0].serve", 10)}),  # nobody could answer
    ("[b]", "ask: [a, c]", {("a", "asker", "queries[0].ask", 11),
                            ("c", "asker", "queries[0].ask", 11)}),
    ("[b]", "", set()),  # askers by default (every node but b) may only listen
    ("[a, b]", "ask: [a]", set()),
])
def test_a_query_server_or_named_asker_without_a_turn_is_an_error(
        tmp_path: Path, order: str, ask: str, silent: set[tuple[str, str, str, int]]) -> None:
    mission = MISSION.split("channels:")[0].replace(
        "MAC", f"mac: {{type: tdma, slot_s: 2.0, order: {order}}}")
    path = tmp_path / "asked.yaml"
    path.write_text(mission + QUERIES.replace("ASK", ask or "# ask: every other node"))
    result = RUNNER.invoke(app, ["check", str(path), "--no-key", "--json"])
    data = json.loads(result.output)
    found = {(s["node"], s["as"], s["path"], s["line"]) for s in data["silent"]}
    assert found == silent, data["silent"]
    assert (result.exit_code == 2) == bool(silent)
    for s in data["silent"]:
        assert s["query"] == "depth" and "never gets a turn to send" in s["message"]
        assert f"take {s['node']} out of this query's {s['path'].split('.')[1]}" in s["message"]
