"""One Zenoh space across the water through real processes (issue 15's features): `zab sim`
with plain Zenoh applications (only `zenoh` and `msgpack`) at the nodes' endpoints, and `zab
run` processes over `zab water`. A surface subscriber turns a demand-driven channel on and off;
two members of a key family arrive on their own keys; a get crosses the water and its errors
come back in words; a surfaced vehicle's values come over IP, acoustic again after the dive.
The pure cores behind each are tested on the virtual clock in tests/core/."""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import msgpack
import pytest
import yaml
import zenoh

from bridge.runtime.surface_wifi import access_point
from tests.conftest import MISSIONS, REPO, free_port
from tests.harness import put
from tests.zsim import Inbox, mission_file, zab_sim
from tests.zsim import app as plain_app

ZSPACE = MISSIONS / "zspace.yaml"
LONG = True  # a minute and a half of zab sim: handed out first
CYCLE_S = 3.0  # the example's TDMA cycle
INDEPENDENT = True  # each test waits on real time: xdist may spread them (the shared zab sim
# then starts once per worker that runs a test of it)


@pytest.fixture(scope="module")
def zspace(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, list[str]]]:
    """`zab sim` of the example mission as it is, shared by the tests that use it as it is
    (each on keys of its own); its nodes' endpoints."""
    mission, endpoints = mission_file(ZSPACE.read_text(), tmp_path_factory.mktemp("zspace"))
    with zab_sim(mission, endpoints, timeout=600):
        yield endpoints


# -- demand-driven sending -------------------------------------------------------------------

def latest_stats(session, key: str, seconds: float) -> dict:
    got: list[dict] = []
    sub = session.declare_subscriber(key, lambda s: got.append(
        msgpack.unpackb(s.payload.to_bytes())))
    try:
        end = time.time() + seconds
        while time.time() < end and not got:
            time.sleep(0.05)
        return got[-1] if got else {}
    finally:
        sub.undeclare()


def test_a_subscriber_at_the_surface_turns_a_channel_on_and_off_through_zab_sim(
        zspace: dict[str, list[str]]) -> None:
    endpoints = zspace
    auv1, top = plain_app(endpoints["auv1"]), plain_app(endpoints["top"])
    try:
        put(auv1, "auv1/status", {"battery": 77, "mode": "transit"})
        time.sleep(7.0)  # two TDMA cycles: nothing is wanted yet
        key = "@zab/zspace/auv1/stats"
        assert latest_stats(auv1, key, 3.0)["sent_per_channel"].get("status", 0) == 0
        got: list[tuple[str, dict]] = []
        sub = top.declare_subscriber("auv1/status", lambda s: got.append(
            (str(s.key_expr), msgpack.unpackb(s.payload.to_bytes()))))
        deadline = time.time() + 10.0
        while not got and time.time() < deadline:
            time.sleep(0.05)
        assert got[0] == ("auv1/status", {"battery": 77, "mode": "transit"})
        sub.undeclare()
        time.sleep(4.0)  # the new @want crosses within a cycle
        before = latest_stats(auv1, key, 3.0)["sent_per_channel"]["status"]
        time.sleep(6.0)
        after = latest_stats(auv1, key, 3.0)["sent_per_channel"]["status"]
        assert after == before
    finally:
        auv1.close()
        top.close()


# -- key families ------------------------------------------------------------------------------

def test_two_wildcard_sources_arrive_on_their_own_keys_through_zab_sim(
        zspace: dict[str, list[str]]) -> None:
    endpoints = zspace
    auv1, top = plain_app(endpoints["auv1"]), plain_app(endpoints["top"])
    try:
        inbox = Inbox()
        top.declare_subscriber("auv1/sensors/**", inbox)
        put(auv1, "auv1/sensors/a/temp", {"celsius": 10.0})
        put(auv1, "auv1/sensors/b/temp", {"celsius": 20.0})
        put(auv1, "auv1/sensors/*/temp", {"celsius": 30.0})  # no one member: counted
        got = dict(inbox.drain(8.0))
        assert got == {"auv1/sensors/a/temp": {"celsius": 10.0},
                       "auv1/sensors/b/temp": {"celsius": 20.0}}
        deadline, dropped = time.time() + 10.0, {}
        while "auv1/sensors/*/temp" not in dropped and time.time() < deadline:
            dropped = latest_stats(auv1, "@zab/zspace/auv1/stats", 3.0).get("payloads_dropped",
                                                                              {})
        assert dropped.get("auv1/sensors/*/temp") == 1, dropped
    finally:
        auv1.close()
        top.close()


# -- queries -----------------------------------------------------------------------------------

TEST_MISSION = """
nodes:
  auv3: {address: 4, position: {x: 9000, y: 0, depth: 10}}
queries:
  - name: slowinfo
    key: auv1/slowinfo
    serve: auv1
    ask: top
    reply: [{field: depth_m, min: 0, max: 200, resolution: 0.5}]
    timeout_s: 1.5
"""


def e2e_mission(tmp_path: Path) -> tuple[Path, dict]:
    data = yaml.safe_load(ZSPACE.read_text())
    extra = yaml.safe_load(TEST_MISSION)
    data["nodes"].update(extra["nodes"])  # auv3 is out of acoustic range: its link is down
    data["mac"]["order"].append("auv3")
    data["queries"] += extra["queries"]
    return mission_file(yaml.safe_dump(data, sort_keys=False), tmp_path)


def get(session, selector: str, timeout: float = 30.0) -> tuple[list, list[str], float]:
    started = time.time()
    values, errors = [], []
    for reply in session.get(selector, timeout=timeout):
        if reply.ok is not None:
            values.append((str(reply.ok.key_expr), msgpack.unpackb(reply.ok.payload.to_bytes())))
        else:
            errors.append(reply.err.payload.to_string())
    return values, errors, time.time() - started


def test_a_plain_get_crosses_the_water_through_zab_sim(tmp_path: Path) -> None:
    mission, endpoints = e2e_mission(tmp_path)
    with zab_sim(mission, endpoints):
        auv1, top = plain_app(endpoints["auv1"]), plain_app(endpoints["top"])
        try:
            def answer(query) -> None:
                detail = int(str(query.parameters).partition("detail=")[2] or 0)
                query.reply(query.key_expr, msgpack.packb(
                    {"depth_m": 42.5, "state": "transit", "detail": detail}))
                query.drop()

            auv1.declare_queryable("auv1/info", answer)
            deadline = time.time() + 20  # until the surface has heard auv1
            while True:
                values, errors, took = get(top, "auv1/info?detail=3")
                if values or time.time() > deadline or "link down" not in " ".join(errors):
                    break
                time.sleep(1.0)
            assert values == [("auv1/info", {"depth_m": 42.5, "state": "transit",
                                             "detail": 3})], errors
            assert not errors and took < 12.0  # two TDMA cycles of 3 s, at most
            # concurrent gets share one request
            results: list = []
            threads = [threading.Thread(target=lambda: results.append(
                get(top, "auv1/info?detail=1"))) for _ in range(2)]
            for t in threads:
                t.start()
            for t in threads:
                t.join()
            assert [r[0] for r in results] == [[("auv1/info", {"depth_m": 42.5,
                                                               "state": "transit",
                                                               "detail": 1})]] * 2
            # a deadline shorter than the round trip: a clear error
            values, errors, took = get(top, "auv1/slowinfo")
            assert values == [] and len(errors) == 1
            assert "auv1: no reply to query 'slowinfo' within 1.5 s" in errors[0]
            # the link to auv3 is down: at once, naming it
            values, errors, took = get(top, "auv3/info?detail=0")
            assert values == [] and "auv3: acoustic link down" in errors[0] and took < 1.0
            values, errors, took = get(top, "auv1/info?detail=banana")
            assert values == [] and "malformed parameters" in errors[0] and took < 1.0
        finally:
            auv1.close()
            top.close()


def test_a_get_through_zab_run_processes_and_zab_water(tmp_path: Path) -> None:
    """What the vehicles run at sea: one `zab run` per node, here over `zab water`."""
    data = yaml.safe_load(ZSPACE.read_text())
    water = free_port()
    data["modem"]["options"]["water"] = f"127.0.0.1:{water}"
    mission, endpoints = mission_file(yaml.safe_dump(data, sort_keys=False), tmp_path)
    procs = [subprocess.Popen([sys.executable, "-m", "bridge", "water", str(mission), "--port",
                               str(water)], cwd=REPO, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)]
    sessions = []
    try:
        time.sleep(1.0)
        for node in ("top", "auv1"):
            procs.append(subprocess.Popen([sys.executable, "-m", "bridge", "run", str(mission),
                                           "--node", node], cwd=REPO,
                                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        deadline = time.time() + 20
        while len(sessions) < 2:
            try:
                sessions.append(plain_app(endpoints[("auv1", "top")[len(sessions)]]))
            except Exception:
                assert time.time() < deadline, "zab run did not open its endpoint"
                time.sleep(0.2)
        auv1, top = sessions

        def answer(query) -> None:
            query.reply(query.key_expr, msgpack.packb({"depth_m": 5.0, "state": "idle",
                                                       "detail": 1}))
            query.drop()

        auv1.declare_queryable("auv1/info", answer)
        deadline = time.time() + 25
        while True:
            values, errors, _ = get(top, "auv1/info?detail=1")
            if values or time.time() > deadline:
                break
            time.sleep(1.0)  # until the surface has heard auv1
        assert values == [("auv1/info", {"depth_m": 5.0, "state": "idle", "detail": 1})], errors
    finally:
        for session in sessions:
            session.close()
        for proc in reversed(procs):
            proc.send_signal(signal.SIGINT)
        for proc in procs:
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


# -- surfacing ---------------------------------------------------------------------------------

def test_surfacing_and_diving_through_zab_sim(tmp_path: Path) -> None:
    data = yaml.safe_load(ZSPACE.read_text())
    for name in ("top", "auv1"):  # as the deploy kit runs them: routers
        data["nodes"][name]["zenoh"] = {"mode": "router", "scouting/gossip/enabled": False,
                                        "scouting/delay": 0}
    mission, endpoints = mission_file(yaml.safe_dump(data, sort_keys=False), tmp_path)
    with zab_sim(mission, endpoints):
        auv1, top = plain_app(endpoints["auv1"]), plain_app(endpoints["top"])
        wifi = None
        try:
            got: list[tuple[float, dict]] = []
            top.declare_subscriber("auv1/status", lambda s: got.append(
                (time.time(), msgpack.unpackb(s.payload.to_bytes()))))
            time.sleep(0.5)
            put(auv1, "auv1/status", {"battery": 77.3, "mode": "survey"})
            deadline = time.time() + 12
            while not got and time.time() < deadline:
                time.sleep(0.1)
            assert got and got[0][1] == {"battery": 77, "mode": "survey"}  # quantised
            wifi = access_point(endpoints["top"] + endpoints["auv1"])
            time.sleep(2.0)  # the tokens cross; the bridges switch over
            got.clear()
            put(auv1, "auv1/status", {"battery": 66.6, "mode": "transit"})
            time.sleep(3 * CYCLE_S)  # latching every 2 s: acoustic copies would show here
            assert [v for _, v in got] == [{"battery": 66.6, "mode": "transit"}]
            # a get at the surface: the value that came over IP, not the older acoustic one
            # the surface bridge published before (its latched queryable answered 77 until the
            # dive)
            assert latched(top, "auv1/status") == [{"battery": 66.6, "mode": "transit"}]
            got.clear()
            dived = time.time()
            wifi.close()
            wifi = None
            deadline = time.time() + 2 + 2 * CYCLE_S
            while not got and time.time() < deadline:
                time.sleep(0.1)
            assert got and got[0][1] == {"battery": 67, "mode": "transit"}  # latched, acoustic
            assert got[0][0] - dived <= 1.0 + 2 * CYCLE_S
        finally:
            if wifi is not None:
                wifi.close()
            auv1.close()
            top.close()


def latched(session: zenoh.Session, key: str) -> list[dict]:
    """What a get on ``key`` answers (each reply's value)."""
    return [msgpack.unpackb(r.ok.payload.to_bytes()) for r in session.get(key, timeout=3.0)
            if r.ok is not None]


def token_seen(session: zenoh.Session, node: str) -> bool:
    """Whether ``node``'s bridge token is visible from ``session`` (joined over IP)."""
    return any(r.ok is not None for r in session.liveliness().get(
        f"@zab/zspace/{node}/bridge", timeout=1.0))


def wait_for(check: Callable[[], bool], timeout: float) -> bool:
    deadline = time.time() + timeout
    while time.time() < deadline:
        if check():
            return True
        time.sleep(0.2)
    return False


def test_zab_sim_puts_a_surfaced_vehicle_on_the_surface_wifi_and_takes_it_off(
        tmp_path: Path) -> None:
    data = yaml.safe_load((MISSIONS / "zspace.yaml").read_text())
    for name in ("top", "auv1"):  # as the deploy kit runs them: routers
        data["nodes"][name]["zenoh"] = {"mode": "router", "scouting/gossip/enabled": False,
                                        "scouting/delay": 0}
    data["nodes"]["auv1"]["path"] = {  # at the surface ~[3.9, 20.1] s after the water starts
        "waypoints": [{"x": 40, "y": 30, "depth": 4}, {"x": 40, "y": 30, "depth": 0},
                      {"x": 40, "y": 46, "depth": 0}, {"x": 40, "y": 46, "depth": 10}],
        "speed_mps": 1.0}
    path, endpoints = mission_file(yaml.safe_dump(data, sort_keys=False), tmp_path)
    with zab_sim(path, endpoints):
        auv1, top = plain_app(endpoints["auv1"]), plain_app(endpoints["top"])
        try:
            got: list[dict] = []
            top.declare_subscriber("auv1/status", lambda s: got.append(
                msgpack.unpackb(s.payload.to_bytes())))
            assert wait_for(lambda: token_seen(top, "auv1"), 15.0)  # surfaced: on the WiFi
            time.sleep(1.0)  # both bridges switch over
            put(auv1, "auv1/status", {"battery": 66.6, "mode": "transit"})
            time.sleep(2 * CYCLE_S)  # latching every 2 s: acoustic copies would show here
            assert got == [{"battery": 66.6, "mode": "transit"}]  # over IP, unquantised, once
            got.clear()
            assert wait_for(lambda: not token_seen(top, "auv1"), 20.0)  # dived
            assert wait_for(lambda: bool(got), 2 + 2 * CYCLE_S)
            assert got[0] == {"battery": 67, "mode": "transit"}  # latched, acoustic again
        finally:
            auv1.close()
            top.close()


def test_two_vehicles_surfaced_at_once_keep_their_own_values(tmp_path: Path) -> None:
    """auv1 and auv2 up together: one Zenoh joins all three nodes. With inputs read on bare
    keys (``status``), auv2's bridge took auv1's status as its own: auv1's value came out as
    auv2/status, and stayed auv2's latched state after the dive. Each vehicle's inputs are
    under its own name now, and every value keeps its sender, over IP and after the dive."""
    data = yaml.safe_load(ZSPACE.read_text())
    for name in ("top", "auv1", "auv2"):  # as the deploy kit runs them: routers
        data["nodes"][name]["zenoh"] = {"mode": "router", "scouting/gossip/enabled": False,
                                        "scouting/delay": 0}
    mission, endpoints = mission_file(yaml.safe_dump(data, sort_keys=False), tmp_path)
    with zab_sim(mission, endpoints):
        auv1, auv2 = plain_app(endpoints["auv1"]), plain_app(endpoints["auv2"])
        top = plain_app(endpoints["top"])
        wifi = None
        try:
            got: dict[str, list[dict]] = {"auv1/status": [], "auv2/status": []}
            for key, values in got.items():
                top.declare_subscriber(key, lambda s, v=values: v.append(
                    msgpack.unpackb(s.payload.to_bytes())))
            wifi = access_point(endpoints["top"] + endpoints["auv1"] + endpoints["auv2"])
            assert wait_for(lambda: token_seen(top, "auv1") and token_seen(top, "auv2"), 10.0)
            time.sleep(2.0)  # the bridges switch over
            put(auv1, "auv1/status", {"battery": 11.0, "mode": "survey"})
            put(auv2, "auv2/status", {"battery": 22.0, "mode": "transit"})
            time.sleep(2 * CYCLE_S)
            assert got == {"auv1/status": [{"battery": 11.0, "mode": "survey"}],
                           "auv2/status": [{"battery": 22.0, "mode": "transit"}]}
            wifi.close()
            wifi = None
            assert wait_for(lambda: not token_seen(top, "auv1"), 15.0)
            for values in got.values():
                values.clear()
            assert wait_for(lambda: all(got.values()), 3 * CYCLE_S)  # latched, acoustic
            assert got["auv1/status"][0] == {"battery": 11, "mode": "survey"}
            assert got["auv2/status"][0] == {"battery": 22, "mode": "transit"}
        finally:
            if wifi is not None:
                wifi.close()
            for session in (auv1, auv2, top):
                session.close()


def test_a_get_while_the_vehicle_is_surfaced_is_answered_once_over_ip_at_once(
        tmp_path: Path) -> None:
    """The serving vehicle up: Zenoh carries the get to its queryable over IP; the surface
    bridge's queryable for the key ends at once without a reply and asks nothing across the
    water (it used to: a second, quantised reply seconds later, and the vehicle's bridge asked
    its queryable again). A query whose ``local_key`` is another key is got there over IP by
    the surface bridge, each reply handed on as it came. After the dive the get crosses the
    water again."""
    data = yaml.safe_load(ZSPACE.read_text())
    for name in ("top", "auv1"):  # as the deploy kit runs them: routers
        data["nodes"][name]["zenoh"] = {"mode": "router", "scouting/gossip/enabled": False,
                                        "scouting/delay": 0}
    data["queries"].append({**data["queries"][0], "name": "card", "key": "{node}/card",
                            "local_key": "{node}/info"})
    mission, endpoints = mission_file(yaml.safe_dump(data, sort_keys=False), tmp_path)
    exact = {"depth_m": 1.25, "state": "survey", "detail": 1}  # crosses the water as 1.5
    with zab_sim(mission, endpoints):
        auv1, top = plain_app(endpoints["auv1"]), plain_app(endpoints["top"])
        wifi = None
        try:
            calls: list[float] = []

            def answer(query) -> None:
                calls.append(time.time())
                query.reply(query.key_expr, msgpack.packb(exact))
                query.drop()

            auv1.declare_queryable("auv1/info", answer)
            wifi = access_point(endpoints["top"] + endpoints["auv1"])
            assert wait_for(lambda: token_seen(top, "auv1"), 10.0)
            time.sleep(2.0)  # the bridges switch over

            def every_reply(key: str = "auv1/info") -> tuple[list, list[str], float]:
                started = time.time()
                replies = list(top.get(f"{key}?detail=1", timeout=15.0,
                                       consolidation=zenoh.ConsolidationMode.NONE))
                return ([(str(r.ok.key_expr), msgpack.unpackb(r.ok.payload.to_bytes()))
                         for r in replies if r.ok],
                        [r.err.payload.to_string() for r in replies if r.err],
                        time.time() - started)

            values, errors, took = every_reply()
            assert values == [("auv1/info", exact)] and not errors  # once, unquantised
            assert took < 2.0, took  # (milliseconds; across the water 2 s and more)
            values, errors, took = every_reply("auv1/card")  # got on auv1/info over IP
            assert values == [("auv1/card", exact)] and not errors and took < 2.0, took
            time.sleep(CYCLE_S)  # an acoustic request would have reached auv1 by now
            assert len(calls) == 2
            wifi.close()
            wifi = None
            assert wait_for(lambda: not token_seen(top, "auv1"), 15.0)  # dived
            deadline = time.time() + 20  # until the surface has heard auv1 (links up)
            while True:
                values, errors, took = every_reply()
                if values or time.time() > deadline or "link down" not in " ".join(errors):
                    break
                time.sleep(1.0)
            assert values == [("auv1/info", {**exact, "depth_m": 1.5})] and not errors
            assert took > 0.5
        finally:
            if wifi is not None:
                wifi.close()
            auv1.close()
            top.close()
