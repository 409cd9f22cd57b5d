"""``zab check`` of missions with several links or routes: each link's nodes, the routes and
their worst-case times, relay budgets, end-to-end age bounds, and a loop refused."""

from __future__ import annotations

import json
from pathlib import Path

from typer.testing import CliRunner

from bridge.cli.app import app

RUNNER = CliRunner()
MISSIONS = Path(__file__).resolve().parents[2] / "deploy" / "missions"


def check(path: Path) -> dict:
    result = RUNNER.invoke(app, ["check", str(path), "--json", "--no-key"])
    assert result.exit_code == 0, result.output
    return json.loads(result.output)


def test_check_shows_each_link_the_routes_the_relay_budget_and_the_age_bound() -> None:
    data = check(MISSIONS / "umci_relay.yaml")
    rov1 = next(n for n in data["nodes"] if n["name"] == "rov1")
    assert [entry["link"] for entry in rov1["links"]] == ["acoustic", "rf"]
    assert rov1["links"][1]["mac"]["note"] == "master"
    network = data["network"]
    assert [(link["name"], link["kind"], link["mac"]) for link in network["links"]] == [
        ("acoustic", "acoustic", "tdma"), ("rf", "rf", "polled")]
    assert {(r["from"], r["to"]): r["path"] for r in network["routes"]} == {
        ("surface", "rov2"): ["surface", "rov1", "rov2"],
        ("rov2", "surface"): ["rov2", "rov1", "surface"]}
    assert {(r["node"], r["link"]) for r in network["relays"]} == {("rov1", "acoustic"),
                                                                   ("rov1", "rf")}
    assert all(r["fits"] and r["carried_Bps"] > 0 for r in network["relays"])
    ages = {a["channel"]: a for a in network["age_bounds"]}
    status = ages["status"]
    assert status["route"] == ["rov2", "rov1", "surface"]  # the worst sender: the far one
    # its interval, then rov2's turn and frame (its slowest link, acoustics: one turn in
    # 15 s), then rov1's (9 s apart on acoustics): the hop bounds of the routes table
    assert status["age_bound_s"] == 10 + next(r["bound_s"] for r in network["routes"]
                                               if r["from"] == "rov2")


def test_a_relay_over_its_budget_is_warned(tmp_path: Path) -> None:
    # the status of both ROVs every 4 s: ROV2's frames for the surface (with the
    # acknowledgements of the surface's goto frames) and ROV1's own overflow its acoustic
    # turns (tests/core/test_relay_budget.py: the fleet's backlog grows there)
    text = (MISSIONS / "umci_relay.yaml").read_text().replace("interval_s: 10", "interval_s: 4")
    path = tmp_path / "busy.yaml"
    path.write_text(text)
    data = check(path)
    over = [r for r in data["network"]["relays"] if not r["fits"]]
    assert [(r["node"], r["link"]) for r in over] == [("rov1", "acoustic")]
    assert over[0]["margin_Bps"] < 0
    assert any(w.startswith("relay rov1 on acoustic: its own frames") for w in data["warnings"])
    # a channel faster than its senders' turns adds nothing: each sends one frame a turn
    line = (MISSIONS / "acoustic_line.yaml").read_text()
    fast = tmp_path / "fast.yaml"
    fast.write_text(line.replace("interval_s: 30", "interval_s: 1"))
    every_turn = tmp_path / "every_turn.yaml"
    every_turn.write_text(line.replace("interval_s: 30", "interval_s: 16"))
    assert check(fast)["network"]["relays"] == check(every_turn)["network"]["relays"]


def test_a_routing_loop_is_refused_with_its_place(tmp_path: Path) -> None:
    text = (MISSIONS / "acoustic_line.yaml").read_text().replace(
        "routes: {head: n1}", "routes: {head: tail}")
    path = tmp_path / "loop.yaml"
    path.write_text(text)
    result = RUNNER.invoke(app, ["check", str(path), "--json", "--no-key"])
    assert result.exit_code == 2
    problems = json.loads(result.output)["errors"]
    assert any("routing loop n2 -> tail -> n2" in p["message"]
               and p["path"] == "nodes.n2.routes" for p in problems), problems


def test_a_route_listing_two_relays_shows_its_primary_worst_case_and_the_alternative(
        tmp_path: Path) -> None:
    from tests.core.test_routes import DIAMOND

    path = tmp_path / "diamond.yaml"
    path.write_text(DIAMOND)
    network = check(path)["network"]
    routes = {(r["from"], r["to"]): r for r in network["routes"]}
    carried = {(r["node"], r["link"]): r["carried_Bps"] for r in network["relays"]}
    assert carried[("r2", "upper")] == carried[("r1", "upper")] > 0  # r2 budgeted as if r1
    assert carried[("r2", "lower")] == carried[("r1", "lower")] > 0  # were down all the time
    there = routes[("surface", "far")]
    assert there["path"] == ["surface", "r1", "far"]  # the worst case over the primary
    assert [a["path"] for a in there["alternatives"]] == [["surface", "r2", "far"]]
    assert there["alternatives"][0]["bound_s"] > 0 and there["bound_s"] > 0
    assert [a["path"] for a in routes[("far", "surface")]["alternatives"]] == [
        ["far", "r2", "surface"]]
    shown = RUNNER.invoke(app, ["check", str(path), "--no-key"], env={"COLUMNS": "200"})
    assert "surface -> r2 -> far ≤" in shown.output
    looped = tmp_path / "loop.yaml"  # a loop only the alternative takes
    looped.write_text(DIAMOND.replace("r1: {address: 2,",
                                      "r1: {address: 2, routes: {far: [r2, surface]},"))
    result = RUNNER.invoke(app, ["check", str(looped), "--json", "--no-key"])
    assert result.exit_code == 2
    problems = json.loads(result.output)["errors"]
    assert any("routing loop r1 -> surface -> r1" in p["message"]
               and p["path"] == "nodes.r1.routes" for p in problems), problems


def test_each_link_s_mac_timing_is_said_in_words() -> None:
    """umci_relay's mac line printed Python's dicts: ``acoustic {}, rf {'ipg_s': 1.0576, …}``."""
    result = RUNNER.invoke(app, ["check", str(MISSIONS / "umci_relay.yaml"), "--no-key"],
                           env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output
    said = " ".join(result.output.split())  # (as one line: the console wraps at its width)
    assert "mac tdma (acoustic), polled (rf): rf (ipg_s 1.0576, needed_ipg_s 1.0576, " \
           "sequence rov2) transmit turns" in said, said


def test_check_says_which_hops_send_a_lost_reliable_copy_again_themselves() -> None:
    """A relay (and the origin, for its first hop) sends again a copy its next hop did not
    carry on only where it hears that hop's answer (bridge.core.custody): every hop of
    acoustic_line; on umci_relay only ROV1's, the surface not hearing ROV1's RF."""
    def repaired(name: str) -> dict[tuple[str, str], list[str]]:
        streams = check(MISSIONS / name)["streams"]
        return {(w["from"], w["to"]): w["repaired"] for s in streams for w in s["learned"]}

    assert repaired("acoustic_line.yaml") == {
        ("head", "tail"): ["head -> n1", "n1 -> n2", "n2 -> tail"]}
    assert repaired("umci_relay.yaml") == {("surface", "rov2"): ["rov1 -> rov2"]}
    result = RUNNER.invoke(app, ["check", str(MISSIONS / "umci_relay.yaml"), "--no-key"])
    assert "a copy lost on rov1 -> rov2 is sent again by that hop's sender" in " ".join(
        result.output.split())
