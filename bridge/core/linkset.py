"""The links of one node (pure): for each, its MAC schedule, frame size, addresses, the store
that tracks what went out on it, and its peers' health on it.

A mission without ``links`` gives a node one :class:`LinkSide` (its modem), exactly the node
of before: its schedule is the mission's, its store the node's, and the node's own
:class:`~bridge.core.link.Links` measure its peers. With several links each side has its own
schedule (the MAC of the link, :mod:`bridge.mission.network`'s view), its own store (a latest
value goes out once per link, to the destinations that link serves:
:class:`~bridge.core.links_policy.LinkPolicy`) and its own :class:`Links`, whose changes go to
``links/<link>/<peer>``; the node's :class:`Links` then say whether a peer is heard at all
(over any link, or through relays).

After an opportunity that sent nothing (nothing to send after all, or the modem refused the
frame) a side takes no other for :data:`IDLE_S`, unless news comes first (a sample, a frame
heard: :meth:`LinkSet.news`): a MAC that offers the next one at once (``none``, ``aloha``
without backoff) never makes its driver ask in a loop.
"""

from __future__ import annotations

from bridge.core.link import Links, LinkThresholds, heartbeat_s
from bridge.core.mac import Opportunity, Schedule, schedule_for
from bridge.core.outputs import Outbox
from bridge.core.store import OutboundStore
from bridge.mission.network import LinkInfo, Network
from bridge.wire.channels import ChannelTable

__all__ = ["IDLE_S", "LinkSet", "LinkSide"]

IDLE_S = 1.0
"""How long a side waits, without news, after an opportunity that sent nothing."""


class LinkSide:
    """One link of a node."""

    def __init__(self, info: LinkInfo, node: str, schedule: Schedule, store: OutboundStore,
                 thresholds: LinkThresholds, health: Links | None) -> None:
        """``health``: the peers' states on this link (None: the node's own :class:`Links`,
        its only link)."""
        self.info = info
        self.name = info.name
        self.kind = info.kind
        self.node = node
        self.schedule = schedule
        self.store = store
        self.thresholds = thresholds
        self.health = health
        self.frame_bytes = info.frame_bytes_of(node)
        self.room = self.frame_bytes
        """Bytes of an own frame after its network header (:meth:`LinkSet.__init__`)."""
        self.header_bytes = 0
        """The longest network header of an own frame on this link."""
        self.heartbeat_s = heartbeat_s(info.view)
        self.peers = tuple(m for m in info.members if m != node)
        self.last_tx: float | None = None
        """When this node's last frame on this link was built."""
        self.sent = 0
        """Frames this node sent on this link."""
        self.idle_at: float | None = None
        """When an opportunity last sent nothing (None: one sent since, or news came)."""

    def opportunity(self, now: float, due: float | None) -> Opportunity | None:
        """The schedule's next opportunity for what is ``due``, no sooner than :data:`IDLE_S`
        after one that sent nothing."""
        opp = self.schedule.next_opportunity(now, due)
        if opp is None or self.idle_at is None or opp.start >= self.idle_at + IDLE_S:
            return opp
        # (past ``latest`` it is none: asked again then, the schedule offers the next one)
        return Opportunity(self.idle_at + IDLE_S, opp.latest, opp.must_send, opp.poll, opp.kind,
                           opp.until)

    def used(self, start: float, end: float) -> None:
        """A frame went out from ``start``; the modem was done at ``end``."""
        self.schedule.on_sent(start, end)
        self.idle_at = None

    def skipped(self, now: float, until: float | None = None) -> None:
        """The opportunity offered before ``now`` sent nothing (the modem refused it
        ``until`` then, if later)."""
        self.schedule.on_skipped(now)
        self.idle_at = now if until is None else max(now, until)

    def name_of(self, address: int) -> str | None:
        """The peer at ``address`` on this link."""
        return self.info.name_of(address)

    def address_of(self, name: str) -> int:
        return self.info.addresses[name]

    def __repr__(self) -> str:
        return f"<LinkSide {self.name} of {self.node}>"


class LinkSet:
    """Every link of one node, the first in mission order being its primary (the one that
    ranges, and the one a runtime without a link name means)."""

    def __init__(self, network: Network, table: ChannelTable, node: str, outbox: Outbox,
                 node_health: Links, store: OutboundStore, seed: int | None) -> None:
        """``node_health``: the node's own :class:`Links`; ``store``: its primary store."""
        self.network = network
        self.node = node
        infos = network.links_of(node)
        if not infos:
            raise ValueError(f"{node} is on no link")
        self.sides: dict[str, LinkSide] = {}
        for i, info in enumerate(infos):
            thresholds = LinkThresholds.for_mission(info.view)
            several = network.several
            side = LinkSide(
                info, node, schedule_for(info.view, node, seed=seed),
                store if i == 0 else OutboundStore.for_node(table.channels, node), thresholds,
                Links(thresholds, [p for p in info.members if p != node], outbox,
                      link=info.name) if several else None)
            self.sides[info.name] = side
        self.primary = next(iter(self.sides.values()))
        self.node_health = node_health
        self.stores = [side.store for side in self.sides.values()]
        net = table.net
        if net is not None:
            for side in self.sides.values():
                through = network.routed_over(node, side.name)
                side.header_bytes = net.routed_bytes if through else net.plain_bytes
                side.room = min([side.frame_bytes, *(network.path_frame_bytes(node, d)
                                                     for d in through)]) - side.header_bytes

    def side(self, link: str | None) -> LinkSide:
        """The side of ``link`` (None: the primary); KeyError names the node's links."""
        if link is None:
            return self.primary
        side = self.sides.get(link)
        if side is None:
            raise KeyError(f"{self.node} is not on link {link!r} "
                           f"(its links: {', '.join(self.sides)})")
        return side

    def news(self) -> None:
        """A sample or a frame came: every side may take its next opportunity at once."""
        for side in self.sides.values():
            side.idle_at = None

    def heard(self, side: LinkSide, peer: str, now: float) -> None:
        """A valid frame from neighbour ``peer`` on ``side``."""
        if side.health is not None:
            side.health.heard(peer, now)

    def update(self, now: float) -> None:
        """Re-evaluate each link's peers (several links; the node's own are done apart)."""
        for side in self.sides.values():
            if side.health is not None:
                side.health.update(now)
