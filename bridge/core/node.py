"""The bridge logic of one node, sans I/O: samples in, frames out, frames in, publications out.

:class:`NodeCore` never reads a clock, opens a socket or touches Zenoh: every method takes the
times it needs. It is a façade over parts that own their state: the sending side
(:class:`~bridge.core.outbound.Outbound`: store, streams, families, demand, frame building),
the receiving side (:class:`~bridge.core.inbound.Inbound`), the stream receivers and the
acks owed (:class:`~bridge.core.receivers.Receivers`), the links
(:class:`~bridge.core.link.Links`), the MAC (a :class:`~bridge.core.mac.Schedule`),
positioning (:class:`~bridge.core.ranges.Ranges`) and queries
(:class:`~bridge.core.queries.Queries`). A node on several links has a MAC per link
(:class:`~bridge.core.linkset.LinkSet`); their policy and its relaying are
:class:`~bridge.core.network.NodeNetwork`: the MAC methods take the link's name (None: the
node's first link, its only one in a mission without ``links``).

One way in per kind of event, one way out:

=============================================  ============================================
a sample on an input key, or its delete        :meth:`NodeCore.ingest`, :meth:`NodeCore.delete`
the MAC's next opportunity, and what to do     :meth:`NodeCore.wake_at`, :meth:`NodeCore.act`
the modem carried that out (or refused)        :meth:`NodeCore.done`
a frame heard                                  :meth:`NodeCore.receive`
a range the modem measured                     :meth:`NodeCore.modem_range`
time passes (links, expiries, coasting)        :meth:`NodeCore.tick`
a Zenoh get, and the local get it served       :meth:`NodeCore.ask`, :meth:`NodeCore.query_served`
a peer reachable over IP, or no longer         :meth:`NodeCore.ip_reachable`
everything produced since the last call        :meth:`NodeCore.take`
=============================================  ============================================

Outputs are :class:`~bridge.core.outputs.Publish`, :class:`~bridge.core.outputs.Status` and
:class:`~bridge.core.events.Event` records, in order, plus the query outputs.

Restarts. What a restart must not lose — every unfinished reliable value and transfer, each
receiver's delivered window, the authentication counter's reservation and replay windows, the
peers' epochs, each latching channel's value — is :meth:`NodeCore.state`, plain data that the
runtime saves (atomically, before it carries out the outputs or sends the frame that depend on
it: :attr:`NodeCore.needs_save`) and hands back to the next run. A node that starts without it
draws a new *epoch*; peers learn it from its frames and resynchronise (fresh receive windows
for it; everything outstanding to it sent again), so a reliable channel never wedges.
"""

from __future__ import annotations

import math
import random
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

from bridge.core.images import Images
from bridge.core.inbound import Inbound
from bridge.core.link import Links, LinkThresholds
from bridge.core.links_policy import LinkPolicy
from bridge.core.linkset import LinkSet
from bridge.core.loaded import LoadedMission
from bridge.core.mac import Schedule
from bridge.core.network import AUTH_WINDOW, NodeNetwork
from bridge.core.outbound import Outbound, OutFrame
from bridge.core.outputs import NodeStats, Outbox, Output, Publish, Status
from bridge.core.positioning import Positioning, needs_positioning
from bridge.core.queries import LocalGet, OverIp, Queries, QueryAnswer, QueryEnd, Ticket
from bridge.core.ranges import Ranges
from bridge.core.receivers import Receivers
from bridge.core.reception import ModemFix, ModemRange, RangingMode, Reception
from bridge.core.restarts import STATE_VERSION, resumable
from bridge.core.snapshot import snapshot
from bridge.errors import MissionError
from bridge.frozen import direct_init
from bridge.wire.auth import Authenticator
from bridge.wire.goby import frame_codec_for
from bridge.wire.seal import KeyRing, frame_authenticator

__all__ = ["Action", "NodeCore", "NodeStats", "OutFrame", "Output", "Ping", "Publish",
           "SendFrame", "Status", "Taken"]

EPOCHS = 256  # stream epochs, EPOCH_BITS wide


@direct_init
@dataclass(frozen=True)
class SendFrame:
    """At an open opportunity: send ``frame`` (asking ``frame.dest`` to ack it if ``frame.ack``;
    ``ranged``: the ack ranges, for ``ranging.ping``); ``until``: its turn's end, no try after."""

    frame: OutFrame
    ranged: bool = False
    until: float = math.inf


@dataclass(frozen=True)
class Ping:
    """What to do at an open opportunity: ask the modem for a two-way range to ``peer``."""

    peer: int


Action = SendFrame | Ping

Taken = Output | LocalGet | QueryAnswer | QueryEnd
"""What :meth:`NodeCore.take` gives: the parts' outputs, then what the queries ask of the
runtime (a local get) or answer (replies, ends)."""


class NodeCore:
    """One node's bridge logic: a façade over the parts that own its state."""

    def __init__(self, loaded: LoadedMission, node: str,
                 auth: Authenticator | None = None, rng: random.Random | None = None,
                 state: Mapping[str, Any] | None = None, key: bytes | KeyRing | None = None,
                 seed: int | None = None, outputs: Collection[type] | None = None) -> None:
        """``rng`` draws this run's epoch when there is no ``state`` (a fresh one per run by
        default; seeded for a reproducible simulation); ``state``: what :meth:`state` returned
        in the previous run, to resume from; ``key``: the frame key(s) of an authenticated
        mission (the core reads no file and no environment: its runtime loads the key);
        ``seed``: the MAC's draws (random access backoffs); ``outputs``: see :class:`Outbox`."""
        mission = self.mission = loaded.mission
        if node not in mission.nodes:
            raise ValueError(f"node {node!r} is not in mission {mission.mission!r}")
        table = self.table = loaded.table
        self.node = node
        rng = rng or random.Random()
        outbox = self._outbox = Outbox(outputs)
        self.stats: NodeStats = outbox.stats
        state = resumable(state, node, table.fingerprint.hex(), outbox)
        wire_auth = mission.wire.auth
        if wire_auth is not None and auth is None:
            if key is None:
                raise MissionError(f"{node}: wire.auth is on: give the frame key "
                                   "(the runtime loads it, see bridge.runtime.keys)")
            auth = frame_authenticator(table, key, mission.address_of(node), state.get("auth"),
                                       window=AUTH_WINDOW if table.net is not None else 0)
        self.auth = auth
        drawn = rng.randrange(EPOCHS)  # (drawn even when resumed: the draws that follow stay)
        self.epoch: int = state.get("epoch", drawn)
        self.codec = frame_codec_for(table, auth)
        self.modem_ranging: RangingMode | None = None  # how the modem ranges (the runtime says)
        self.queries = Queries(mission, table, node) if table.queries else None
        self.receivers = Receivers(table, outbox, state)
        self.outbound = Outbound(mission, table, node, self.codec, self.epoch, outbox,
                                 self.receivers, self.queries, rng, state)
        network = loaded.network
        self.thresholds = LinkThresholds.for_node(network, node)
        interest = self.outbound.interest
        self.links = Links(self.thresholds, table.foreign_nodes(node), outbox,
                           interest.repeat if interest is not None else None)
        self.linkset = LinkSet(network, table, node, outbox, self.links, self.outbound.store,
                               seed)
        self.schedule: Schedule = self.linkset.primary.schedule
        self.policy = LinkPolicy(mission, self.linkset, outbox)
        self.network = NodeNetwork.of(table, self.linkset, self.policy, outbox, rng, state)
        """Several links or routes: the links' policy and the frames carried for others."""
        if self.network is not None:
            self.outbound.attach(self.network)
        self.positioning = Positioning(mission, node) if needs_positioning(mission, node) else None
        self.ranges = Ranges(mission, self.positioning, outbox, self.outbound.drop_payload) \
            if self.positioning is not None else None
        if self.ranges is not None:
            self.outbound.delays = self.ranges.on_transmit
        self.inbound = Inbound(mission, node, self.codec, outbox, self.linkset, self.links,
                               self.receivers, self.outbound, self.queries, self.ranges,
                               sealed=auth is not None, network=self.network)
        out = self.outbound  # pictures and operators' controls come in as its samples
        self.images = out.images = self.inbound.images = Images(
            table, node, outbox, self.receivers, out.senders, out.drop_payload,
            out.bindings, state.get("images"), out.surfacing) if mission.images else None
        # what observers read (the parts' own objects)
        self.store, self.bindings, self.families = out.store, out.bindings, out.families
        self.senders, self.interest, self.surfacing = out.senders, out.interest, out.surfacing
        self.link_states, self.last_heard = self.links.states, self.links.last_heard
        self.received_at, self.mismatched = self.inbound.received_at, self.inbound.mismatched

    # -- state across restarts -----------------------------------------------------------------

    @property
    def needs_save(self) -> bool:
        """:meth:`state` changed in a way a restart must not lose: save it before carrying out
        the outputs or sending the frame just built."""
        return self._outbox.unsaved or (self.auth is not None and self.auth.changed)

    def storage(self, error: str | None, now: float) -> None:
        """The runtime's saves of :meth:`state` fail (``error``: why) or work (None); while
        they fail, new reliable values are refused (:mod:`bridge.core.saving`)."""
        event = self.outbound.saving.changed(error, now)
        if event is not None:
            self._outbox.status("state", event.to_dict())
            self._outbox.event(event)

    def saved(self) -> None:
        """The runtime saved :meth:`state`."""
        self._outbox.unsaved = False
        if self.auth is not None:
            self.auth.changed = False

    def state(self) -> dict[str, Any]:
        """Everything a restart must resume, as msgpack-able plain data."""
        return {
            "version": STATE_VERSION, "mission": self.mission.mission, "node": self.node,
            "fingerprint": self.table.fingerprint.hex(), "epoch": self.epoch,
            "peer_epochs": dict(self.receivers.peer_epochs), **self.outbound.state(),
            "receivers": self.receivers.state(),
            "auth": self.auth.state() if self.auth is not None else None,
            **({"images": self.images.state()} if self.images is not None else {}),
            **(self.network.routing.state() if self.network is not None else {}),
        }

    # -- the one way out -----------------------------------------------------------------------

    def take(self) -> list[Taken]:
        """Everything produced since the last call, in order (the queries' last)."""
        out: list[Taken] = self._outbox.take()  # type: ignore[assignment]  # (ours now)
        if self.queries is not None:
            out += self.queries.take()
        return out

    # -- samples in ----------------------------------------------------------------------------

    def ingest(self, key: str, data: bytes, encoding: str, now: float, ref: str | None = None,
               sample_key: str | None = None, attachment: bytes | None = None,
               taken: float | None = None) -> None:
        """A sample arrived on an input key (see :meth:`Outbound.ingest`)."""
        self.linkset.news()
        self.outbound.ingest(key, data, encoding, now, ref, sample_key, attachment, taken)

    def delete(self, key: str, now: float) -> None:
        """A Zenoh delete on an input key: a tombstone for the channels with ``deletes``."""
        self.outbound.delete(key, now)

    def ros2_input(self, key: str) -> Any:
        """The ROS 2 topic read on input ``key``, or None."""
        return self.outbound.ros2_input(key)

    def payload_cap(self, key: str) -> int:
        """The longest payload input ``key`` takes: a longer one is dropped before it is
        decoded (:func:`~bridge.wire.payloads.payload_cap`)."""
        return self.outbound.payload_cap(key)

    def drop_payload(self, key: str, reason: str, now: float, cause: str = "unfit") -> None:
        """Count a payload that cannot be used, by key and ``cause`` (logged and summarised at
        a bounded rate: :mod:`bridge.core.drops`)."""
        self.outbound.drop_payload(key, reason, now, cause)

    def numbers(self, key: str, data: bytes, encoding: str, names: tuple[str, ...],
                now: float) -> tuple[float, ...] | None:
        """The finite numbers ``names`` of a payload, or None (counted as a dropped payload)."""
        return self.outbound.numbers(key, data, encoding, names, now)

    def ip_reachable(self, peer: str, up: bool, now: float) -> None:
        """The peer's bridge became reachable over IP (``up``) or stopped being so."""
        self.outbound.ip_reachable(peer, up, now)

    # -- the MAC: when to wake, what to do, how it went -----------------------------------------

    def next_due(self, now: float | None = None, link: str | None = None) -> float | None:
        """When something (data, an acknowledgement, a retransmission, a heartbeat, a query or
        a ping) is next due (on ``link``); None while nothing is pending."""
        side = self.linkset.side(link) if self.network is not None else None
        due = self.outbound.next_due(now, side)
        if due == -math.inf:
            return due
        times = [due]
        if self.queries is not None:
            times.append(self.queries.next_due())
        if self.ranges is not None and link in (None, self.linkset.primary.name):
            times.append(self.ranges.next_ping())
        return min([t for t in times if t is not None], default=None)

    def wake_at(self, now: float, link: str | None = None) -> float | None:
        """When the MAC of ``link`` next has an opportunity for what is due (None: nothing
        is, wait for data or a frame); the runtime sleeps until then and calls :meth:`act`."""
        opp = self.linkset.side(link).opportunity(now, self.next_due(now, link))
        return None if opp is None else opp.start

    def act(self, now: float, at: float, link: str | None = None) -> Action | None:
        """What to do now on ``link``, if an opportunity is open: a frame built to start at
        modem time ``at``, or a ping (``ranging.ping`` with a modem that pings); None: nothing
        (the opportunity, if any, is given up). Report how it went with :meth:`done`."""
        side = self.linkset.side(link)
        opp = side.opportunity(now, self.next_due(now, link))
        if opp is None or opp.start > now + 1e-9:
            return None
        ranges = self.ranges if side is self.linkset.primary else None
        peer = ranges.due(now) if ranges is not None and self.modem_ranging \
            and opp.poll is None else None
        if peer is not None and self.modem_ranging is RangingMode.PING:
            return Ping(peer)
        net = self.network
        always = opp.must_send or peer is not None or self.outbound.heartbeat_due(
            now, side if net is not None else None)
        out = self.outbound.build(now, at, always=always) if net is None else \
            net.transmission(side, now, at, always, self.outbound.build, self.outbound.candidates)
        if out is None:
            side.skipped(now)
            return None
        if opp.poll is not None:  # the poll rides on the frame's destination address
            out = replace(out, dest=side.address_of(opp.poll))
        if peer is not None:  # the modem measures the range when the peer acknowledges
            out = replace(out, dest=peer, ack=True)
        return SendFrame(out, peer is not None, opp.until)

    def done(self, action: Action, start: float, end: float, *,
             confirmed: bool | None = None, error: str | None = None) -> None:
        """``action`` was carried out from ``start`` to ``end`` (runtime clock); ``error``:
        it failed (a frame's data stays due); ``confirmed``: the modem's acknowledgement."""
        dest = action.peer if isinstance(action, Ping) else (
            action.frame.dest if action.ranged else None)
        peer = self.mission.name_of(dest) if dest is not None else None
        if peer is not None and self.ranges is not None:
            self.ranges.asked(peer, start, error)
        side = self.linkset.side(action.frame.link if isinstance(action, SendFrame) else None)
        if isinstance(action, SendFrame):
            out = action.frame
            if error is None:
                if self.network is not None:
                    self.network.relayed(side, out, start)
                if (own := out.own if out.carried else out) is not None:
                    self.outbound.sent(own, start, confirmed)
            else:
                if self.ranges is not None:
                    self.ranges.forget_transmit(out.at)
                self.outbound.failed(error, start)
        if error is None:
            side.used(start, end)
        else:
            side.skipped(start, end)

    # -- frames and ranges in ------------------------------------------------------------------

    def receive(self, rx: Reception, now: float, modem_now: float | None = None,
                link: str | None = None) -> None:
        """Decode one received frame (heard on ``link``; ``modem_now``: the modem clock at the
        call, DLBL times are in it) and publish what it carries for this node."""
        side = self.linkset.side(link)
        frames = self.network.frames(rx, now) if self.network is not None else (rx,)
        for one in frames:
            self.inbound.receive(one, now, modem_now, side)

    def modem_range(self, rng: ModemRange, now: float) -> None:
        """The modem measured a range itself (a ping, a propagation time): publish it like a
        DLBL range, and the fix attempted with it."""
        peer = self.mission.name_of(rng.peer)
        if self.ranges is not None and peer is not None:
            self.ranges.modem_range(peer, rng.travel_time_s, rng.method, rng.time, now)

    def modem_fix(self, fix: ModemFix, now: float) -> None:
        """The modem's USBL head located a peer: published on ``usbl/<peer>`` as it is."""
        peer = self.mission.name_of(fix.peer)
        if peer is not None:
            self._outbox.status(f"usbl/{peer}", fix.payload())

    # -- time and queries ----------------------------------------------------------------------

    def tick(self, now: float) -> None:
        """Periodic work: link states (and which link carries what), reliable values past
        their TTL or retries, the tracker's news, queries past their deadline, held pictures."""
        self.update_links(now)
        self.outbound.expire(now)
        if self.ranges is not None:
            self.ranges.tick(now)
        if self.queries is not None:
            self.queries.expire(now)
        if self.images is not None:
            self.images.tick(now)
        self.outbound.tick(now)  # (drops summarised; latched values saved)

    def update_links(self, now: float) -> None:
        """Re-evaluate peers' links; changes go on ``link/``, ``links/``, ``route/<peer>``."""
        self.links.update(now)
        if self.network is not None:
            self.network.update(now)

    def ask(self, key: str, parameters: Any, now: float, until: float | None = None,
            wildcard: bool = False) -> Ticket | str | OverIp:
        """A Zenoh get on ``key`` (``wildcard``: matched by one) with ``parameters`` (a dict), its
        caller waiting ``until``: the ticket it waits on (QueryAnswer / QueryEnd), why it ends at
        once, or :class:`OverIp`: the server is reachable over IP, nothing crosses the water."""
        found = self.queries.spec_for(key) if self.queries is not None else None
        if found is None:
            return f"{key!r} is not a query of mission {self.mission.mission!r} at {self.node}"
        spec, server = found
        self.links.update(now)
        state, refused = (self.links.states.get(server), None) if self.network is None \
            else self.network.reach(server, key, now)
        return self.queries.ask(spec, server, parameters, now,  # type: ignore[union-attr]
                                state, until, refused, wildcard)

    def query_served(self, ticket: tuple[int, str, int], values: list[Any], now: float,
                     unusable: Sequence[tuple[str, str]] = ()) -> None:
        """The local get of a request ended: queue its replies for the asker (Queries.served)."""
        if self.queries is not None:
            self.queries.served(ticket, values, now, unusable)

    @property
    def last_tx(self) -> float | None:
        """When this node's last frame was built."""
        return self.outbound.last_tx

    def snapshot(self, now: float) -> dict[str, Any]:
        """Counters and channel ages as plain data (:func:`~bridge.core.snapshot.snapshot`)."""
        return snapshot(self.node, self.epoch, now, self.stats, self.outbound, self.inbound,
                        self.links, self.queries, self.table, self.network)
