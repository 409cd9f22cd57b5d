"""`zab put` with a value its key's payload cannot hold: one line and exit 2, never a traceback.

Found with a table-driven probe of :func:`bridge.cli.poke.payload_for` (every value below, at
the top and at every field of ROS 2 messages, and on plain keys): an integer beyond msgpack's
64 bits, or a string with a lone surrogate (JSON's ``"\\ud800"``), raised OverflowError or
UnicodeEncodeError out of msgpack, and JSON nested past Python's stack a RecursionError.
"""

from __future__ import annotations

import json
from typing import Any

import pytest
from typer.testing import CliRunner

from bridge.cli.app import app
from bridge.cli.poke import PokeError, payload_for
from bridge.ros2.messages import decode_cdr, encode_cdr, type_hash
from bridge.ros2.names import topic_key
from tests.conftest import MISSIONS

DEAD = "tcp/127.0.0.1:9"  # (never reached: a value that cannot be sent is refused before)
PLAIN = "auv1/nav"
DISTRO = "jazzy"
TYPES = ["nav_msgs/msg/Odometry", "geometry_msgs/msg/Twist", "std_msgs/msg/String",
         "sensor_msgs/msg/NavSatFix", "sensor_msgs/msg/CompressedImage", "std_msgs/msg/UInt64",
         "std_msgs/msg/Float32MultiArray"]
VALUES = ["5", "-1", "1.5", "1e400", "NaN", "18446744073709551616", "-9223372036854775809",
          '"s"', '""', '"\\ud800"', "[]", "[1, 2]", '[1.5, "x"]', "[[1]]", '[{"a": 1}]',
          "[null]", "{}", '{"a": 1}', '{"\\udc00": 1}', "null", "true",
          "[18446744073709551616]"]


def ros2_key(msgtype: str) -> str:
    return topic_key(0, "/probe", msgtype, type_hash(DISTRO, msgtype))


def field_paths(tree: dict[str, Any], prefix: str = "") -> list[str]:
    """Every dotted field path of a message's plain data."""
    out = []
    for name, value in tree.items():
        path = f"{prefix}{name}"
        out.append(path)
        if isinstance(value, dict):
            out += field_paths(value, f"{path}.")
    return out


def nest(path: str, value: Any) -> Any:
    for part in reversed(path.split(".")):
        value = {part: value}
    return value


def test_no_value_anywhere_raises_anything_but_a_one_line_poke_error() -> None:
    """The probe: each value at the top and at every field of each type, and on a plain key
    (msgpack) at the top and nested."""
    cases = [(PLAIN, json.loads(v)) for v in VALUES] + \
        [(PLAIN, {"x": [1, json.loads(v)]}) for v in VALUES]
    for msgtype in TYPES:
        key = ros2_key(msgtype)
        default = decode_cdr(DISTRO, msgtype, encode_cdr(DISTRO, msgtype, {}))
        cases += [(key, json.loads(v)) for v in VALUES]
        cases += [(key, nest(path, json.loads(v)))
                  for path in field_paths(default) for v in VALUES]
    refused = 0
    for key, value in cases:
        try:
            payload_for(key, value)
        except PokeError as exc:
            assert "\n" not in str(exc) and str(exc).startswith(f"cannot put on {key}: ")
            refused += 1
    assert len(cases) > 1800 and refused > 900


@pytest.mark.parametrize(("key", "value", "says"), [
    (PLAIN, "18446744073709551616",
     "18446744073709551616 is beyond msgpack's integers (-2**63 to 2**64 - 1)"),
    (PLAIN, '{"x": [1.5, -9223372036854775809]}', "x.1: -9223372036854775809 is beyond"),
    (PLAIN, '"\\ud800"', "'\\ud800' is not UTF-8 text (a lone surrogate"),
    (PLAIN, '{"a": {"\\udc00": 1}}', "a: the name '\\udc00' is not UTF-8 text"),
    (PLAIN, "[" * 5000 + "]" * 5000, "the value is nested too deeply to read"),
    (ros2_key("geometry_msgs/msg/Twist"), "5",
     "expected the message's fields as an object"),
    (ros2_key("geometry_msgs/msg/Twist"), '{"linear": 5}',
     "linear: expected a mapping for geometry_msgs/msg/Vector3, got int"),
    (ros2_key("geometry_msgs/msg/Twist"), '{"linear": {"x": "fast"}}',
     "linear.x: expected a number, got str"),
    (ros2_key("std_msgs/msg/String"), '{"data": {"a": 1}}', "data: expected a string, got dict"),
    (ros2_key("std_msgs/msg/UInt64"), '{"data": 18446744073709551616}',
     "data: 18446744073709551616 does not fit a uint64"),
    (ros2_key("nav_msgs/msg/Odometry"), '{"pose": {"covariance": [1, 2]}}',
     "pose.covariance: needs 36 values, got 2"),
    (ros2_key("sensor_msgs/msg/CompressedImage"), '{"data": "abc"}',
     "data: expected a list, got str"),
], ids=["uint64+1", "nested-int64-1", "lone-surrogate", "surrogate-name", "nested-5000",
        "ros2-int-message", "ros2-int-field-message", "ros2-string-number", "ros2-dict-string",
        "ros2-uint64+1", "ros2-covariance-count", "ros2-string-bytes"])
def test_zab_put_refuses_a_value_its_key_cannot_hold_in_one_line(key: str, value: str,
                                                                   says: str) -> None:
    result = CliRunner().invoke(app, ["put", DEAD, key, value])
    assert result.exception is None or isinstance(result.exception, SystemExit), \
        result.exception
    assert result.exit_code == 2, result.output
    said = " ".join(result.output.split())  # (rich wraps long lines)
    assert says in said, said
    assert "Traceback" not in result.output and "cannot connect" not in result.output


TWIST = "geometry_msgs/msg/Twist"


@pytest.mark.parametrize(("value", "says", "known"), [
    ('{"nonexistent": 1}',
     f"no field 'nonexistent' in {TWIST} (its fields: linear, angular)", {}),
    ('{"linear": {"x": 1, "q": 2}}',
     "linear: no field 'q' in geometry_msgs/msg/Vector3 (its fields: x, y, z)",
     {"linear": {"x": 1}}),
], ids=["top", "nested"])
def test_zab_put_refuses_a_field_the_ros2_type_has_not(value: str, says: str,
                                                        known: dict) -> None:
    """A name the key's ROS 2 type has not was dropped silently: the CDR sent had none of
    it. The bridge's own encoding still ignores such names (an application's extras)."""
    result = CliRunner().invoke(app, ["put", DEAD, ros2_key(TWIST), value])
    assert result.exit_code == 2 and says in " ".join(result.output.split()), result.output
    assert encode_cdr(DISTRO, TWIST, json.loads(value)) == encode_cdr(DISTRO, TWIST, known)


@pytest.mark.parametrize(("mission", "key", "value", "says"), [
    ("goby_dccl", "command/topside", '{"mode": "dive", "nonexistent": 1}',
     "channel 'command' has no field 'nonexistent' (its fields: mode, goto_lat, goto_lon, "
     "note)"),
    ("goby_dccl", "command/topside", "5",
     "channel 'command': zab.auv.Command: expected a mapping, got int"),
    ("goby_dccl", "nav_status", '{"lat": 1}', "channel 'nav': lon: required field missing"),
    ("goby_dccl", "command/topside", '{"mode": "swim"}', "mode: 'swim' is not one of"),
    ("morph", "target_reference", '{"vector": {"x": 1, "q": 2}}',
     "channel 'target_reference' has no field 'q' in vector (its fields there: x, y)"),
    ("morph", "nav", '{"x": "far"}', "channel 'nav': x: expected a number, got str 'far'"),
    ("morph", "command", '"surface"', "channel 'mission_command': "),
], ids=["dccl-unknown", "dccl-int", "dccl-missing", "dccl-enum", "unknown", "string-number",
        "string-map"])
def test_zab_put_with_the_mission_refuses_what_its_channels_cannot_take(
        mission: str, key: str, value: str, says: str) -> None:
    """Without the mission zab put cannot know a DCCL or msgpack channel's fields: it sent
    the value and the bridge dropped it (counted, at the vehicle). With --mission it says
    why, and sends nothing."""
    path = str(MISSIONS / f"{mission}.yaml")
    result = CliRunner().invoke(app, ["put", DEAD, key, value, "--mission", path])
    assert result.exit_code == 2, result.output
    said = " ".join(result.output.split())
    assert said.startswith(f"cannot put on {key}: ") and says in said, said
    fits = CliRunner().invoke(app, ["put", DEAD, key, {
        "command/topside": '{"mode": "dive", "note": "hi"}', "nav_status": json.dumps(
            {"lat": 1, "lon": 2, "depth": 3, "heading": 4, "speed": 1, "battery": 5,
             "mode": "idle", "time": 6}), "target_reference": '{"vector": {"x": 1, "y": 0}}',
        "nav": '{"x": 1, "y": 2, "depth": 3, "heading": 4, "speed": 1}',
        "command": '{"action": "surface", "leg": 3}'}[key], "--mission", path])
    assert "cannot connect to" in fits.output, fits.output  # (checked, then sent)


IMAGES = str(MISSIONS / "bluerov_images.yaml")


@pytest.mark.parametrize(("key", "value", "says"), [
    ("camera/control", '{"width": 4000}', "image control 'camera': width 4000 is outside "
     "8..2048"),
    ("camera/control", '{"colour": true}', "image control 'camera': unknown control colour"),
    ("camera/control", '{"request": "sometime"}', "request 'sometime' is none of none, now, "
     "cancel"),
    ("camera/control", '{"budget_bytes": 99999}', "budget_bytes 99999 is outside 37..6400 "
     "(the channel's max_budget_bytes)"),
    ("camera/control", '{"roi": [0.5, 0.5, 0.5, 0.5]}', "is empty (x1 must be > x0"),
    ("camera/control", "5", "a control is a map"),
    ("rov/camera", '{"a": 1}', "image channel 'camera' takes pictures there: JPEG or PNG "
     "bytes (image/jpeg, image/png), which zab put does not send"),
], ids=["width", "unknown", "request", "budget", "roi", "not-a-map", "picture-key"])
def test_zab_put_with_the_mission_checks_an_image_channel_s_keys(key: str, value: str,
                                                                  says: str) -> None:
    """An image control the camera would not follow was sent, then dropped by the bridge as
    unfit (counted there); JSON on the camera's picture key likewise. With --mission, zab put
    refuses it as the bridge would, and sends nothing."""
    result = CliRunner().invoke(app, ["put", DEAD, key, value, "--mission", IMAGES])
    said = " ".join(result.output.split())
    assert result.exit_code == 2 and said.startswith(f"cannot put on {key}: "), said
    assert says in said, said
    fits = CliRunner().invoke(app, ["put", DEAD, "camera/control",
                                    '{"request": "now", "width": 80, "roi": [0, 0, 0.5, 0.5]}',
                                    "--mission", IMAGES])
    assert "cannot connect to" in fits.output, fits.output  # (checked, then sent)
