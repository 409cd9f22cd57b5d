"""Type hashes, CDR through rosbags, field selection and defaults of a ROS 2 element."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rosbags.typesys import Stores, get_typestore

from bridge.codec import Layout
from bridge.errors import DecodeError, EncodeError
from bridge.mission.ros2 import Ros2Topic
from bridge.ros2 import messages
from bridge.ros2.element import compile_ros2

JAZZY = get_typestore(Stores.ROS2_JAZZY)
ODOM = "nav_msgs/msg/Odometry"

# Published REP-2011 hashes: std_msgs/String from rmw_zenoh_cpp docs/design.md's key examples;
# the others as `ros2 topic info -v` prints them on Jazzy (golden values in public ROS 2 code).
GOLDEN = {
    "std_msgs/msg/String":
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
    "nav_msgs/msg/Odometry":
        "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0",
    "geometry_msgs/msg/Twist":
        "RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a",
    "geometry_msgs/msg/Pose":
        "RIHS01_d501954e9476cea2996984e812054b68026ae0bfae789d9a10b23daf35cc90fa",
    "sensor_msgs/msg/Imu":
        "RIHS01_7d9a00ff131080897a5ec7e26e315954b8eae3353c3f995c55faf71574000b5b",
}


@pytest.mark.parametrize("msgtype", sorted(GOLDEN))
def test_type_hashes_match_the_published_ones(msgtype: str) -> None:
    assert messages.type_hash("jazzy", msgtype) == GOLDEN[msgtype]


def odometry(x: float = 12.34, frame: str = "map") -> bytes:
    """A CDR Odometry as a ROS 2 publisher would send it (rosbags' own classes)."""
    t = JAZZY.types
    msg = t[ODOM](
        header=t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=5, nanosec=7),
                                        frame_id=frame),
        child_frame_id="base",
        pose=t["geometry_msgs/msg/PoseWithCovariance"](
            pose=t["geometry_msgs/msg/Pose"](
                position=t["geometry_msgs/msg/Point"](x=x, y=-5.5, z=-40.0),
                orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.5, w=0.75)),
            covariance=np.arange(36, dtype=np.float64)),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](
            twist=t["geometry_msgs/msg/Twist"](
                linear=t["geometry_msgs/msg/Vector3"](x=1.0, y=0.0, z=0.0),
                angular=t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.25)),
            covariance=np.zeros(36)))
    return bytes(JAZZY.serialize_cdr(msg, ODOM))


def test_decode_gives_plain_nested_data() -> None:
    plain = messages.decode_cdr("jazzy", ODOM, odometry())
    assert plain["pose"]["pose"]["position"] == {"x": 12.34, "y": -5.5, "z": -40.0}
    assert plain["header"] == {"stamp": {"sec": 5, "nanosec": 7}, "frame_id": "map"}
    assert plain["pose"]["covariance"] == [float(i) for i in range(36)]


def test_uint8_arrays_are_bytes_both_ways() -> None:
    data = messages.encode_cdr("jazzy", "sensor_msgs/msg/Image",
                               {"height": 1, "width": 3, "data": b"\x01\x02\xff"})
    image = JAZZY.deserialize_cdr(data, "sensor_msgs/msg/Image")
    assert image.data.tolist() == [1, 2, 255]
    assert messages.decode_cdr("jazzy", "sensor_msgs/msg/Image", data)["data"] == b"\x01\x02\xff"


@pytest.mark.parametrize("cut", [0, 3, 4, 20, 100, 300])
def test_truncated_cdr_is_a_decode_error(cut: int) -> None:
    with pytest.raises(DecodeError):
        messages.decode_cdr("jazzy", ODOM, odometry()[:cut])


def test_a_bad_encapsulation_header_is_a_decode_error() -> None:
    with pytest.raises(DecodeError, match="encapsulation"):
        messages.decode_cdr("jazzy", ODOM, b"\x7f\x01\x00\x00" + odometry()[4:])


def test_a_string_that_is_not_utf8_is_a_decode_error() -> None:
    data = messages.encode_cdr("jazzy", "std_msgs/msg/String", {"data": "abc"})
    with pytest.raises(DecodeError, match="utf-8"):
        messages.decode_cdr("jazzy", "std_msgs/msg/String", data.replace(b"abc", b"\xff\xfe!"))


def test_encode_refuses_values_that_do_not_fit() -> None:
    with pytest.raises(EncodeError, match=r"header\.stamp\.sec"):
        messages.encode_cdr("jazzy", ODOM, {"header": {"stamp": {"sec": 2**40}}})
    with pytest.raises(EncodeError, match="child_frame_id"):
        messages.encode_cdr("jazzy", ODOM, {"child_frame_id": 3})
    with pytest.raises(EncodeError, match=r"pose\.covariance: needs 36"):
        messages.encode_cdr("jazzy", ODOM, {"pose": {"covariance": [1.0, 2.0]}})


ARRAYS = {"uint8": "std_msgs/msg/UInt8MultiArray", "int16": "std_msgs/msg/Int16MultiArray",
          "uint32": "std_msgs/msg/UInt32MultiArray", "float32": "std_msgs/msg/Float32MultiArray"}


@settings(max_examples=300, deadline=None)
@given(st.sampled_from(sorted(ARRAYS)), st.lists(st.one_of(
    st.integers(-70_000, 70_000), st.integers(), st.booleans(), st.text(max_size=2),
    st.floats(-70_000, 70_000), st.floats(allow_nan=True, allow_infinity=True)), max_size=6))
def test_a_numeric_array_takes_each_value_as_a_field_does(base: str, values: list[object]
                                                          ) -> None:
    """Arrays go through numpy at once (a camera's megabytes took seconds one by one): each
    value as a single field of the type takes it (ints rounded, in range, bools and text
    refused), and a refusal names the first value that does not fit."""
    msgtype = ARRAYS[base]
    expected: list[object] = []
    refused = None
    for i, value in enumerate(values):
        try:
            expected.append(messages._scalar(base, value, f"data.{i}"))
        except EncodeError as exc:
            refused = str(exc)
            break
    if refused is not None:
        with pytest.raises(EncodeError) as exc_info:
            messages.encode_cdr("jazzy", msgtype, {"data": values})
        assert str(exc_info.value) == refused
        return
    got = messages.decode_cdr("jazzy", msgtype, messages.encode_cdr(
        "jazzy", msgtype, {"data": values}))["data"]
    if base == "uint8":
        assert got == bytes(expected)  # type: ignore[arg-type]
        return
    with np.errstate(over="ignore"):  # (beyond a float32: inf both ways)
        want = np.asarray(expected, dtype=np.float32 if base == "float32" else None)
    assert np.array_equal(np.asarray(got), want, equal_nan=base == "float32")  # (NaN is a float)


def test_a_picture_s_bytes_go_whole() -> None:
    data = bytes(range(256)) * 4000  # (a megabyte: one value at a time, about a second)
    message = messages.encode_cdr("jazzy", "sensor_msgs/msg/CompressedImage",
                                  {"format": "jpeg", "data": data})
    assert messages.decode_cdr("jazzy", "sensor_msgs/msg/CompressedImage",
                               message)["data"] == data


FIELDS = [
    {"field": "pose.pose.position.x", "min": -100, "max": 100, "resolution": 0.01},
    {"field": "pose.pose.position.z", "min": -100, "max": 0, "resolution": 0.1},
    {"field": "header.frame_id", "type": "string", "max_length": 8},
]


def element(**spec: object):
    ros2 = Ros2Topic.model_validate({"topic": "/auv1/odom", "type": ODOM, **spec})
    layout = Layout.from_fields(FIELDS)
    return compile_ros2(ros2, layout, [layout.fields[i].spec for i in range(3)], ["auv1"],
                        ["ship"]), layout


def test_selected_fields_cross_and_the_rest_comes_from_defaults() -> None:
    ros2, layout = element(defaults={"child_frame_id": "auv1/base", "pose.covariance":
                                     [0.5] * 36}, stamp_now=["header.stamp"])
    sent = ros2.decode(odometry(x=12.345), ros2.out_key.format(src="auv1", dst="ship",
                                                               node="ship"))
    crossed = layout.unpack(layout.pack(sent))  # what the far side gets from the frame
    assert crossed == {"pose": {"pose": {"position": {"x": pytest.approx(12.35),
                                                      "z": pytest.approx(-40.0)}}},
                       "header": {"frame_id": "map"}}
    out = JAZZY.deserialize_cdr(ros2.encode(crossed, 1_700_000_000.25), ODOM)
    assert out.pose.pose.position.x == pytest.approx(12.345, abs=0.005)
    assert out.pose.pose.position.y == 0.0  # not carried, no default
    assert out.header.frame_id == "map"  # carried beats a default
    assert out.child_frame_id == "auv1/base"
    assert out.pose.covariance.tolist() == [0.5] * 36
    assert (out.header.stamp.sec, out.header.stamp.nanosec) == (1_700_000_000, 250_000_000)
    assert out.pose.pose.orientation.w == 1.0  # the definition's default (float64 w 1)


def test_keys_follow_the_topics() -> None:
    ros2, _ = element(out_topic="/{src}/odom_acoustic", domain=3)
    assert ros2.in_key == "3/auv1/odom/*/*"
    assert ros2.out_key == ("3/{src}/odom_acoustic/nav_msgs::msg::dds_::Odometry_/"
                            + GOLDEN[ODOM])


def test_another_type_or_definition_on_the_topic_is_refused_by_name() -> None:
    ros2, _ = element()
    with pytest.raises(DecodeError, match="unknown ROS 2 type geometry_msgs/msg/Twist"):
        ros2.decode(b"\x00\x01\x00\x00" + bytes(48),
                    "0/auv1/odom/geometry_msgs::msg::dds_::Twist_/" + GOLDEN["geometry_msgs"
                                                                             "/msg/Twist"])
    with pytest.raises(DecodeError, match="not the ROS 2 jazzy definition"):
        ros2.decode(odometry(), "0/auv1/odom/nav_msgs::msg::dds_::Odometry_/RIHS01_" + "0" * 64)
    with pytest.raises(DecodeError, match="unknown ROS 2 type custom::thing"):
        ros2.decode(odometry(), "0/auv1/odom/custom::thing/x")
