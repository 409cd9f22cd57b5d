"""rmw_zenoh's names on Zenoh: topic key expressions and liveliness tokens (sans I/O).

Follows rmw_zenoh_cpp's ``docs/design.md`` ("Topic and Service name mapping to Zenoh key
expressions", "Graph Cache") and ``liveliness_utils.cpp`` (Jazzy 0.2.4+, Kilted, Rolling):

- data:  ``<domain>/<topic without leading/trailing slash>/<dds type>/<type hash>``, the topic's
  inner slashes kept (``0/auv1/odom/nav_msgs::msg::dds_::Odometry_/RIHS01_3cc9…``);
- token: ``@ros2_lv/<domain>/<zid>/<node id>/<entity id>/<kind>/<enclave>/<namespace>/<node>``
  and, for a publisher or subscription, ``/<topic>/<dds type>/<type hash>/<qos>``, every name
  *mangled* (each ``/`` replaced by ``%``; an empty namespace or enclave ``/`` becomes ``%``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Literal

from bridge.mission.ros2 import NameError_, dds_type_name

ADMIN_SPACE = "@ros2_lv"
SLASH_REPLACEMENT = "%"

EntityKind = Literal["NN", "MP", "MS"]

_DDS_TYPE = re.compile(r"^([A-Za-z][A-Za-z0-9_]*)::(msg)::dds_::([A-Z][A-Za-z0-9]*)_$")
_HASH = re.compile(r"^RIHS01_[0-9a-f]{64}$")


def ros_type_name(dds_type: str) -> str | None:
    """``nav_msgs::msg::dds_::Odometry_`` -> ``nav_msgs/msg/Odometry``; None if not of that form."""
    match = _DDS_TYPE.match(dds_type)
    return None if match is None else "/".join(match.groups())


def mangle(name: str) -> str:
    """rmw_zenoh's ``mangle_name``: every ``/`` becomes ``%``."""
    return name.replace("/", SLASH_REPLACEMENT)


def topic_key(domain: int, topic: str, msgtype: str, type_hash: str) -> str:
    """The data key expression of ``topic`` (the topic's slashes kept, outer ones dropped)."""
    if not _HASH.match(type_hash) and type_hash != "*":
        raise NameError_(f"{type_hash!r} is not a RIHS01 type hash")
    return f"{domain}/{topic.strip('/')}/{dds_type_name(msgtype)}/{type_hash}"


def topic_listen_key(domain: int, topic: str) -> str:
    """Every type on ``topic``: ``<domain>/<topic>/*/*`` (a type and a hash chunk, nothing else)."""
    return f"{domain}/{topic.strip('/')}/*/*"


@dataclass(frozen=True)
class TopicKey:
    """A data key taken apart."""

    domain: int
    topic: str
    dds_type: str
    type_hash: str

    @property
    def msgtype(self) -> str | None:
        return ros_type_name(self.dds_type)


def parse_topic_key(key: str) -> TopicKey:
    """Inverse of :func:`topic_key`; ``NameError_`` if ``key`` is not of that shape."""
    parts = key.split("/")
    if len(parts) < 4 or not parts[0].isdigit() or not all(parts):
        raise NameError_(f"{key!r} is not an rmw_zenoh topic key")
    return TopicKey(int(parts[0]), "/" + "/".join(parts[1:-2]), parts[-2], parts[-1])


@dataclass(frozen=True)
class Qos:
    """The QoS a token announces. rmw_zenoh's defaults (``qos.cpp``): reliable, volatile,
    keep last 42; deadline, lifespan and liveliness lease infinite, liveliness automatic."""

    reliability: Literal["reliable", "best_effort"] = "reliable"
    durability: Literal["volatile", "transient_local"] = "volatile"
    history: Literal["keep_last", "keep_all"] = "keep_last"
    depth: int = 42

    def keyexpr(self) -> str:
        """``qos_to_keyexpr``: ``<rel>:<dur>:<hist>,<depth>:<deadline s>,<ns>:<lifespan s>,<ns>:
        <liveliness>,<lease s>,<ns>``, each left empty when it equals rmw_zenoh's default.
        Enum values are rmw/types.h's (reliable 1, best effort 2; transient local 1, volatile
        2; keep last 1, keep all 2)."""
        rel = "" if self.reliability == "reliable" else "2"
        dur = "" if self.durability == "volatile" else "1"
        hist = "" if self.history == "keep_last" else "2"
        depth = "" if self.depth == 42 else str(self.depth)
        return f"{rel}:{dur}:{hist},{depth}:,:,:,,"


def node_token(domain: int, zid: str, node_id: int, node_name: str,
               namespace: str = "/", enclave: str = "/") -> str:
    """The liveliness token of a ROS 2 node (kind ``NN``; entity id = node id)."""
    return "/".join((ADMIN_SPACE, str(domain), zid, str(node_id), str(node_id), "NN",
                     mangle(enclave), mangle(namespace), mangle(node_name)))


def entity_token(domain: int, zid: str, node_id: int, entity_id: int, kind: EntityKind,
                 node_name: str, topic: str, msgtype: str, type_hash: str, qos: Qos,
                 namespace: str = "/", enclave: str = "/") -> str:
    """The liveliness token of a publisher (``MP``) or subscription (``MS``) of ``topic``."""
    return "/".join((ADMIN_SPACE, str(domain), zid, str(node_id), str(entity_id), kind,
                     mangle(enclave), mangle(namespace), mangle(node_name), mangle(topic),
                     mangle(dds_type_name(msgtype)), mangle(type_hash), qos.keyexpr()))


def node_name_for(zab_node: str) -> str:
    """The ROS 2 node name under which a bridge node appears: ``zab_<node>`` (``-`` -> ``_``)."""
    return "zab_" + re.sub(r"[^A-Za-z0-9_]", "_", zab_node)
