"""The ``ros2`` block of a mission element: which ROS 2 topic and type a channel element carries."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

from bridge.ros2.names import NameError_, check_topic, dds_type_name


class Ros2Qos(BaseModel):
    """The QoS the bridge announces for its ROS 2 publishers (rmw_zenoh defaults)."""

    model_config = ConfigDict(extra="forbid")

    reliability: Literal["reliable", "best_effort"] = "reliable"
    history: Literal["keep_last", "keep_all"] = "keep_last"
    depth: int = Field(42, ge=1, le=10_000, description="KEEP_LAST depth (42: rmw_zenoh's).")


class Ros2Topic(BaseModel):
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
