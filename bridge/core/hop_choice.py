"""Next-hop choice (pure): which of the hops a route lists carries a node's traffic now.

A route may list several next hops, best first (``routes: {far: [r1, r2]}``; the listed
routes of one node name the same hops in the same order: :mod:`bridge.mission.network`).
The node sends through one of them at a time, with the link policy's hysteresis
(:mod:`bridge.core.links_policy`), a hop's health being its best over the links the node
shares with it (each link's own :class:`~bridge.core.link.Links`, or the node's):

- at first, the first listed hop, kept until it has been silent for its links'
  ``down_after_s`` (a hop heard later than another at start is no reason to leave it);
- *failover*: when the hop in use is down and another listed hop is up (or degraded), the
  first such hop takes over;
- *failback*: when a hop listed earlier has been up for its links' ``failback_s`` (default:
  ``degraded_after_s``) without a break, traffic returns to it.

Routed frames name the hop chosen (the network header's ``via``), so only that relay
carries them on.
"""

from __future__ import annotations

from bridge.core.link import Links, LinkState
from bridge.core.linkset import LinkSet

__all__ = ["HopChoice"]

_RANK = {LinkState.UP: 0, LinkState.DEGRADED: 1, LinkState.DOWN: 2}


class HopChoice:
    """The next hop in use among the hops this node's routes list, with hysteresis."""

    def __init__(self, linkset: LinkSet) -> None:
        self.linkset = linkset
        node, network = linkset.node, linkset.network
        routes = network.mission.nodes[node].routes
        listed = any(not isinstance(route, str) and len(route) > 1 for route in routes.values())
        self.dests: dict[str, tuple[str, ...]] = {
            dest: hops for dest in network.mission.nodes
            if listed and dest != node and len(hops := network.next_hops(node, dest)) > 1}
        """The destinations whose route lists several hops, and those hops."""
        self.order: tuple[str, ...] = next(iter(self.dests.values()), ())
        self.chosen: str | None = self.order[0] if self.order else None
        self._health: dict[str, list[Links]] = {
            hop: [side.health or linkset.node_health for side in linkset.sides.values()
                  if hop in side.peers] for hop in self.order}
        sides = {hop: [s for s in linkset.sides.values() if hop in s.peers] for hop in self.order}
        self._failback_s = {hop: max(s.info.view.link.failback_s or s.thresholds.degraded_after_s
                                     for s in found) for hop, found in sides.items()}
        self._news_s = {hop: max(s.thresholds.down_after_s for s in found)
                        for hop, found in sides.items()}
        self._started: float | None = None
        self._up_since: dict[str, float] = {}

    def state(self, hop: str) -> LinkState:
        """``hop``'s best state over the links this node shares with it."""
        return min((h.states.get(hop, LinkState.DOWN) for h in self._health[hop]),
                   key=_RANK.__getitem__, default=LinkState.DOWN)

    def update(self, now: float) -> tuple[str, str, str] | None:
        """Follow the hops' health; the switch made as ``(was, via, reason)`` (None: none)."""
        was = self.chosen
        if was is None:
            return None
        if self._started is None:
            self._started = now
        for hop in self.order:
            if self.state(hop) is LinkState.UP:
                self._up_since.setdefault(hop, now)
            else:
                self._up_since.pop(hop, None)
        best = self._choose(was, now)
        if best == was:
            return None
        self.chosen = best
        reason = "failback" if self.order.index(best) < self.order.index(was) else "failover"
        return was, best, reason

    def _choose(self, was: str, now: float) -> str:
        for hop in self.order:  # failback: a hop listed earlier, up long enough
            if hop == was:
                break
            since = self._up_since.get(hop)
            if since is not None and now - since >= self._failback_s[hop]:
                return hop
        if self.state(was) is not LinkState.DOWN or self._unknown(was, now):
            return was
        for hop in self.order:  # failover: the first hop heard at all
            if self.state(hop) is not LinkState.DOWN:
                return hop
        return was  # every hop is down: stay, and take the first to come back

    def _unknown(self, hop: str, now: float) -> bool:
        """``hop`` was never heard and the node is young: no news yet."""
        assert self._started is not None
        return all(hop not in h.last_heard for h in self._health[hop]) \
            and now - self._started < self._news_s[hop]
