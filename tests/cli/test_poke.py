"""`zab listen`, `zab put` and the README's program, against a running simulated fleet."""

from __future__ import annotations

import re
import subprocess
import sys
import time
from pathlib import Path

import msgpack

from bridge.cli.poke import format_sample
from tests.conftest import REPO, on_free_ports
from tests.gui.fleet import MISSION, VehicleApps
from tests.harness import outside_session, running_fleet

ZAB = [sys.executable, "-m", "bridge"]


def endpoint(loaded, node: str) -> str:
    return loaded.mission.nodes[node].zenoh.listen[0]


def test_put_crosses_the_water_and_listen_prints_it_decoded() -> None:
    """`zab put` at auv1's endpoint; its value comes out at the surface, where `zab listen`
    prints it on one line, decoded and quantised."""
    loaded = on_free_ports(MISSION, "guitest.yaml")
    with running_fleet(loaded):
        listener = subprocess.Popen(
            [*ZAB, "listen", endpoint(loaded, "ssv"), "auv1/nav", "--count", "1",
             "--duration", "40"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            assert listener.stderr is not None
            assert "listening on auv1/nav" in listener.stderr.readline()  # subscriber is up
            put = subprocess.run(
                [*ZAB, "put", endpoint(loaded, "auv1"), "nav",
                 '{"x": 12.34, "y": -5.06, "depth": 7.5}'],
                capture_output=True, text=True, timeout=30)
            assert put.returncode == 0, put.stderr
            assert "put nav (" in put.stdout
            out, errors = listener.communicate(timeout=45)
        finally:
            if listener.poll() is None:
                listener.kill()
                listener.communicate()
    assert listener.returncode == 0, errors
    assert out.splitlines() == ['auv1/nav {"x": 12.3, "y": -5.1, "depth": 7.5}']


def test_put_sets_the_msgpack_encoding() -> None:
    loaded = on_free_ports(MISSION, "guitest.yaml")
    with running_fleet(loaded):
        session = outside_session(loaded, "auv1")
        seen = []
        try:
            session.declare_subscriber("poke/test", lambda s: seen.append(
                (str(s.encoding), msgpack.unpackb(s.payload.to_bytes()))))
            done = subprocess.run([*ZAB, "put", endpoint(loaded, "auv1"), "poke/test",
                                   '{"a": [1, 2.5, "x"]}'], capture_output=True, text=True,
                                  timeout=30)
            deadline = time.time() + 5
            while not seen and time.time() < deadline:
                time.sleep(0.05)
        finally:
            session.close()
    assert done.returncode == 0, done.stderr
    assert seen == [("application/msgpack", {"a": [1, 2.5, "x"]})]


def test_bad_arguments_and_a_dead_endpoint_exit_cleanly() -> None:
    bad_json = subprocess.run([*ZAB, "put", "tcp/127.0.0.1:9", "k", "{x"],
                              capture_output=True, text=True, timeout=30)
    assert bad_json.returncode == 2 and "not JSON" in bad_json.stderr
    dead = subprocess.run([*ZAB, "listen", "tcp/127.0.0.1:9", "--duration", "1"],
                          capture_output=True, text=True, timeout=30)
    assert dead.returncode == 1 and "cannot connect to tcp/127.0.0.1:9" in dead.stderr
    assert "Traceback" not in dead.stderr + bad_json.stderr


def test_listen_decodes_json_and_rounds_float_noise() -> None:
    assert format_sample("a/b", b'{"v": 9.536743164062498e-08}', "application/json") == \
        'a/b {"v": 9.53674316e-08}'
    assert format_sample("a/b", msgpack.packb({"x": 0.30000000000000004}),
                         "application/msgpack") == 'a/b {"x": 0.3}'


def readme_program() -> str:
    text = (REPO / "README.md").read_text(encoding="utf-8")
    found = re.search(r"<!-- readme-program:.*?-->\n```python\n(.*?)```", text, re.S)
    assert found, "README has no marked program"
    return found.group(1)


def test_the_readme_program_runs_against_a_simulated_fleet(tmp_path: Path) -> None:
    """The exact README text, given the surface's endpoint of a small simulated fleet whose
    vehicles publish navigation: five lines of navigation, then a clean exit."""
    program = tmp_path / "first.py"
    program.write_text(readme_program(), encoding="utf-8")
    loaded = on_free_ports(MISSION, "guitest.yaml")
    with running_fleet(loaded), VehicleApps(loaded):
        done = subprocess.run([sys.executable, str(program), endpoint(loaded, "ssv")],
                              capture_output=True, text=True, timeout=90)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert len(lines) == 5
    for line in lines:
        assert re.fullmatch(r"auv[12]/nav: x -?\d+\.\d m, y -?\d+\.\d m, depth \d+\.\d m", line)


def test_the_readme_program_says_so_when_nothing_listens(tmp_path: Path) -> None:
    program = tmp_path / "first.py"
    program.write_text(readme_program(), encoding="utf-8")
    done = subprocess.run([sys.executable, str(program), "tcp/127.0.0.1:9"],
                          capture_output=True, text=True, timeout=30)
    assert done.returncode != 0
    assert "Unable to connect" in done.stderr
