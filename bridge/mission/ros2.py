"""The ``ros2`` block of a mission element: which ROS 2 topic and type a channel element carries."""

from __future__ import annotations

import re
from typing import Any, Literal

from pydantic import ConfigDict, Field, field_validator

from bridge.mission.base import MissionModel

_TYPE = re.compile(r"^([A-Za-z][A-Za-z0-9_]*)/(msg)/([A-Z][A-Za-z0-9]*)$")
_TOKEN = re.compile(r"^[A-Za-z_{][A-Za-z0-9_{}]*$")  # one topic name token (templates allowed)


class NameError_(ValueError):
    """A ROS 2 topic or type name that rmw_zenoh could not carry."""


def check_topic(topic: str) -> str:
    """``topic`` if it is an absolute ROS 2 topic name (``/auv1/odom``; ``{src}`` allowed)."""
    if not topic.startswith("/") or topic.endswith("/") or topic == "/":
        raise NameError_(f"{topic!r}: a ROS 2 topic here is absolute, like /auv1/odom")
    for token in topic[1:].split("/"):
        if not _TOKEN.match(token) or "__" in token:
            raise NameError_(f"{topic!r}: {token!r} is not a valid ROS 2 name token "
                             "(letters, digits and single underscores, not starting with a "
                             "digit)")
    return topic


def dds_type_name(msgtype: str) -> str:
    """``nav_msgs/msg/Odometry`` -> ``nav_msgs::msg::dds_::Odometry_`` (the name in keys)."""
    match = _TYPE.match(msgtype)
    if match is None:
        raise NameError_(f"{msgtype!r} is not a ROS 2 message type like nav_msgs/msg/Odometry")
    package, kind, name = match.groups()
    return f"{package}::{kind}::dds_::{name}_"


class Ros2Qos(MissionModel):
    """The QoS the bridge announces for its ROS 2 publishers (rmw_zenoh defaults)."""

    model_config = ConfigDict(extra="forbid")

    reliability: Literal["reliable", "best_effort"] = "reliable"
    history: Literal["keep_last", "keep_all"] = "keep_last"
    depth: int = Field(42, ge=1, le=10_000, description="KEEP_LAST depth (42: rmw_zenoh's).")


class Ros2Topic(MissionModel):
    """A ROS 2 topic carried by an element over rmw_zenoh's keys, instead of ``in``/``out``."""

    model_config = ConfigDict(extra="forbid")

    topic: str = Field(description="Topic read at the sender, absolute (/auv1/odom); may use "
                       "{node}/{src}.")
    out_topic: str | None = Field(None, description="Topic published at receivers; may use "
                                  "{src}, {dst}, {node}. Default: the same topic.")
    type: str = Field(description="Message type, e.g. nav_msgs/msg/Odometry.")
    distro: Literal["jazzy", "kilted"] = Field("jazzy", description="ROS 2 distribution whose "
                                               "message definitions (and type hashes) to use.")
    domain: int = Field(0, ge=0, le=232, description="ROS_DOMAIN_ID, the first key chunk.")
    defaults: dict[str, Any] = Field(default_factory=dict, description="Values of fields that do "
                                     "not cross, by dotted path (header.frame_id: odom); the "
                                     "rest is zero/empty.")
    stamp_now: list[str] = Field(default_factory=list, description="builtin_interfaces/Time "
                                 "fields set to the time of publishing at the receiver "
                                 "(header.stamp).")
    qos: Ros2Qos = Field(default_factory=Ros2Qos)

    @field_validator("topic", "out_topic")
    @classmethod
    def _topic(cls, v: str | None) -> str | None:
        if v is not None:
            try:
                check_topic(v)
            except NameError_ as exc:
                raise ValueError(str(exc)) from None
        return v

    @field_validator("type")
    @classmethod
    def _type(cls, v: str) -> str:
        try:
            dds_type_name(v)
        except NameError_ as exc:
            raise ValueError(str(exc)) from None
        return v
