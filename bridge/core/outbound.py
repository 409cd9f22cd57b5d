"""The sending side of a node (pure): samples in, frames out.

A sample on an input key is decoded and packed for every channel that reads the key: into the
latest-value store, the queue of a reliable or fragmented stream, or a key family's member.
At an opportunity :meth:`Outbound.build` fills a frame, priority then age, from what is due:
acknowledgements owed first, then latest values somebody wants, queued values and fragments,
family names and members, demand bitmaps and queries. :meth:`Outbound.sent` records the frame
the modem took. Heartbeats keep a silent node audible.
"""

from __future__ import annotations

import functools
import logging
import math
import random
from collections.abc import Callable, Collection, Mapping
from dataclasses import replace
from typing import TYPE_CHECKING, Any

from bridge.core.bounds import retry_floor_s, round_trip_s
from bridge.core.builder import Candidate, FramePlan, fill
from bridge.core.drops import DropLedger
from bridge.core.events import Delivery, FieldsLeftOut, FrameSent, SendFailed, Surfaced
from bridge.core.families import Extra, Families
from bridge.core.frames import OutFrame, Sender
from bridge.core.images import MAX_PICTURE_BYTES, Images, ImageSender, control_keys
from bridge.core.interest import Interest
from bridge.core.keyspace import Keyspace
from bridge.core.latched import Latched
from bridge.core.link import heartbeat_s
from bridge.core.linkset import LinkSide
from bridge.core.outputs import Outbox
from bridge.core.queries import Queries
from bridge.core.receivers import Receivers
from bridge.core.reliable import SEQ_MOD, ReliableSender, default_retry_s
from bridge.core.restarts import FAILED
from bridge.core.saving import Saving
from bridge.core.store import ChannelState, OutboundStore
from bridge.core.surfacing import Relay, Surfacing
from bridge.core.transfer import TransferSender
from bridge.errors import DecodeError, EncodeError
from bridge.mission.model import Mission
from bridge.wire.auth import Authenticator
from bridge.wire.channels import ChannelCodec, ChannelTable, ElementCodec
from bridge.wire.frame import FrameCodec, WireCodec
from bridge.wire.payloads import decode_payload, payload_cap
from bridge.wire.sample_meta import aged_payload, encoding_id, stamped, tombstone
from bridge.wire.unused import left_out, schema_tree, union, whole_names

if TYPE_CHECKING:
    from bridge.core.network import NodeNetwork
    from bridge.ros2.element import Ros2Element

__all__ = ["OutFrame", "Outbound", "Sender"]

log = logging.getLogger("zab.core")

LEFT_OUT_KEPT = 256
"""Sets of fields left out (per key) said once each; further ones are only counted."""
LEFT_OUT_EVERY_S = 60.0
"""Least time between two sets of fields left out told for one key (a flood of new field
names on a key is counted, told once a minute)."""
Delays = Callable[[float], list[int | None]]
"""The DLBL delays of a frame starting at a modem time."""


def _hinted(auth: Authenticator, address: int, built: float) -> None:
    """A frame telling ``address`` its replay mark left (built at ``built``)."""
    auth.hinted(address)


def _unfit(outbound: Outbound, channel: WireCodec, bits: int, now: float) -> bool:
    """Whether an entry of ``channel`` does not fit its ``wire_bits`` in a frame (a bug, such
    as a fragmented channel's whole value): then it is left out, a counted drop (cause
    ``unbuildable``) with a log line, never an error that ends the transmit task."""
    if bits >= 0 and not bits >> channel.wire_bits:
        return False
    outbound.drop_payload(channel.name, f"channel {channel.name!r}: an entry of "
                          f"{bits.bit_length()} bits does not fit its {channel.wire_bits} bits "
                          "in a frame (left out)", now, "unbuildable")
    return True


def _dropped(outbound: Outbound, states: list[ChannelState], now: float,
             side: LinkSide | None) -> None:
    """Latest values dropped from a frame, marked sent at ``now`` (due again when they are,
    not at every opportunity)."""
    if outbound.network is not None and side is not None:
        outbound.network.mark_sent(side.name, states, now)
    else:
        outbound.store.mark_sent(states, now)


class Outbound:
    """Store, streams, families, demand and heartbeats of one node, and its frames."""

    def __init__(self, mission: Mission, table: ChannelTable, node: str, codec: FrameCodec,
                 epoch: int, outbox: Outbox, receivers: Receivers, queries: Queries | None,
                 rng: random.Random, state: Mapping[str, Any]) -> None:
        self.mission = mission
        self.table = table
        self.node = node
        self.codec = codec
        self.epoch = epoch
        self.outbox = outbox
        self.stats = outbox.stats
        self.drops = DropLedger(node)  # payloads dropped: counted, told at a bounded rate
        self.stats.payloads_dropped = self.drops.by_key
        self.saving = Saving()  # whether the runtime can save the state (bridge.core.saving)
        self.receivers = receivers
        self.queries = queries
        if queries is not None:  # a get or a reply that cannot be used: told as a put's
            queries.drop, queries.told_left_out = self.drop_payload, self.report_left_out
        self.delays: Delays | None = None
        """The DLBL delays of each frame built (set by the node when it ranges)."""
        self.images: Images | None = None
        """The image channels' inputs and controls (set by the node when it has some)."""
        self.frame_bytes = mission.node_modem(node).frame_bytes
        self.heartbeat_s = heartbeat_s(mission)
        self.last_tx: float | None = None
        self._started: float | None = None
        self.store = OutboundStore.for_node(table.channels, node)
        self.network: NodeNetwork | None = None
        """The node's links, their policy and its frames' network header (:meth:`attach`)."""
        self.stores = [self.store]
        """The store of each link (the first is :attr:`store`)."""
        self.latched = Latched(self.store, outbox, node)
        """The latching channels' values kept across restarts."""
        self.latched.resume(state.get("latched"), table.channels)
        self._failed: list[Delivery] = list(state.get(FAILED, ()))
        """Values an earlier run under another mission left unfinished, reported failed at the
        first tick (at its time)."""
        self.families = Families(table, node, self.latched.put)
        self.latched.unresumed += self.families.resume(state.get("families"))
        self.surfacing = Surfacing(node, mission.surfacing.republish) \
            if mission.surfacing is not None else None
        if queries is not None:  # (a get to a server reachable over IP goes over IP)
            queries.surfacing = self.surfacing
        self.interest = Interest(table.interest, mission.demand.refresh_s) \
            if table.interest is not None and mission.demand is not None else None
        self.bindings: dict[str, list[tuple[ChannelCodec, int, ElementCodec]]] = {}
        for channel in table.channels:  # (an image channel's keys are Images')
            if channel.index in self.store.states and channel.family is None \
                    and channel.image is None:
                for i, element in enumerate(channel.elements):
                    self.bindings.setdefault(element.input_key(node), []).append(
                        (channel, i, element))
        self._ros2_inputs = {key: next((e.ros2 for _, _, e in found if e.ros2 is not None), None)
                             for key, found in self.bindings.items()}
        self._caps = {key: payload_cap(max(e.layout.bits for _, _, e in found))
                      for key, found in self.bindings.items()}
        self._cap = payload_cap(max((e.layout.bits for c in table.channels
                                     for e in c.elements), default=0))
        pictures = [c.image.input_key(node) for c in table.channels
                    if c.image is not None and not c.image.control and c.sent_by(node)]
        self.keyspace = Keyspace(mission, table, node,
                                 [*self.bindings, *self.families.subscriptions(), *pictures],
                                 outbox, self.surfacing, control_keys(table, node))
        metas = [(key, e.meta) for key, found in self.bindings.items() for _, _, e in found]
        metas += [(key, e.meta) for key, found in self.families.subscriptions().items()
                  for c, i in found for e in (c.elements[i],)]
        self._stamped = {key for key, meta in metas if meta is not None}
        """Input keys whose channels carry fields beside the value (sample_meta)."""
        self._attached = {key for key, meta in metas if meta and meta.attachment_bytes}
        self._aged = {c.index for c in table.channels if any(e.meta and e.meta.age_step_s
                                                             for e in c.elements)}
        self._read = {key: union(schema_tree(e.layout.json_schema()) for _, _, e in found)
                      for key, found in self.bindings.items() if self._ros2_inputs[key] is None}
        """The fields each input key's channels read (to report those left out)."""
        self._whole = {key: whole_names(tree) for key, tree in self._read.items()}
        """Per key of :attr:`_read`, the names read whole: a sample of only these (the usual
        one) is not walked."""
        self._left_out: set[tuple[str, tuple[str, ...]]] = set()
        self._left_out_told: dict[str, float] = {}  # key ("" for any) → when last told
        self._never_fit = self._unfit_channels()
        """Channels this node sends that no frame of its can hold (``zab check`` says so):
        a value for one is a counted drop, not a channel due for ever."""
        retry_s = default_retry_s(mission)
        self.senders: dict[int, Sender] = {
            c.index: (ImageSender if c.image is not None and not c.image.control
                      else TransferSender if c.fragmented else ReliableSender)(
                c, c.destinations(node), retry_s, rng.randrange(SEQ_MOD))
            for c in table.streams if c.index in self.store.states}
        self._streamed: dict[int, float] = {}
        """When each stream (by channel index) last had something in a frame: its values and
        fragments wait from then, so streams of one priority take turns."""
        by_name = {s.channel.name: s for s in self.senders.values()}
        for name, saved in (state.get("senders") or {}).items():
            if name in by_name:
                by_name[name].restore(saved)
        self._filtered = self.interest is not None or self.surfacing is not None

    def attach(self, network: NodeNetwork) -> None:
        """The node's links (each its store, schedule, frame size), their policy, and what
        puts the network header on its frames (several links or routes)."""
        self.network = network
        self.stores = network.linkset.stores
        self.latched.onto(self.stores[1:])  # (the values resumed, on every link)
        self._filtered = self._filtered or not network.policy.single
        routes = network.routing.network
        floor = retry_floor_s(routes, self.node)
        for sender in self.senders.values():
            if isinstance(sender, TransferSender):
                sender.behind_relays(d for d in sender.dests
                                     if routes.next_hop(self.node, d) not in (d, None))
            elif isinstance(sender, ReliableSender):
                sender.learn({d: trip for d in sender.dests
                              if math.isfinite(trip := round_trip_s(routes, self.node, d))},
                             floor, network.linkset.node_health.last_heard)
        if self.queries is not None:  # a query's timeout says where its route breaks
            self.queries.explain = network.explain

    # -- samples in ------------------------------------------------------------------------------

    def ingest(self, key: str, data: bytes, encoding: str, now: float,
               ref: str | None = None, sample_key: str | None = None,
               attachment: bytes | None = None, taken: float | None = None) -> None:
        """A sample arrived on an input key: pack it for every channel that reads the key.

        ``ref`` (the publisher's correlation text) is echoed in delivery reports;
        ``sample_key`` is the sample's own key when ``key`` has wildcards (ROS 2 inputs);
        ``attachment``: the sample's, carried by channels with ``attachment_bytes``;
        ``taken``: the sample's own timestamp, if it has one (when its value was taken: what
        a channel's ``age`` carries, never later than ``now``). A payload over the key's cap
        is dropped before it is decoded (pictures: see Images)."""
        if self.images is not None and self.images.ingest(key, data, encoding, now, ref):
            return
        if len(data) > (cap := self._caps.get(key, self._cap)):  # (self.payload_cap, inlined)
            self.drop_payload(key, f"{len(data)} bytes, over this key's cap of {cap}", now,
                              "too_large")
            return
        bindings = self.bindings.get(key, ())
        ros2 = self._ros2_inputs.get(key)
        try:
            value = (ros2.decode(data, sample_key or key) if ros2 is not None
                     else decode_payload(data, encoding))
            read = self._read.get(key)
            if read is not None and not (value.__class__ is dict
                                         and value.keys() <= self._whole[key]) \
                    and (extra := left_out(value, read)):
                self.report_left_out(key, extra, now)
            if self._stamped and (key in self._stamped or self.families.senders):
                value = stamped(value, encoding_id(encoding, data), attachment)
        except DecodeError as exc:
            self.drop_payload(key, str(exc), now, "undecodable")
            return
        taken = now if taken is None else min(taken, now)
        self._store(key, bindings, lambda element: element.layout.pack(value), now, ref, taken)
        if self.families.senders:
            for problem in self.families.ingest(key, value, now):
                self.drop_payload(key, problem, now)
        if self.surfacing is not None and self.surfacing.reachable:  # full fidelity over IP
            self._relay(key, bindings, Relay(key, data, encoding, attachment if key in
                                             self._attached else None, taken=taken))

    def delete(self, key: str, now: float) -> None:
        """A Zenoh delete on an input key: a tombstone in each channel with ``deletes`` that
        reads the key (its latched value is not sent again)."""
        bindings = [b for b in self.bindings.get(key, ()) if b[2].meta and b[2].meta.deletes]
        self._store(key, bindings, lambda element: tombstone(element.layout), now, None)
        for problem in self.families.delete(key, now):
            self.drop_payload(key, problem, now)
        if self.surfacing is not None and self.surfacing.reachable:
            self._relay(key, bindings, Relay(key, b"", "", delete=True, taken=now))

    def _unfit_channels(self) -> dict[int, str]:
        """Why each channel sent whole by this node fits in none of its links' frames, beside
        the frame's overhead and count field (queries' repeatable entries lengthen it)."""
        mission, codec, node = self.mission, self.codec, self.node
        biggest = max(mission.frame_sizes_of(node), default=mission.modem.frame_bytes)
        room = codec.body_capacity_bits(biggest - self.table.net_header_bytes) \
            - codec.count_bits
        return {c.index: f"channel {c.name!r} ({codec.channel_cost_bits(c)} bits with its "
                         f"index) can never fit in a {biggest}-byte frame of {node!r} ({room} "
                         "bits free after overhead): see zab check"
                for c in self.table.channels if c.index in self.store.states
                and not c.fragmented and codec.channel_cost_bits(c) > room}

    def _store(self, key: str, bindings: Collection[tuple[ChannelCodec, int, ElementCodec]],
               pack: Callable[[ElementCodec], int], now: float, ref: str | None,
               taken: float | None = None) -> None:
        """Each binding's packed value into the store (taken at ``taken``), or queued by its
        stream."""
        store = self.store
        latched = False  # a latching channel's value changed (saved across restarts)
        for channel, index, element in bindings:
            if channel.index in self._never_fit:
                self.drop_payload(key, self._never_fit[channel.index], now)
                continue
            try:
                packed = pack(element)
            except EncodeError as exc:
                self.drop_payload(key, f"channel {channel.name!r}: {exc}", now)
                continue
            sender = self.senders.get(channel.index)
            if sender is None:
                store.update(channel.index, index, packed, now, taken)
                if len(self.stores) > 1:
                    for other in self.stores[1:]:
                        other.update(channel.index, index, packed, now, taken)
                latched = latched or channel.latching
            elif store.update_value(channel.index, index, packed, now):
                payload = store.states[channel.index].payload()
                refused = self.saving.refusal()  # (while the state cannot be saved)
                reports = sender.offer(payload, now, key, ref) if refused is None \
                    else sender.refuse(now, key, ref, refused)
                self.outbox.reports(reports, changed=sender.changed)
        if latched:
            self.latched.put(now)

    def _relay(self, key: str, bindings: Collection[tuple[ChannelCodec, int, ElementCodec]],
               relay: Relay) -> None:
        """A sample (or a delete) put as it came on the output keys of the destinations
        reachable over IP (full fidelity), with the attachment the acoustic path carries."""
        assert self.surfacing is not None
        outs = [(d, element.output_key(self.node, d))
                for channel, _, element in bindings if not channel.stream
                for d in channel.destinations(self.node)]
        self.outbox.items.extend(self.surfacing.relays(
            key, outs + self.families.outputs_for(key), relay))

    def report_left_out(self, key: str, fields: list[str], now: float) -> None:
        """Fields of a sample on ``key`` that no channel carries: counted per sample, logged
        and reported (an event) once per key and set of fields, a set a minute per key
        (:data:`LEFT_OUT_EVERY_S`) and one a second in all (at most :data:`LEFT_OUT_KEPT`
        sets: a flood of new field names is counted, not told)."""
        self.stats.fields_left_out[key] += 1
        seen = (key, tuple(fields))
        told = self._left_out_told
        if seen not in self._left_out and len(self._left_out) < LEFT_OUT_KEPT \
                and not 0.0 <= now - told.get(key, -math.inf) < LEFT_OUT_EVERY_S \
                and not 0.0 <= now - told.get("", -math.inf) < 1.0:
            self._left_out.add(seen)
            told[key] = told[""] = now
            log.warning("%s: fields %s of %r are carried by no channel: they do not cross "
                        "(counted; said once)", self.node, ", ".join(fields), key)
            self.outbox.event(FieldsLeftOut(now, key, fields))

    def ros2_input(self, key: str) -> Ros2Element | None:
        """The ROS 2 topic read on input ``key``, or None."""
        return self._ros2_inputs.get(key)

    def payload_cap(self, key: str) -> int:
        """The longest payload input ``key`` takes (:func:`~bridge.wire.payloads.payload_cap`
        of the bits its channels keep); a picture key's is
        :data:`~bridge.core.images.MAX_PICTURE_BYTES`."""
        cap = self._caps.get(key)
        if cap is None:
            pictures = self.images is not None and key in self.images.inputs
            return MAX_PICTURE_BYTES if pictures else self._cap
        return cap

    def drop_payload(self, key: str, reason: str, now: float, cause: str = "unfit") -> None:
        """Count a payload that cannot be used, by key and ``cause`` (logged and summarised at
        a bounded rate: :mod:`bridge.core.drops`)."""
        summary = self.drops.drop(key, cause, reason, now)
        if summary is not None:
            self.outbox.event(summary)

    def tick(self, now: float) -> None:
        """Periodic work: the latched values an earlier run saved that could not be resumed
        counted as drops, the values it left unfinished under another mission reported failed,
        latched values saved if it is time (:mod:`bridge.core.latched`), the drops not
        summarised yet summarised if it is time (a summary a second at most)."""
        for name, why in self.latched.take_unresumed(now):
            self.drop_payload(name, why, now, "unresumable")
        if self._failed:
            self.outbox.reports([replace(d, time=now) for d in self._failed])
            self._failed = []
        self.latched.tick(now)
        if (summary := self.drops.due(now)) is not None:
            self.outbox.event(summary)

    def numbers(self, key: str, data: bytes, encoding: str, names: tuple[str, ...],
                now: float) -> tuple[float, ...] | None:
        """The finite numbers ``names`` of a payload, or None (counted as a dropped payload)."""
        try:
            if len(data) > (cap := self.payload_cap(key)):
                raise DecodeError(f"{len(data)} bytes, over the cap of {cap}")
            value = decode_payload(data, encoding)
            numbers = tuple(float(value[k]) for k in names)
            if not all(map(math.isfinite, numbers)):
                raise ValueError("not finite")
            return numbers
        except (DecodeError, TypeError, KeyError, ValueError) as exc:
            self.drop_payload(key, f"needs numbers {', '.join(names)}: {exc}", now)
            return None

    def ip_reachable(self, peer: str, up: bool, now: float) -> None:
        """The peer's bridge became reachable over IP (``up``) or stopped being so."""
        if self.surfacing is not None and self.surfacing.changed(peer, up, now):
            event = Surfaced(now, peer, up)
            self.outbox.status(f"surfaced/{peer}", event.to_dict())
            self.outbox.event(event)

    # -- what is due -----------------------------------------------------------------------------

    def next_due(self, now: float | None, side: LinkSide | None = None) -> float | None:
        """When data, an acknowledgement, a retransmission or a heartbeat is next due on
        ``side`` (default: the node's only link), without queries and pings, which the node
        adds; None while nothing is pending."""
        if now is not None and self._started is None:
            self._started = now  # the node first plans: its first heartbeat one period later
        if self.network is not None and side is not None:
            return self._next_due_on(now, side, self.network)
        if self.receivers.due or (self.codec.auth is not None and self.codec.auth.owed):
            return -math.inf  # (a peer waits for an acknowledgement, or for its @mark)
        times = [self._store_next_due(now), self.next_heartbeat()]
        if self.families.senders:
            times.append(self.families.next_due(now, self.wants))
        if self.interest is not None:
            times.append(self.interest.next_due())
        if self.senders:
            times += [s.next_time() for s in self.senders.values()]
        return min([t for t in times if t is not None], default=None)

    def _next_due_on(self, now: float | None, side: LinkSide, net: NodeNetwork
                     ) -> float | None:
        """:meth:`next_due` on one of the node's links."""
        policy, auth = net.policy, self.codec.auth
        if any(policy.serves(side, src) for src in self.receivers.due_to()) or (
                auth is not None and auth.owed):
            return -math.inf  # (an acknowledgement, or a peer's @mark)
        times = [self._store_next_due(now, side), self.next_heartbeat(side),
                 net.next_carried(side)]
        if self.families.senders:
            times.append(self.families.next_due(now, lambda c: self.wants(c, side)))
        if self.interest is not None:
            times.append(self.interest.next_due())
        times += [net.stream_due(side, s) for s in self.senders.values()]
        return min([t for t in times if t is not None], default=None)

    def next_heartbeat(self, side: LinkSide | None = None) -> float | None:
        """When a frame is due on ``side`` (default: the node's only link) to keep it heard."""
        beat_s = self.heartbeat_s if side is None else side.heartbeat_s
        if beat_s is None:
            return None
        last = self.last_tx if side is None else side.last_tx
        since = self._started if last is None else last
        return -math.inf if since is None else since + beat_s

    def heartbeat_due(self, now: float, side: LinkSide | None = None) -> bool:
        beat = self.next_heartbeat(side)
        return beat is not None and beat <= now + 1e-9

    def _store_next_due(self, now: float | None, side: LinkSide | None = None
                        ) -> float | None:
        """When a latest-value channel somebody wants becomes due (on ``side``)."""
        store = self.store if side is None else side.store
        if not self._filtered:
            return store.next_due(now)
        times = [t for s in store.states.values()
                 if self.wants(s.channel, side) and (t := s.ready_at(now)) is not None]
        return min(times, default=None)

    def wants(self, channel: ChannelCodec, side: LinkSide | None = None) -> bool:
        """Whether some destination reached over ``side`` (default: any) wants ``channel``
        now (always, without demand, surfacing or several links)."""
        if not self._filtered or channel.stream:
            return True
        destinations = channel.destinations(self.node) if side is None or \
            self.network is None else self.network.policy.destinations(side, channel)
        if self.surfacing is not None:
            destinations = self.surfacing.acoustic(destinations)
        return bool(destinations) and (self.interest is None
                                       or self.interest.wants(channel, destinations))

    def candidates(self, now: float, side: LinkSide | None = None) -> list[Candidate]:
        """Everything that could go in a frame sent at ``now`` (on ``side``)."""
        due = (self.store if side is None else side.store).due(now)
        if self._filtered:
            due = [s for s in due if self.wants(s.channel, side)]
        out = [Candidate(s.channel, s.last_sent, s) for s in due]
        if self.interest is not None and (want := self.interest.candidate(now)) is not None:
            out.append(want)
        if self.queries is not None:
            out += self.queries.candidates(now)
        for sender in self.senders.values():
            since = self._streamed.get(sender.channel.index)
            out += [Candidate(sender.channel, since, (sender, item), n)
                    for n, item in enumerate(sender.due(now))]
        if self.families.senders:
            out += self.families.candidates(now, lambda c: self.wants(c, side))
        if self.codec.auth is not None and self.codec.auth.owed:
            out += self._marks()
        if self.network is not None and side is not None:
            out = self.network.carried_by(side, out)
        return out

    def _marks(self) -> list[Candidate]:
        """The ``@mark`` entries owed to senders whose frames were refused as replayed
        (:mod:`bridge.wire.marks`)."""
        codec, auth = self.table.marks, self.codec.auth
        assert codec is not None and auth is not None
        out = []
        for address, mark in auth.hints():
            peer = self.mission.name_of(address)
            if peer is not None:
                hinted = functools.partial(_hinted, auth, address)
                out.append(Candidate(codec, None, Extra(
                    codec, codec.pack(self.table.nodes.index(peer), mark), hinted, peer)))
        return out

    # -- frames out ------------------------------------------------------------------------------

    def build(self, now: float, at: float, *, always: bool = False,
              side: LinkSide | None = None, room: int | None = None) -> OutFrame | None:
        """A frame of what is due at ``now``, to start at modem time ``at`` on ``side``
        (default: the node's only link) in ``room`` bytes after its network header (default:
        the link's); None when there is nothing to send and ``always`` is false, or the wire
        format has no empty frame (Goby's). Report it with :meth:`sent` or :meth:`failed`."""
        codec, net = self.codec, self.network if side is not None else None
        if room is None:
            room = self.frame_bytes if net is None else side.room  # type: ignore[union-attr]
        budget = codec.body_capacity_bits(room) - codec.count_bits
        items: list[tuple[WireCodec, int]] = []
        targets: set[str] = set()
        acks: list[tuple[str, int]] = []
        receivers, entries = self.receivers, (1 << codec.count_bits) - 1
        riding: list[tuple[str, int]] = []  # repeated acks to nodes behind a relay
        ack_codec = self.table.ack
        cost = 0 if ack_codec is None else codec.channel_cost_bits(ack_codec)
        if receivers.owing:  # acknowledgements first: they unblock the peer
            assert ack_codec is not None
            for src, index in receivers.owed():
                if net is not None and not net.policy.serves(side, src):  # type: ignore[arg-type]
                    continue  # owed over another link
                if net is not None and net.policy.hops.get(src, src) != src \
                        and not receivers.owed_now(src, index):
                    riding.append((src, index))  # (only in a frame relayed to it anyway)
                    continue
                if cost > budget or len(items) >= entries:
                    break
                items.append((ack_codec, receivers.ack_bits(src, index)))
                budget -= cost
                acks.append((src, index))
                targets.add(src)
        picked, left = fill(codec, self.candidates(now, side), budget, entries - len(items))
        chosen: list[ChannelState] = []
        dropped: list[ChannelState] = []
        streams: list[tuple[Sender, Any]] = []
        extras: list[Extra] = []
        asks_ack = False  # a channel in the frame asks for the modem's acknowledgement
        node = self.node
        for candidate in picked:
            what = candidate.what
            if isinstance(what, Extra):
                if _unfit(self, what.channel, what.bits, now):
                    continue
                extras.append(what)
                items.append((what.channel, what.bits))
                if net is not None:
                    targets |= net.extra_targets(side, what)  # type: ignore[arg-type]
                continue
            if isinstance(what, ChannelState):
                channel = what.channel
                bits = what.payload() if channel.index not in self._aged \
                    else aged_payload(channel.elements, what.packed, what.taken, now)
                if _unfit(self, channel, bits, now):
                    dropped.append(what)  # (marked sent: due again when it is)
                    continue
                chosen.append(what)
                items.append((channel, bits))
            else:
                sender, item = what
                channel = sender.channel
                bits = sender.entry(item)
                if _unfit(self, channel, bits, now):
                    continue
                streams.append((sender, item))
                items.append((channel, bits))
            targets.update(channel.destinations(node) if net is None
                           else net.targets(side, channel, what))  # type: ignore[arg-type]
            asks_ack = asks_ack or channel.ack
        if riding:  # a repeat never makes a relay carry a frame: it rides one that goes
            budget -= sum(codec.channel_cost_bits(c.channel) for c in picked)
            for src, index in riding:  # to its node anyway, in the room left
                if src in targets and cost <= budget and len(items) < entries:
                    assert ack_codec is not None
                    items.append((ack_codec, receivers.ack_bits(src, index)))
                    budget -= cost
                    acks.append((src, index))
        if dropped:
            _dropped(self, dropped, now, side)
        left_out = tuple(c.what for c in left if isinstance(c.what, ChannelState))
        self.stats.left_out += len(left_out)
        if not items and not (always and codec.empty_frames):
            return None
        delays = self.delays(at) if self.delays is not None and self.table.dlbl else ()
        try:
            data = codec.encode(items, delays, self.epoch, now) if net is None else \
                codec.encode(items, delays, self.epoch, now,
                             prefix=net.header(targets, [c.channel for c in picked]))
        except (ValueError, OverflowError) as exc:  # (a bug: never the transmit task's end)
            self.drop_payload("(frame)", f"a frame could not be built: {exc}", now,
                              "unbuildable")
            _dropped(self, chosen, now, side)
            return None
        if net is not None:  # (the next hop's address: a relayed target's neighbour)
            targets = {net.policy.hops.get(t, t) for t in targets}
        dest, ack = self.addressing(targets, asks_ack, side)
        return OutFrame(data, dest, ack, at, FramePlan(tuple(chosen), left_out), now,
                        tuple(streams), tuple(acks), tuple(extras),
                        None if side is None else side.name)

    def addressing(self, targets: Collection[str], asks_ack: bool,
                   side: LinkSide | None = None) -> tuple[int | None, bool | None]:
        """Where a frame for ``targets`` goes: the unicast address (on ``side``) when they are
        one node (else None, broadcast), and the modem's acknowledgement, asked only of a
        unicast."""
        dest = None
        if len(targets) == 1:
            target = next(iter(targets))
            dest = self.mission.address_of(target) if side is None else side.address_of(target)
        return dest, (True if dest is not None and asks_ack else None)

    def sent(self, out: OutFrame, now: float, confirmed: bool | None = None) -> None:
        """The modem accepted ``out`` at ``now``; ``confirmed``: its own acknowledgement said
        the frame reached ``out.dest`` (reliable entries in it are then not re-sent, only
        awaited)."""
        if self.network is not None and out.link is not None:
            self.network.mark_sent(out.link, out.plan.chosen, out.built)
            self.network.linkset.sides[out.link].last_tx = out.built
        else:
            self.store.mark_sent(out.plan.chosen, out.built)
        by_sender: dict[int, tuple[Sender, list[Any]]] = {}
        for sender, item in out.streams:
            by_sender.setdefault(id(sender), (sender, []))[1].append(item)
        dest = self.mission.name_of(out.dest) if out.dest is not None else None
        for sender, group in by_sender.values():
            self._streamed[sender.channel.index] = out.built
            self.outbox.reports(sender.sent(group, out.built))
            if confirmed and dest is not None:
                sender.confirmed(group, dest)
        self.receivers.acked(out.acks, now)
        if out.streams:
            self.outbox.unsaved = True
        for extra in out.extras:
            extra.on_sent(out.built)
        self.last_tx = out.built
        stats = self.stats
        stats.frames_sent += 1
        names = [s.channel.name for s in out.plan.chosen]
        if out.streams:
            names += [s.channel.name for s, _ in out.streams]
        for name in names:
            stats.sent_per_channel[name] += 1
        self.outbox.event(FrameSent(now, len(out.data), names, dest, out.data,
                                    out.link if self.network is not None
                                    and self.network.linkset.network.several else None))

    def failed(self, error: str, now: float) -> None:
        """The modem refused a frame: its data stays due."""
        self.stats.send_errors += 1
        self.outbox.event(SendFailed(now, error))

    # -- the streams' other end ------------------------------------------------------------------

    def on_ack(self, src: str, header: tuple[int, ...], now: float) -> None:
        """An acknowledgement entry from ``src`` (for this node's streams, or another's)."""
        peer, stream, epoch, tid, base, bitmap = header
        if self.table.nodes[peer] != self.node:
            return  # acknowledges someone else
        if epoch != self.epoch:
            return  # a window of an earlier run of this node
        channel = self.table.streams[stream]
        sender = self.senders.get(channel.index)
        if sender is None or src not in sender.dests:
            return
        if isinstance(sender, TransferSender):
            self.outbox.reports(sender.on_ack(src, tid, base, bitmap, now))
            progress = sender.progress()
            if progress is not None:
                self.outbox.status(f"transfer/{channel.name}", {**progress, "time": now})
        else:
            self.outbox.reports(sender.on_ack(src, base, bitmap, now))

    def resync(self, peer: str) -> None:
        """``peer`` started afresh: send it again everything outstanding."""
        for sender in self.senders.values():
            if peer in sender.dests:
                sender.resync(peer)

    def expire(self, now: float) -> None:
        """Reliable values past their TTL or retries are reported failed."""
        for sender in self.senders.values():
            reports = sender.expire(now)
            if reports and self.network is not None:
                reports = self.network.explained(reports, now)
            self.outbox.reports(reports)

    def state(self) -> dict[str, Any]:
        """What a restart resumes of the sending side: its streams' values (``senders``) and
        its latching channels' (``latched``, when it holds some) and its key families' names and
        latching values (``families``)."""
        latched = self.latched.state()
        families = self.families.state()
        return {"senders": {s.channel.name: s.state() for s in self.senders.values()},
                **({"latched": latched} if latched else {}),
                **({"families": families} if families else {})}
