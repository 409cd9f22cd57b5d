"""`zab listen`, `zab put` and the README's program, against a running simulated fleet."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from pathlib import Path

import msgpack
import pytest

from bridge.cli.poke import format_sample
from tests.conftest import REPO, on_free_ports
from tests.gui.fleet import MISSION
from tests.harness import outside_session, running_fleet

ZAB = [sys.executable, "-m", "bridge"]


def endpoint(loaded, node: str) -> str:
    return loaded.mission.nodes[node].zenoh.listen[0]


def put_and_listen(loaded, listen: tuple[str, str], put: tuple[str, str, str]) -> str:
    """`zab listen` at ``listen`` (node, key expression) until one value comes, and `zab put`
    at ``put`` (node, key, JSON value), against the running fleet of ``loaded``; returns what
    `zab listen` printed (both exit 0)."""
    listener = subprocess.Popen(
        [*ZAB, "listen", endpoint(loaded, listen[0]), listen[1], "--count", "1",
         "--duration", "90"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert listener.stderr is not None
        assert "listening on" in listener.stderr.readline()  # the subscriber is up
        done = subprocess.run([*ZAB, "put", endpoint(loaded, put[0]), put[1], put[2]],
                              capture_output=True, text=True, timeout=60)  # (7 s on a quiet
        # machine, 30 s was seen on CI's 2 loaded cores)
        assert done.returncode == 0, done.stderr
        assert f"put {put[1]} (" in done.stdout.replace("\n", "")  # (rich wraps long keys)
        out, errors = listener.communicate(timeout=100)
    finally:
        if listener.poll() is None:
            listener.kill()
            listener.communicate()
    assert listener.returncode == 0, errors
    return out


def test_put_crosses_the_water_and_listen_prints_it_decoded() -> None:
    """`zab put` at auv1's endpoint; its value comes out at the surface, where `zab listen`
    prints it on one line, decoded and quantised."""
    loaded = on_free_ports(MISSION, "guitest.yaml")
    with running_fleet(loaded):
        out = put_and_listen(loaded, ("ssv", "auv1/nav"),
                             ("auv1", "nav", '{"x": 12.34, "y": -5.06, "depth": 7.5}'))
    assert out.splitlines() == ['auv1/nav {"x": 12.3, "y": -5.1, "depth": 7.5}']


def test_put_sets_the_msgpack_encoding() -> None:
    loaded = on_free_ports(MISSION, "guitest.yaml")
    with running_fleet(loaded):
        session = outside_session(loaded, "auv1")
        seen = []
        try:
            session.declare_subscriber("poke/test", lambda s: seen.append(
                (str(s.encoding), msgpack.unpackb(s.payload.to_bytes()),
                 s.attachment.to_bytes() if s.attachment is not None else b"")))
            done = subprocess.run([*ZAB, "put", endpoint(loaded, "auv1"), "poke/test",
                                   '{"a": [1, 2.5, "x"]}'], capture_output=True, text=True,
                                  timeout=30)
            deadline = time.time() + 5
            while not seen and time.time() < deadline:
                time.sleep(0.05)
        finally:
            session.close()
    assert done.returncode == 0, done.stderr
    [(encoding, value, attachment)] = seen
    assert (encoding, value) == ("application/msgpack", {"a": [1, 2.5, "x"]})
    # an operator's command, as the GUI's: the reference it printed, for delivery reports
    ref = re.search(r"\(\d+ B msgpack, ref (put-[0-9a-f]{8})\)", done.stdout)
    assert ref and attachment == f"ref:{ref.group(1)}".encode(), done.stdout


def test_bad_arguments_and_a_dead_endpoint_exit_cleanly() -> None:
    bad_json = subprocess.run([*ZAB, "put", "tcp/127.0.0.1:9", "k", "{x"],
                              capture_output=True, text=True, timeout=30)
    assert bad_json.returncode == 2 and "not JSON" in bad_json.stderr
    dead = subprocess.run([*ZAB, "listen", "tcp/127.0.0.1:9", "--duration", "1"],
                          capture_output=True, text=True, timeout=30)
    assert dead.returncode == 1 and "cannot connect to tcp/127.0.0.1:9" in dead.stderr
    said = " ".join(dead.stderr.split())  # a vehicle's endpoint: no router advice, no config
    assert "nothing answers there: is a vehicle's bridge running (zab demo, zab sim, zab " \
        "run)?" in said and "zenohd" not in said and "zenoh.connect" not in said, said
    assert "Traceback" not in dead.stderr + bad_json.stderr


def test_listen_decodes_json_and_rounds_float_noise() -> None:
    assert format_sample("a/b", b'{"v": 9.536743164062498e-08}', "application/json") == \
        'a/b {"v": 9.53674316e-08}'
    assert format_sample("a/b", msgpack.packb({"x": 0.30000000000000004}),
                         "application/msgpack") == 'a/b {"x": 0.3}'
    # a Unix time keeps its milliseconds (9 digits printed 1795813660.9 as 1795813660.0)
    assert format_sample("a/b", msgpack.packb({"time": 1795813660.9173}),
                         "application/msgpack") == 'a/b {"time": 1795813660.917}'


def test_listen_prints_a_picture_as_its_caption_not_its_bytes() -> None:
    """`zab listen` on an image channel's key printed each PNG as 12 kB of hex on one line."""
    import numpy as np

    from bridge.image.formats import write_image

    meta = {"zab:channel": "camera", "zab:bytes": "407", "zab:final": "false",
            "zab:roi": "[0.25, 0.25, 0.75, 0.75]", "zab:psnr_estimate": "31.2"}
    said = ('"zab:bytes": 407, "zab:channel": "camera", "zab:final": false, '
            '"zab:psnr_estimate": 31.2, "zab:roi": [0.25, 0.25, 0.75, 0.75]}')
    png = write_image(np.zeros((120, 160), np.uint8), "png", text=meta)
    assert format_sample("rov/camera", png, "image/png") == (
        'rov/camera {"picture": "png", "size": [160, 120], "mode": "L", '
        f'"length": {len(png)}, {said}')
    jpeg = write_image(np.zeros((120, 160, 3), np.uint8), "jpeg", text=meta)  # (a comment)
    assert format_sample("rov/camera", jpeg, "") == (
        'rov/camera {"picture": "jpeg", "size": [160, 120], "mode": "RGB", '
        f'"length": {len(jpeg)}, {said}')
    # a camera's own JPEG inside a message, a cut picture, and other long bytes
    assert format_sample("cam", msgpack.packb({"format": "jpeg", "data": jpeg}), "") == (
        f'cam {{"format": "jpeg", "data": {{"picture": "jpeg", "size": [160, 120], '
        f'"mode": "RGB", "length": {len(jpeg)}, {said}}}')
    assert format_sample("rov/camera", png[:40], "image/png") == \
        'rov/camera {"picture": "unreadable", "length": 40}'
    assert format_sample("x", bytes(range(200)), "") == \
        f'x {{"bytes": "{bytes(range(32)).hex()}... (200 bytes)"}}'
    short = bytes(range(192, 256))  # (64 bytes: whole)
    assert format_sample("x", short, "") == f'x {{"bytes": "{short.hex()}"}}'


def test_listen_with_the_mission_prints_each_field_to_its_channel_s_step() -> None:
    from bridge.cli.rounding import Steps
    from bridge.core.loaded import load_mission
    from tests.conftest import MISSIONS

    steps = Steps(load_mission(MISSIONS / "morph.yaml"))
    noisy = msgpack.packb({"vector": {"x": 3.25242824, "y": 0.0207777294}})
    # x: 8 bits, step 0.0246; y: 6 bits, step 0.00166 (zab check)
    assert format_sample("lsv/target_reference", noisy, "application/msgpack", steps) == \
        'lsv/target_reference {"vector": {"x": 3.252, "y": 0.0208}}'
    nav = msgpack.packb({"x": 20.400000000000002, "heading": 14, "speed": 0.8000000000000003})
    assert format_sample("gcv/nav", nav, "application/msgpack", steps) == \
        'gcv/nav {"x": 20.4, "heading": 14, "speed": 0.8}'
    # a key no channel publishes keeps its digits (up to 9 significant ones)
    assert format_sample("my/key", noisy, "application/msgpack", steps) == \
        'my/key {"vector": {"x": 3.25242824, "y": 0.0207777294}}'


def test_listen_takes_the_mission_and_refuses_a_bad_one(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("mission: [")
    done = subprocess.run([*ZAB, "listen", "tcp/127.0.0.1:9", "--mission", str(bad)],
                          capture_output=True, text=True, timeout=30)
    assert done.returncode == 2 and "invalid mission" in done.stderr
    assert "Traceback" not in done.stderr


def readme_program() -> str:
    text = (REPO / "README.md").read_text(encoding="utf-8")
    found = re.search(r"<!-- readme-program:.*?-->\n```python\n(.*?)```", text, re.S)
    assert found, "README has no marked program"
    return found.group(1)


def test_the_readme_program_says_so_when_nothing_listens(tmp_path: Path) -> None:
    program = tmp_path / "first.py"
    program.write_text(readme_program(), encoding="utf-8")
    done = subprocess.run([sys.executable, str(program), "tcp/127.0.0.1:9"],
                          capture_output=True, text=True, timeout=30)
    assert done.returncode != 0
    assert "Unable to connect" in done.stderr


def test_a_ros2_topic_s_cdr_prints_as_its_message(mission_key: str) -> None:
    """`zab listen` at ros2_odometry's ship printed each Odometry as {"bytes": "0001..."}:
    the type is in the rmw_zenoh key, so the message prints decoded."""
    from bridge.core.loaded import load_mission
    from tests.conftest import MISSIONS

    odom = load_mission(MISSIONS / "ros2_odometry.yaml").table.by_name("odom").elements[0]
    assert odom.ros2 is not None
    key = odom.output_key("auv1", "ship")
    data = odom.ros2.encode({"pose": {"pose": {"position": {"x": 12.5}}}}, 100.0)
    line = format_sample(key, data, "")
    assert line.startswith(key + " {") and '"x": 12.5' in line and '"frame_id": "odom"' in line
    assert '"pose"' not in format_sample(key, b"\x00\x01\x00\x00\x07", "")  # malformed: raw


def test_put_on_a_ros2_topic_key_sends_its_cdr(mission_key: str) -> None:
    """`zab put` on ros2_odometry's cmd_vel key sent msgpack, which the bridge drops ('not a
    CDR Twist'): on an rmw_zenoh key the value goes as the message the key names."""
    from bridge.cli.poke import PokeError, payload_for
    from bridge.core.loaded import load_mission
    from bridge.runtime.virtual_fleet import FastFleet
    from tests.conftest import MISSIONS

    loaded = load_mission(MISSIONS / "ros2_odometry.yaml")
    cmd = loaded.table.by_name("cmd_vel").elements[0]
    assert cmd.ros2 is not None
    key = cmd.ros2.publisher_key("ship")
    payload, encoding = payload_for(key, {"linear": {"x": 0.5}, "angular": {"z": 0.1}})
    assert encoding == ""
    core = FastFleet(loaded, seed=1).cores["ship"]
    taken = next(k for k in core.bindings if core.ros2_input(k) is not None)
    core.ingest(taken, payload, encoding, 10.0, sample_key=key)
    assert not core.stats.payloads_dropped
    assert payload_for("a/b", {"x": 1}) == (msgpack.packb({"x": 1}), "application/msgpack")
    with pytest.raises(PokeError, match="expected the message's fields"):
        payload_for(key, [1, 2])


def test_zab_put_on_a_ros2_key_crosses_and_zab_listen_prints_the_twist() -> None:
    """Real processes on a ROS 2 mission: `zab put` of a Twist on the key a ROS 2 node at the
    ship publishes /auv1/cmd_vel_remote on; `zab listen` at the vehicle prints the Twist its
    bridge publishes on /auv1/cmd_vel (CDR, read by the type the key names)."""
    from tests.conftest import MISSIONS

    loaded = on_free_ports((MISSIONS / "ros2_odometry.yaml").read_text(), "ros2_odometry.yaml")
    cmd = loaded.table.by_name("cmd_vel").elements[0]
    assert cmd.ros2 is not None
    with running_fleet(loaded):
        out = put_and_listen(loaded, ("auv1", "0/auv1/cmd_vel/**"), (
            "ship", cmd.ros2.publisher_key("ship"),
            '{"linear": {"x": 0.5, "z": -0.25}, "angular": {"z": 0.1}}'))
    [line] = out.splitlines()
    key, _, value = line.partition(" ")
    assert key == cmd.ros2.out_key, key  # (/auv1/cmd_vel: no {src} or {node} in it)
    assert '"linear": {"x": 0.5, "y": 0.0, "z": -0.25}' in value, value


BAD_KEYS = {  # a key, and what zab put and zab listen say is wrong with it (the mission
    # file's words: bridge.mission.keyexpr)
    "a//b": "empty chunk: '//' (write 'a/b')",
    "/a": "empty chunk: a leading '/' (write 'a')",
    "a/b/": "empty chunk: a trailing '/' (write 'a/b')",
    "": "empty",
    "a?b": "'?' is forbidden",
    "a/*b": "'*' only as a whole chunk ('*' or '**') or in '$*', not '*b'",
    "a/**b": "'*' only as a whole chunk ('*' or '**') or in '$*', not '**b'",
    "a/$b": "'$' only in '$*' (a wildcard inside a chunk), not '$b'",
    "a/**/**": "not canonical (write 'a/**')",
}


@pytest.mark.parametrize("key", BAD_KEYS)
def test_a_bad_key_is_said_in_words(key: str) -> None:
    from bridge.cli.poke import key_problem

    said = key_problem(key)
    assert said is not None and BAD_KEYS[key] in said, said
    assert "Invalid Key Expr" not in said and ".rs:" not in said
    assert key_problem("robot/nav") is None and key_problem("robot/*/a$*b/**") is None


@pytest.mark.parametrize(("endpoint", "why"), [
    ("notanendpoint", "not <protocol>/<address>"),
    ("tcp/127.0.0.1", "no port"),
    ("tcp/127.0.0.1:notaport", "'notaport' is not a port"),
    ("tcp/127.0.0.1:70000", "'70000' is not a port"),
    ("tcp/:7447", "no host"),
    ("tcpp/127.0.0.1:7447", "unknown protocol 'tcpp'"),
])
def test_a_bad_endpoint_is_said_with_the_form_expected(endpoint: str, why: str) -> None:
    from bridge.cli.poke import endpoint_problem

    said = endpoint_problem(endpoint)
    assert said is not None and why in said and "tcp/127.0.0.1:7447" in said, said
    for good in ("tcp/127.0.0.1:7447", "tcp/[::1]:7447", "udp/10.0.0.2:7447",
                 "tcp/localhost:7447", "unixsock-stream//tmp/zenoh.sock"):
        assert endpoint_problem(good) is None, good


def _one_line_exit_2(*args: str) -> str:
    done = subprocess.run([*ZAB, *args], capture_output=True, text=True, timeout=30,
                          env={**os.environ, "COLUMNS": "80"})
    output = done.stdout + done.stderr
    assert done.returncode == 2, output
    for raw in ("Traceback", "Json5Err", "Invalid Key Expr", ".rs:", "ZError"):
        assert raw not in output, output
    [line] = done.stderr.strip().splitlines()
    return line


def test_zab_put_and_listen_say_what_is_wrong_with_a_key_or_an_endpoint() -> None:
    assert _one_line_exit_2("put", "tcp/127.0.0.1:9", "a//b", "1") == (
        "invalid key 'a//b': empty chunk: '//' (write 'a/b'); a key is chunks joined by '/', "
        "e.g. robot/nav")
    line = _one_line_exit_2("listen", "tcp/127.0.0.1:9", "a/**b")
    assert line.startswith("invalid key expression 'a/**b': '*' only as a whole chunk ('*' "
                           "or '**') or in '$*', not '**b'"), line
    for command in (("put", "notanendpoint", "k", "1"), ("listen", "notanendpoint", "k")):
        assert _one_line_exit_2(*command) == (
            "invalid endpoint 'notanendpoint': not <protocol>/<address>; expected a Zenoh "
            "endpoint such as tcp/127.0.0.1:7447")
