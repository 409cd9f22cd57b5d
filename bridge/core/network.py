"""A node's part in a network of links (pure): what goes out on which of its links, and the
network header of its frames.

Only missions with several links or routes have one (:class:`NodeNetwork`); with one link
and no routes a node builds its frames as it always did. Here, for each frame built on a
link (:class:`~bridge.core.linkset.LinkSide`):

- the candidates are narrowed to what that link carries now (the destinations
  :class:`~bridge.core.links_policy.LinkPolicy` gives it: latest values, reliable values and
  fragments still owed to one of them, queries and replies for one of them);
- the frame serves exactly those destinations (its network header's ``for``), so a node that
  overhears it on another link does not take it twice;
- once sent, the other links' stores count a latest value as sent too when they carry none of
  its destinations (it is not sent again there after a failover); a failover sends the
  latching channels to the destination once on the new link at once;
- a relay's frames for others compete for the link's opportunities
  (:class:`~bridge.core.routing.Routing`).
"""

from __future__ import annotations

import itertools
import random
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import replace
from typing import Any

from bridge.core.builder import Candidate
from bridge.core.events import Delivery, FrameDropped, FrameRelayed
from bridge.core.families import Extra
from bridge.core.frames import OutFrame
from bridge.core.link import LinkState
from bridge.core.links_policy import LinkPolicy, Switch
from bridge.core.linkset import LinkSet, LinkSide
from bridge.core.outputs import Outbox
from bridge.core.reception import Reception
from bridge.core.reliable import Pending, ReliableSender
from bridge.core.routing import Routing
from bridge.core.store import ChannelState
from bridge.core.transfer import TransferSender
from bridge.errors import FrameError
from bridge.wire.channels import ChannelCodec, ChannelTable
from bridge.wire.families import NameCodec
from bridge.wire.interest import InterestCodec
from bridge.wire.network import SEGMENT_MAX, NetCodec

__all__ = ["AUTH_WINDOW", "NodeNetwork"]

AUTH_WINDOW = 1024
"""With several links or routes, frames of a sender may arrive out of order: this many
counters below the highest are still accepted, once each (bridge.wire.auth). A relay holds a
frame minutes on a slow hop while its origin sends one a second on a fast one (or is heard
directly): on umci_relay, 64 refused half of ROV2's relayed frames (a bitmap of 128 bytes
per sender in the saved state)."""


class NodeNetwork:
    """The links, their policy and the relaying of one node in a networked mission."""

    def __init__(self, linkset: LinkSet, policy: LinkPolicy, routing: Routing) -> None:
        self.linkset = linkset
        self.policy = policy
        self.routing = routing
        self.node = node = linkset.node
        table = routing.table
        self._wide: dict[type, frozenset[str]] = {
            InterestCodec: frozenset(s for c in table.channels if node in c.receivers
                                     for s in c.senders if s != node),
            NameCodec: frozenset(d for c in table.channels if c.family is not None
                                 and c.sent_by(node) for d in c.destinations(node))}
        """Whom a system entry without one addressee is for: an ``@want`` bitmap, every node
        sending this one a channel; an ``@key`` name, every destination of its families."""
        self._own_turn: dict[str, bool] = {}
        """Per link: whether the node's own frame goes first at the next opportunity where it
        is as urgent as the most urgent frame carried (at such ties they take turns)."""

    @classmethod
    def of(cls, table: ChannelTable, linkset: LinkSet, policy: LinkPolicy, outbox: Outbox,
           rng: random.Random, state: Mapping[str, Any]) -> NodeNetwork | None:
        """The node's network part when its frames carry the network header (None: one link
        and no routes, the frames of before)."""
        if table.net is None:
            return None
        return cls(linkset, policy, Routing(table, linkset.network, linkset, policy, outbox,
                                            rng, state))

    def snapshot(self) -> dict[str, Any]:
        """Per link its frames sent; the link in use to each destination; what it carried."""
        return {"links": {name: {"kind": side.kind, "peers": list(side.peers),
                                 "states": {p: s.value for p, s in side.health.states.items()}
                                 if side.health is not None else {}}
                          for name, side in self.linkset.sides.items()},
                **self.routing.snapshot()}

    # -- what a link carries -------------------------------------------------------------------

    def carried_by(self, side: LinkSide, candidates: Iterable[Candidate]) -> list[Candidate]:
        """The candidates ``side`` carries now (latest values are filtered already)."""
        out = []
        for candidate in candidates:
            what = candidate.what
            if isinstance(what, Extra):
                if self.extra_targets(side, what):
                    out.append(candidate)
            elif isinstance(what, ChannelState) or (
                    isinstance(candidate.channel, ChannelCodec)
                    and self.targets(side, candidate.channel, what)):
                out.append(candidate)
        return out

    def targets(self, side: LinkSide, channel: ChannelCodec, what: Any) -> set[str]:
        """The destinations an entry of ``channel`` (``what``: its latest value, or a stream's
        (sender, item)) serves when it goes out on ``side``."""
        served = self.policy.destinations(side, channel)
        if isinstance(what, tuple):
            sender, item = what
            if isinstance(sender, ReliableSender) and isinstance(item, Pending):
                return (item.waiting - item.held).intersection(served)
            if isinstance(sender, TransferSender):
                return set(sender.dests).intersection(served)
        return set(served)

    def extra_targets(self, side: LinkSide, extra: Extra) -> set[str]:
        """The nodes a system entry serves when it goes out on ``side``: its addressee (a
        query's server or asker), or those a wide one is for (:attr:`_wide`) that ``side``
        carries traffic to, relayed ones included."""
        if extra.to is not None:
            return {extra.to} if self.policy.serves(side, extra.to) else set()
        wide = self._wide.get(type(extra.channel), frozenset())
        return {n for n in wide if self.policy.serves(side, n)}

    def stream_due(self, side: LinkSide, sender: ReliableSender | TransferSender
                   ) -> float | None:
        """When ``sender`` next has something for a destination ``side`` carries."""
        served = self.policy.destinations(side, sender.channel)
        if not served:
            return None
        if isinstance(sender, ReliableSender):
            return min((p.next_send for p in sender.flight
                        if (p.waiting - p.held).intersection(served)), default=None)
        return sender.next_time()

    def next_carried(self, side: LinkSide) -> float | None:
        """When this node has a frame of others to carry on ``side``."""
        return self.routing.next_due(side)

    def header(self, targets: Iterable[str], channels: Sequence[Any]) -> bytes:
        """The network header of an own frame for ``targets`` carrying ``channels``."""
        plain = [c for c in channels if isinstance(c, ChannelCodec)]
        priority = max((c.priority for c in plain), default=None)
        ttls = [c.ttl_s for c in plain if c.ttl_s is not None]
        return self.routing.header(targets, priority, min(ttls, default=None))

    # -- what went out -------------------------------------------------------------------------

    def mark_sent(self, link: str, chosen: Sequence[ChannelState], built: float) -> None:
        """Latest values went out on ``link``: its store marks them sent, and so does every
        other link's store that carries none of their destinations now."""
        side = self.linkset.sides[link]
        side.store.mark_sent(chosen, built)
        for other in self.linkset.sides.values():
            if other is side:
                continue
            settled = [other.store.states[s.channel.index] for s in chosen
                       if s.channel.family is None and s.channel.index in other.store.states
                       and not self.policy.destinations(other, s.channel)]
            if settled:
                other.store.mark_sent(settled, built)

    def update(self, now: float) -> None:
        """Each link's peers re-evaluated, the policy following them (a destination that
        moves link gets its latching channels there), frames past their life dropped."""
        self.linkset.update(now)
        self.switched(self.policy.update(now))
        self.routing.expire(now)

    def switched(self, switches: Sequence[Switch]) -> None:
        """Destinations moved to another link: their latching channels go there once at
        once (the new link's store sends them at its next opportunity)."""
        for dest, _, link in switches:
            if link is None:
                continue
            store = self.linkset.sides[link].store
            for state in store.states.values():
                channel = state.channel
                if channel.latching and dest in channel.destinations(self.node):
                    store.resend(channel.index)

    # -- frames carried for others -------------------------------------------------------------

    def transmission(self, side: LinkSide, now: float, at: float, always: bool,
                     builder: Callable[..., OutFrame | None],
                     due: Callable[[float, LinkSide], list[Candidate]]) -> OutFrame | None:
        """What goes out at ``side``'s opportunity now (to start at modem time ``at``): the
        node's own frame (``builder``: :meth:`~bridge.core.outbound.Outbound.build`), or the
        frames it carries for others with its own in the room left, as a bundle; its own
        first when it is more urgent than any of them, and every other time when it is as
        urgent as the most urgent (``due``: what it has due)."""
        def build(room: int | None, always: bool) -> OutFrame | None:
            return builder(now, at, always=always, side=side, room=room)

        routing = self.routing
        routing.expire(now)
        routing.resend(side, now)
        if not routing.waiting[side.name]:
            return build(None, always)
        own_rank, best = self.own_rank(due(now, side)), routing.best_rank(side)
        first = own_rank is not None and best is not None and own_rank >= best
        if first and own_rank == best:  # a tie: own and carried take turns
            first = self._own_turn[side.name] = not self._own_turn.get(side.name, False)
        own = build(None, False) if first else None
        if own is not None:
            if len(own.data) > SEGMENT_MAX:
                return own
            picked = routing.pick(side, side.frame_bytes - NetCodec.bundle_bytes(
                [len(own.data)]), now, bundled=True)
        else:
            picked = routing.pick(side, side.frame_bytes, now)
            left = side.frame_bytes - NetCodec.bundle_bytes(len(d) for _, d in picked) - 1
            room = min(side.room, left, SEGMENT_MAX) - side.header_bytes
            own = build(room, False) if picked and room > 0 else None
        if not picked:
            return own if own is not None else build(None, always)
        frames = [d for _, d in picked]
        if own is None and len(frames) == 1:
            data, dest = frames[0], picked[0][0].dest
        else:
            data, dest = NetCodec.bundle([*frames, *([own.data] if own else [])]), None
        return OutFrame(data, dest, None, at, own.plan if own else routing.plan(), now,
                        link=side.name, carried=tuple(c for c, _ in picked), own=own)

    def relayed(self, side: LinkSide, out: OutFrame, now: float) -> None:
        """``out`` went out on ``side`` at ``now``: the frames it carries for others, and the
        node's own frame kept when it crosses relays with reliable values
        (:meth:`~bridge.core.routing.Routing.keep_own`)."""
        own = out.own if out.carried else out
        if own is not None:
            self.routing.keep_own(side, own.data, frozenset(
                (sender.channel.index, item.seq) for sender, item in own.streams
                if isinstance(sender, ReliableSender)), now)
        if not out.carried:
            return
        self.routing.sent(side, out.carried, now)
        side.last_tx = now
        for carried in out.carried:
            header = carried.header
            self.routing.outbox.event(FrameRelayed(
                now, self.routing.nodes[header.origin], len(carried.frame), side.name,
                side.name_of(carried.dest) if carried.dest is not None else None,
                header.hops))

    def acked(self, src: str, header: tuple[int, ...]) -> None:
        """An acknowledgement entry of ``src`` (for any node's stream) was heard: the frames
        this node keeps for it that it covers are released (:mod:`bridge.core.custody`)."""
        peer, stream, _, _, base, bitmap = header
        table = self.routing.table
        self.routing.custody.acked(src, table.nodes[peer], table.streams[stream].index, base,
                                   bitmap)

    # -- routes that fail -----------------------------------------------------------------------

    def explain(self, dest: str, now: float) -> str | None:
        """Where the route to ``dest`` breaks as this node sees it: the first hop whose far
        end it has not heard lately (directly, or through the hops before); None when
        ``dest`` is a neighbour."""
        path, problem = self.linkset.network.path(self.node, dest, self.policy.hops.get(dest))
        if problem is not None:
            return problem
        if len(path) <= 2:
            return None
        route = " -> ".join(path)
        health = self.linkset.node_health
        for prev, hop in itertools.pairwise(path):
            if health.states.get(hop) is not LinkState.UP:
                heard = health.last_heard.get(hop)
                when = "never heard" if heard is None else f"not heard for {now - heard:.0f} s"
                return f"route {route}: the hop {prev} -> {hop} is missing ({hop} {when})"
        return f"route {route}: every hop is heard; {dest} did not answer in time"

    def reach(self, dest: str, key: str, now: float) -> tuple[LinkState | None, str | None]:
        """How ``dest`` is reached for a query on ``key``: its link state, or for a node
        behind relays its first hop's (what a relay cannot tell this node before the
        query's deadline); and why the query ends at once (the first hop is down, or there
        is no route), if it does."""
        hop = self.policy.hops.get(dest)
        state = self.linkset.node_health.states.get(hop or dest)
        if hop is None or (hop != dest and state not in (LinkState.UP, LinkState.DEGRADED)):
            return state, f"{key}: no route to {dest}: {self.explain(dest, now)}"
        return state, None

    def explained(self, reports: list[Delivery], now: float) -> list[Delivery]:
        """Failures to a node reached through relays, with where its route breaks."""
        out = []
        for report in reports:
            why = self.explain(report.dst, now) if report.state == "failed" \
                and report.dst is not None else None
            out.append(report if why is None else replace(report, reason=f"{report.reason}; "
                                                           f"{why}"))
        return out

    def frames(self, rx: Reception, now: float) -> list[Reception]:
        """The frames of a transmission heard: itself, or each frame of a bundle (a bundle
        whose lengths do not add up is counted ``malformed``)."""
        try:
            segments = NetCodec.unbundle(rx.data)
        except FrameError as exc:
            self.routing.stats.frames_dropped["malformed"] += 1
            self.routing.outbox.event(FrameDropped(now, None, "malformed", str(exc), rx.data))
            return []
        if segments is None:
            return [rx]
        return [Reception(data, rx.src, rx.time, rx.meta) for data in segments]

    def own_rank(self, candidates: Sequence[Candidate]) -> int | None:
        """The rank of the most urgent own candidate (None: nothing due)."""
        if not candidates:
            return None
        priorities = [c.channel.priority for c in candidates
                      if isinstance(c.channel, ChannelCodec)]
        return self.routing.rank(max(priorities)) if priorities else 0
