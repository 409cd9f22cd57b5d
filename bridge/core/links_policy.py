"""Link policy (pure): which of a node's links carries its traffic to each destination, now.

Traffic to a destination goes to its next hop (the destination itself, or the neighbour its
route names: :meth:`~bridge.mission.network.Network.next_hop`; among several its route
lists, the one :class:`~bridge.core.hop_choice.HopChoice` chooses now), over one of the links
this
node shares with that hop. Their order of preference is the channel's ``prefer``, then the
destination's ``prefer``, then the mission's order of links. Exactly one link carries a
(destination, order) at a time, so a value never goes to one node over two links at once:

- at first, the most preferred link (nothing is known yet), kept until the hop has been
  silent on it for the link's ``down_after_s`` (a link heard later than another at start is
  no reason to leave it);
- *failover*: when the hop is down on the link in use and up (or degraded) on another, the
  most preferred such link takes over;
- *failback*: when a more preferred link has been up for ``link.failback_s`` (default: its
  ``degraded_after_s``) without a break, traffic returns to it. The wait is the hysteresis:
  a link flickering at the edge of its range does not pull traffic back and forth.

Each switch is a :class:`~bridge.core.events.LinkSwitched` event and ``route/<peer>``
status (the first choice too, as status), and the latching channels to that destination are
sent once on the new link at once (:meth:`LinkPolicy.update` returns the switches for the
node to do so). With one link everything goes over it and nothing here changes.
"""

from __future__ import annotations

from collections.abc import Sequence

from bridge.core.events import LinkSwitched, RouteSwitched
from bridge.core.hop_choice import HopChoice
from bridge.core.link import LinkState
from bridge.core.linkset import LinkSet, LinkSide
from bridge.core.outputs import Outbox
from bridge.mission.model import Mission
from bridge.wire.channels import ChannelCodec

__all__ = ["LinkPolicy", "Switch"]

Order = tuple[str, ...]  # link names, most preferred first
Switch = tuple[str, str | None, str | None]  # (destination, from link, to link)


class LinkPolicy:
    """The link in use to each destination, per order of preference, with hysteresis."""

    def __init__(self, mission: Mission, linkset: LinkSet, outbox: Outbox) -> None:
        self.node = node = linkset.node
        self.linkset = linkset
        self.outbox = outbox
        self.single = len(linkset.sides) == 1
        network = linkset.network
        self.choice = HopChoice(linkset)
        self.hops: dict[str, str] = {}
        """Each reachable destination's next hop now."""
        for dest in mission.nodes:
            if dest != node and (hop := network.next_hop(node, dest)) is not None:
                self.hops[dest] = hop
        self._dest_order = {d: tuple(mission.nodes[d].prefer or ()) for d in self.hops}
        self._failback_s = {name: side.info.view.link.failback_s or side.thresholds.degraded_after_s
                            for name, side in linkset.sides.items()}
        self.current: dict[tuple[str, Order], str | None] = {}
        self._started: float | None = None
        self._announced: set[tuple[str, Order]] = set()  # whose choice went on route/<peer>
        self._up_since: dict[tuple[str, str], float] = {}  # (link, hop) up without a break
        self._served: dict[tuple[str, int], tuple[str, ...]] = {}  # cache, per version
        self.version = 0
        """Changes whenever a destination moves to another link."""

    # -- the choice --------------------------------------------------------------------------

    def order(self, dest: str, channel: ChannelCodec | None = None) -> Order:
        """The links to ``dest``'s next hop, most preferred first."""
        hop = self.hops.get(dest)
        if hop is None:
            return ()
        usable = [name for name, side in self.linkset.sides.items() if hop in side.peers]
        first = [*(channel.prefer if channel is not None and channel.prefer else ()),
                 *self._dest_order.get(dest, ())]
        ranked = [n for n in dict.fromkeys(first) if n in usable]
        return (*ranked, *(n for n in usable if n not in ranked))

    def link_for(self, dest: str, channel: ChannelCodec | None = None) -> str | None:
        """The link carrying traffic to ``dest`` now (None: no link reaches its next hop)."""
        order = self.order(dest, channel)
        if len(order) <= 1:
            return order[0] if order else None
        key = (dest, order)
        if key not in self.current:
            self.current[key] = order[0]  # nothing known yet: the most preferred
        return self.current[key]

    def serves(self, side: LinkSide, dest: str, channel: ChannelCodec | None = None) -> bool:
        """Whether ``side`` carries traffic to ``dest`` now."""
        if self.single:
            return dest in self.hops
        return self.link_for(dest, channel) == side.name

    def destinations(self, side: LinkSide, channel: ChannelCodec) -> tuple[str, ...]:
        """The destinations of ``channel`` (sent by this node) that ``side`` carries now."""
        all_ = channel.destinations(self.node)
        if self.single:
            return all_
        key = (side.name, channel.index)
        found = self._served.get(key)
        if found is None:
            found = self._served[key] = tuple(d for d in all_
                                              if self.link_for(d, channel) == side.name)
        return found

    # -- hysteresis --------------------------------------------------------------------------

    def update(self, now: float) -> list[Switch]:
        """Follow the links' health: fail over from a link whose hop is down, fail back to a
        more preferred one up for its ``failback_s``; and the next hop among those a route
        lists (:class:`HopChoice`). Returns the switches made."""
        switches = self._follow_hops(now)
        if self.single:
            return switches
        if self._started is None:
            self._started = now
        self._track(now)
        for key, was in list(self.current.items()):
            dest, order = key
            hop = self.hops[dest]
            best = self._choose(order, hop, was, now)
            if best == was:
                if key not in self._announced:  # the first choice, for the record
                    self._announced.add(key)
                    self.outbox.status(f"route/{dest}", {"peer": dest, "link": was,
                                                         "was": None, "via": hop,
                                                         "reason": "first", "time": now})
                continue
            self._announced.add(key)
            self.current[key] = best
            reason = "failback" if best is not None and was is not None \
                and order.index(best) < order.index(was) else "failover"
            switches.append((dest, was, best))
            self.outbox.status(f"route/{dest}", {"peer": dest, "link": best, "was": was,
                                                 "via": hop, "reason": reason, "time": now})
            self.outbox.event(LinkSwitched(now, dest, best, was, reason))
        if switches:
            self.version += 1
            self._served.clear()
        return switches

    def _follow_hops(self, now: float) -> list[Switch]:
        """The next hop of the destinations whose route lists several, when it changes:
        each moves to a link to the new hop (the most preferred, nothing known yet)."""
        moved = self.choice.update(now)
        if moved is None:
            return []
        was, via, reason = moved
        switches: list[Switch] = []
        for dest in self.choice.dests:
            old = [key for key in self.current if key[0] == dest]
            before = self.current[old[0]] if old else None
            for key in old:
                del self.current[key]
            self.hops[dest] = via
            link = self.link_for(dest)
            self._announced.update(key for key in self.current if key[0] == dest)
            switches.append((dest, before, link))
            self.outbox.status(f"route/{dest}", {"peer": dest, "link": link, "was": before,
                                                 "via": via, "was_via": was, "reason": reason,
                                                 "time": now})
            self.outbox.event(RouteSwitched(now, dest, via, was, reason))
        self.version += 1
        self._served.clear()
        return switches

    def _state(self, link: str, hop: str) -> LinkState:
        health = self.linkset.sides[link].health
        assert health is not None
        return health.states.get(hop, LinkState.DOWN)

    def _track(self, now: float) -> None:
        """When each (link, hop) came up and has stayed up since."""
        for name, side in self.linkset.sides.items():
            for hop in side.peers:
                key = (name, hop)
                if self._state(name, hop) is LinkState.UP:
                    self._up_since.setdefault(key, now)
                else:
                    self._up_since.pop(key, None)

    def _choose(self, order: Sequence[str], hop: str, was: str | None, now: float) -> str | None:
        """The link to use from now on, ``was`` being the one in use."""
        for name in order:  # failback: a better link, up long enough
            if name == was:
                break
            since = self._up_since.get((name, hop))
            if since is not None and now - since >= self._failback_s[name]:
                return name
        if was is not None and (self._state(was, hop) is not LinkState.DOWN
                                or self._unknown(was, hop, now)):
            return was
        for name in order:  # failover: the best link on which the hop is heard at all
            if self._state(name, hop) is not LinkState.DOWN:
                return name
        return was  # every link is down: stay, and take the first to come back

    def _unknown(self, link: str, hop: str, now: float) -> bool:
        """``hop`` was never heard on ``link`` and the link is young: no news yet."""
        side = self.linkset.sides[link]
        assert side.health is not None and self._started is not None
        return hop not in side.health.last_heard \
            and now - self._started < side.thresholds.down_after_s

    def snapshot(self) -> dict[str, object]:
        """The link in use to each destination (per order of preference) and its next hop."""
        return {dest: {"via": self.hops[dest], "link": link, "order": list(order)}
                for (dest, order), link in sorted(self.current.items())}
