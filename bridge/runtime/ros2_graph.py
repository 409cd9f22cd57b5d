"""A bridge node as rmw_zenoh peers see it: the Zenoh side of :mod:`bridge.ros2`.

What a ROS 2 node on rmw_zenoh would do, the bridge does too (rmw_zenoh_cpp ``docs/design.md``,
``rmw_publisher_data.cpp``): one liveliness token for its ROS 2 node (``NN``, named
``zab_<node>``), one per publisher (``MP``) and subscription (``MS``); each publication a Zenoh
``put`` on the topic key with the 33-byte attachment (sequence number from 1, source time in ns,
the publisher's GID). ``ros2 topic list/echo`` on an rmw_zenoh vehicle find the topic through
these tokens and receive the messages.
"""

from __future__ import annotations

import itertools
import logging
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import zenoh

from bridge.ros2.attachment import Attachment, bridge_gid
from bridge.ros2.names import entity_token, node_name_for, node_token, parse_topic_key

if TYPE_CHECKING:
    from bridge.ros2.element import Ros2Element
    from bridge.wire.channels import ChannelTable

log = logging.getLogger("zab.ros2")


@dataclass
class _Publisher:
    publisher: Any
    token: Any
    gid: bytes
    sequence: itertools.count[int] = field(default_factory=lambda: itertools.count(1))


class Ros2Graph:
    """The ROS 2 node, publishers and subscriptions of one bridge node on ``session``."""

    NODE_ID = 0  # one ROS 2 node per session; entity ids count from 1

    def __init__(self, session: zenoh.Session, mission: str, node: str) -> None:
        self.session = session
        self.zid = str(session.info.zid())
        self.mission = mission
        self.name = node_name_for(node)
        self._ids = itertools.count(1)
        self._node_tokens: dict[int, Any] = {}
        self._listening: dict[str, Any] = {}
        self._publishers: dict[str, _Publisher] = {}

    def _node(self, domain: int) -> None:
        if domain not in self._node_tokens:
            self._node_tokens[domain] = self.session.liveliness().declare_token(
                node_token(domain, self.zid, self.NODE_ID, self.name))

    def listen(self, ros2: Ros2Element, topic: str) -> str:
        """Announce a subscription to ``topic`` (the bridge's input); returns its token key."""
        known = self._listening.get(topic)
        if known is not None:
            return str(known.key_expr)
        key = entity_token(ros2.domain, self.zid, self.NODE_ID, next(self._ids), "MS", self.name,
                           topic, ros2.msgtype, ros2.type_hash, ros2.qos)
        self._node(ros2.domain)
        self._listening[topic] = self.session.liveliness().declare_token(key)
        return key

    def announce(self, table: ChannelTable, node: str) -> None:
        """Join the ROS 2 graph as ``node``'s bridge: a subscription per ROS 2 topic it reads,
        a publisher per ROS 2 topic it publishes (so ``ros2 topic list/echo`` see them before
        the first message crosses), its image channels' camera topics and pictures too."""
        for channel in table.channels:
            for element in channel.elements:
                if element.ros2 is None:
                    continue
                if channel.sent_by(node) and channel.destinations(node):
                    self.listen(element.ros2, element.ros2.in_topic.format(node=node, src=node))
                for src in channel.senders:
                    if node in channel.destinations(src):
                        self._publisher(element.output_key(src, node), element.ros2)
            spec = channel.image
            if spec is None or spec.control:
                continue
            if spec.ros2 is not None and channel.sent_by(node) and channel.destinations(node):
                # (image_transport publishes a topic only while something subscribes to it)
                self.listen(spec.ros2, spec.ros2.in_topic.format(node=node, src=node))
            for src in channel.senders:
                key = spec.ros2_output_key(src, node)
                if spec.ros2_out is not None and key is not None \
                        and node in channel.destinations(src):
                    self._publisher(key, spec.ros2_out)

    def _publisher(self, key: str, ros2: Ros2Element) -> _Publisher:
        pub = self._publishers.get(key)
        if pub is None:
            self._node(ros2.domain)
            topic = parse_topic_key(key).topic
            token_key = entity_token(ros2.domain, self.zid, self.NODE_ID, next(self._ids), "MP",
                                     self.name, topic, ros2.msgtype, ros2.type_hash, ros2.qos)
            reliable = ros2.qos.reliability == "reliable"
            block = reliable and ros2.qos.history == "keep_all"
            publisher = self.session.declare_publisher(
                key,
                reliability=zenoh.Reliability.RELIABLE if reliable
                else zenoh.Reliability.BEST_EFFORT,
                congestion_control=zenoh.CongestionControl.BLOCK if block
                else zenoh.CongestionControl.DROP)
            token = self.session.liveliness().declare_token(token_key)
            pub = self._publishers[key] = _Publisher(
                publisher, token, bridge_gid(self.mission, self.name, token_key))
        return pub

    def publish(self, key: str, value: Any, ros2: Ros2Element, now: float) -> None:
        """Publish ``value`` as a complete CDR message on ``key``; ``EncodeError`` if it cannot
        be serialised (nothing is sent then)."""
        payload = ros2.encode(value, now)
        pub = self._publisher(key, ros2)
        attachment = Attachment(next(pub.sequence), int(now * 1e9), pub.gid)
        pub.publisher.put(payload, attachment=attachment.pack())

    def close(self) -> None:
        """Undeclare every token and publisher (safe to call twice)."""
        for pub in self._publishers.values():
            for entity in (pub.token, pub.publisher):
                try:
                    entity.undeclare()
                except Exception as exc:  # the session may be closing already
                    log.debug("undeclare: %s", exc)
        tokens = [*self._listening.values(), *self._node_tokens.values()]
        for token in tokens:
            try:
                token.undeclare()
            except Exception as exc:
                log.debug("undeclare: %s", exc)
        self._publishers.clear()
        self._listening.clear()
        self._node_tokens.clear()
