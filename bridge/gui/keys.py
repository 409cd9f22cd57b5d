"""Which Zenoh keys the GUI reads at one node, and what each of them means (pure).

The GUI is an ordinary Zenoh client of one node, normally the surface vehicle. There it sees
three kinds of key:

- the *output* keys that node's bridge publishes for the channels it receives (``auv1/nav``):
  a vehicle's channel values, and its position when the element carries the sender's
  ``nav_key``;
- the *input* keys of the channels that node sends (commands, its own GPS): local values;
- the bridge's own keys under ``@zab/<mission>/<node>/...`` (stats, link, range, position,
  delivery, transfer, events).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from bridge.core.loaded import LoadedMission
from bridge.ros2.element import Ros2Element


@dataclass(frozen=True)
class ChannelSource:
    """One element of one channel, as sent by ``src``; ``nav`` when it is ``src``'s position."""

    channel: str
    src: str
    element: int
    key: str
    nav: bool = False
    ros2: Ros2Element | None = None  # a ROS 2 topic: CDR samples, the key names the type


@dataclass(frozen=True)
class StatusKey:
    """A bridge key ``@zab/<mission>/<node>/<topic>[/<name>]``, split up."""

    node: str
    topic: str
    name: str | None = None


class SurfaceKeys:
    """The keys of a mission as seen at ``node``."""

    def __init__(self, loaded: LoadedMission, node: str) -> None:
        mission = loaded.mission
        if node not in mission.nodes:
            raise ValueError(f"node {node!r} is not in mission {mission.mission!r} "
                             f"(nodes: {', '.join(mission.nodes)})")
        self.node = node
        self.prefix = f"@zab/{mission.mission}"
        self.sources: dict[str, list[ChannelSource]] = {}
        own_nav = mission.nodes[node].nav_key
        for channel in loaded.table.channels:
            for src in channel.senders:
                if src == node:
                    for i, element in enumerate(channel.elements):
                        key = element.input_key(src)
                        self._add(ChannelSource(channel.name, src, i, key, nav=key == own_nav,
                                                ros2=element.ros2))
                elif node in channel.destinations(src):
                    nav_key = mission.nodes[src].nav_key
                    for i, element in enumerate(channel.elements):
                        self._add(ChannelSource(
                            channel.name, src, i, element.output_key(src, node),
                            nav=nav_key is not None and element.input_key(src) == nav_key,
                            ros2=element.ros2))
        if own_nav is not None and not any(s.nav for s in self.sources.get(own_nav, ())):
            self._add(ChannelSource("nav_key", node, 0, own_nav, nav=True))

    def _add(self, source: ChannelSource) -> None:
        found = self.sources.setdefault(source.key, [])
        if source not in found:
            found.append(source)

    def lookup(self, key: str) -> list[ChannelSource] | None:
        """The sources of a received ``key``: its own, or a key family member's (the family's
        wildcard key matches it; the member shows as ``channel:member``)."""
        found = self.sources.get(key)
        if found is not None or "*" in key:
            return found
        chunks = key.split("/")
        out = []
        for pattern, sources in self.sources.items():
            parts = pattern.split("/")
            if "*" in parts and len(parts) == len(chunks) and all(
                    p in ("*", c) for p, c in zip(parts, chunks, strict=True)):
                if all(s.ros2 is not None for s in sources):  # (its type and hash, no member)
                    out += [replace(s, key=key) for s in sources]
                    continue
                member = chunks[parts.index("*")]
                out += [replace(s, channel=f"{s.channel}:{member}", key=key) for s in sources]
        return out or None

    def subscriptions(self) -> list[str]:
        """Key expressions to subscribe to: every value key, and all bridge keys."""
        return [*self.sources, f"{self.prefix}/**"]

    def status(self, key: str) -> StatusKey | None:
        """The parts of a bridge key of this mission, or None for any other key."""
        head = self.prefix + "/"
        if not key.startswith(head):
            return None
        parts = key[len(head):].split("/")
        if len(parts) == 2:
            return StatusKey(parts[0], parts[1])
        if len(parts) == 3:
            return StatusKey(parts[0], parts[1], parts[2])
        if len(parts) == 4 and parts[1] == "links":  # links/<link>/<peer>
            return StatusKey(parts[0], parts[1], f"{parts[2]}/{parts[3]}")
        return None
