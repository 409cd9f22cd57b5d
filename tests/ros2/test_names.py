"""Topic keys, liveliness tokens and QoS text, against rmw_zenoh's design document examples."""

from __future__ import annotations

import pytest

from bridge.mission.ros2 import NameError_, check_topic, dds_type_name
from bridge.ros2.names import (
    Qos,
    entity_token,
    node_name_for,
    node_token,
    parse_topic_key,
    ros_type_name,
    topic_key,
    topic_listen_key,
)

# rmw_zenoh_cpp docs/design.md, "Topic and Service name mapping" and "Graph Cache"
STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
ZID = "8b20917502ee955ac4476e0266340d5c"


def test_topic_keys_of_the_design_document() -> None:
    assert topic_key(0, "/chatter", "std_msgs/msg/String", STRING_HASH) == (
        f"0/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}")
    assert topic_key(0, "/robot1/chatter", "std_msgs/msg/String", STRING_HASH) == (
        f"0/robot1/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}")


def test_a_key_parses_back_and_the_listen_key_takes_any_type_on_the_topic() -> None:
    key = topic_key(7, "/auv1/nav/odom", "nav_msgs/msg/Odometry", STRING_HASH)
    parsed = parse_topic_key(key)
    assert (parsed.domain, parsed.topic, parsed.msgtype, parsed.type_hash) == (
        7, "/auv1/nav/odom", "nav_msgs/msg/Odometry", STRING_HASH)
    assert topic_listen_key(7, "/auv1/nav/odom") == "7/auv1/nav/odom/*/*"
    with pytest.raises(NameError_):
        parse_topic_key("@zab/lab/a/stats")


def test_type_names() -> None:
    assert dds_type_name("nav_msgs/msg/Odometry") == "nav_msgs::msg::dds_::Odometry_"
    assert ros_type_name("geometry_msgs::msg::dds_::Twist_") == "geometry_msgs/msg/Twist"
    assert ros_type_name("not a type") is None
    for bad in ("Odometry", "nav_msgs/Odometry", "nav_msgs/srv/Odometry", "nav_msgs/msg/odom"):
        with pytest.raises(NameError_):
            dds_type_name(bad)


@pytest.mark.parametrize("topic", ["auv1/odom", "/auv1/odom/", "/", "/auv 1/odom", "/a//b",
                                   "/1odom", "/a__b"])
def test_invalid_topics_are_refused(topic: str) -> None:
    with pytest.raises(NameError_):
        check_topic(topic)


def test_node_and_publisher_tokens_of_the_design_document() -> None:
    assert node_token(2, "aac3178e146ba6f1fc6e6a4085e77f21", 0, "listener") == (
        "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener")
    talker = entity_token(2, ZID, 0, 10, "MP", "talker", "/chatter", "std_msgs/msg/String",
                          STRING_HASH, Qos(depth=7))
    assert talker == (f"@ros2_lv/2/{ZID}/0/10/MP/%/%/talker/%chatter/"
                      f"std_msgs::msg::dds_::String_/{STRING_HASH}/::,7:,:,:,,")
    listener = entity_token(2, ZID, 0, 10, "MS", "listener", "/chatter", "std_msgs/msg/String",
                            STRING_HASH, Qos(depth=10))
    assert listener.endswith("/MS/%/%/listener/%chatter/std_msgs::msg::dds_::String_/"
                             f"{STRING_HASH}/::,10:,:,:,,")


def test_qos_text_leaves_rmw_zenoh_defaults_empty() -> None:
    assert Qos().keyexpr() == "::,:,:,:,,"  # reliable, volatile, keep last 42
    assert Qos(reliability="best_effort", durability="transient_local", history="keep_all",
               depth=5).keyexpr() == "2:1:2,5:,:,:,,"


def test_bridge_node_names_are_ros_names() -> None:
    assert node_name_for("auv-1") == "zab_auv_1"
