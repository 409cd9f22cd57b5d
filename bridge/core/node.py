"""The bridge logic of one node, sans I/O: samples in, frames out, frames in, publications out.

:class:`NodeCore` never reads a clock, opens a socket or touches Zenoh: every method takes the
times it needs, and what the node must publish or report accumulates as *outputs* the caller
takes with :meth:`NodeCore.take`. The asyncio + Zenoh adapter
(:mod:`bridge.runtime.zenoh_node`) and the
virtual-clock simulator (:mod:`bridge.runtime.virtual_fleet`) drive the same core.

Outputs:

- :class:`Publish`: a decoded value for an application key (the receiving side of a channel);
- :class:`Status`: bridge state under ``@zab/<mission>/<node>/<topic>`` (stats, link, range, …);
- an :class:`~bridge.core.events.Event` (:class:`~bridge.core.events.FrameSent`,
  :class:`~bridge.core.events.FrameReceived`, :class:`~bridge.core.events.Link`, …) for
  in-process observers; the notable ones are also published on ``…/events``.

Restarts. What a restart must not lose — every unfinished reliable value and transfer, each
receiver's delivered window, the authentication counter's reservation and replay windows, the
peers' epochs — is :meth:`NodeCore.state`, plain data that the runtime saves (atomically,
before it carries out the outputs or sends the frame that depend on it: see
:attr:`NodeCore.needs_save`) and hands back to the next run. A node that starts without it
draws a new *epoch*; peers learn it from its frames and resynchronise (fresh receive windows
for it; everything outstanding to it sent again), so a reliable channel never wedges.
"""

from __future__ import annotations

import logging
import math
import random
from collections import Counter
from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass, field, replace
from functools import partial
from typing import TYPE_CHECKING, Any

from bridge.core.builder import Candidate, FramePlan, fill
from bridge.core.drops import DropLedger, clamps
from bridge.core.events import (
    Delivery,
    Event,
    FrameDropped,
    FrameReceived,
    FrameSent,
    Link,
    MissionMismatch,
    PeerRestarted,
    Position,
    Range,
    RangeFailed,
    SendFailed,
    Surfaced,
)
from bridge.core.families import Extra, Families
from bridge.core.interest import Interest
from bridge.core.lanes import Clearance, Lane, clearance_after, hears_plainly, lanes_for
from bridge.core.link import LinkState, LinkThresholds, LinkWatch, heartbeat_s
from bridge.core.mac import Schedule, schedule_for
from bridge.core.positioning import Positioning, Update, needs_positioning
from bridge.core.queries import Queries, Ticket
from bridge.core.reliable import SEQ_MOD, ReliableReceiver, ReliableSender, default_retry_s
from bridge.core.saving import Saving
from bridge.core.store import ChannelState, OutboundStore
from bridge.core.surfacing import Surfacing
from bridge.core.transfer import TransferReceiver, TransferSender, from_bytes
from bridge.dccl.goby import frame_codec_for
from bridge.errors import DecodeError, EncodeError, FrameError, MissionError
from bridge.frozen import direct_init
from bridge.mission.loader import LoadedMission
from bridge.modems.reception import ModemRange, Reception
from bridge.wire.auth import Authenticator
from bridge.wire.channels import AckCodec, ChannelCodec, ElementCodec
from bridge.wire.families import NameCodec
from bridge.wire.frame import DecodedFrame, Entry
from bridge.wire.interest import InterestCodec
from bridge.wire.marks import MarkCodec
from bridge.wire.payloads import decode_payload, payload_cap
from bridge.wire.queries import QueryCodec

if TYPE_CHECKING:
    from bridge.ros2.element import Ros2Element

HearPlan = tuple[tuple[str, str, bool, "Ros2Element | None"], ...]
"""What :meth:`NodeCore.hear` outputs for one entry: per element, its key, encoding, latching
and ROS 2 type."""
log = logging.getLogger("zab.core")

PEER_STATUS_S = 1.0  # least time between two ``peers/<peer>`` status puts of one peer
ACK_REPEATS = 3  # frames that carry an acknowledgement after it changed (acks can be lost)
STATE_VERSION = 1
EPOCHS = 256  # stream epochs, EPOCH_BITS wide


@direct_init
@dataclass(frozen=True)
class Publish:
    """Put ``value`` on the application key ``key`` (bridged; latched keys answer queries)."""

    key: str
    value: Any
    encoding: str
    latched: bool = False
    ros2: Ros2Element | None = None  # publish as this ROS 2 topic (CDR, rmw_zenoh attachment)


@direct_init
@dataclass(frozen=True)
class Status:
    """Publish ``payload`` (msgpack) on ``@zab/<mission>/<node>/<topic>``."""

    topic: str
    payload: dict[str, Any]


Output = Publish | Status | Event


@direct_init
@dataclass(frozen=True)
class OutFrame:
    """A frame ready for the modem: bytes, unicast address (None = broadcast), ack request,
    the modem-clock start it was built for, and what it carries."""

    data: bytes
    dest: int | None
    ack: bool | None
    at: float
    plan: FramePlan
    built: float
    streams: tuple[tuple[ReliableSender | TransferSender, Any], ...] = ()
    acks: tuple[tuple[str, int], ...] = ()
    extras: tuple[Extra, ...] = ()


@direct_init
@dataclass(frozen=True)
class SendFrame:
    """What to do at an open opportunity: send ``frame`` (to ``frame.dest``, asking the modem
    for its acknowledgement when ``frame.ack``); ``ranged``: its acknowledgement also measures
    a range to ``frame.dest`` (``ranging.ping`` on a modem that ranges that way)."""

    frame: OutFrame
    ranged: bool = False


@dataclass(frozen=True)
class Ping:
    """What to do at an open opportunity: ask the modem for a two-way range to ``peer``."""

    peer: int


Action = SendFrame | Ping


@dataclass
class NodeStats:
    """Counters of one node, published on ``@zab/<mission>/<node>/stats``."""

    frames_sent: int = 0
    frames_received: int = 0
    frames_dropped: Counter[str] = field(default_factory=Counter)
    payloads_dropped: Counter[str] = field(default_factory=Counter)
    values_published: int = 0
    send_errors: int = 0
    left_out: int = 0
    sent_per_channel: Counter[str] = field(default_factory=Counter)
    received_per_channel: Counter[str] = field(default_factory=Counter)


class NodeCore:
    """Store, frame building, frame decoding, link health and ranging of one node."""

    def __init__(self, loaded: LoadedMission, node: str,
                 auth: Authenticator | None = None, rng: random.Random | None = None,
                 state: Mapping[str, Any] | None = None, key: bytes | None = None,
                 seed: int | None = None) -> None:
        """``rng`` draws this run's epoch when there is no ``state`` (a fresh one per run by
        default; seeded for a reproducible simulation); ``state``: what :meth:`state` returned
        in the previous run, to resume from; ``key``: the frame key of an authenticated
        mission (the core reads no file and no environment: its runtime loads the key);
        ``seed``: the MAC's random draws (random access backoffs)."""
        mission = loaded.mission
        if node not in mission.nodes:
            raise ValueError(f"node {node!r} is not in mission {mission.mission!r}")
        self.mission = mission
        self.table = loaded.table
        self.node = node
        rng = rng or random.Random()
        self._outputs: list[Output] = []
        state = self._usable(state)
        wire_auth = mission.wire.auth
        if wire_auth is not None and auth is None:
            if key is None:
                raise MissionError(f"{node}: wire.auth is on: give the frame key "
                                   "(the runtime loads it, see bridge.mission.keys)")
            auth = Authenticator(key, self.table.fingerprint, mission.address_of(node),
                                 wire_auth.tag_bytes, state.get("auth"))
        self.auth = auth
        self.epoch: int = state.get("epoch", rng.randrange(EPOCHS))
        self.peer_epochs: dict[str, int] = dict(state.get("peer_epochs", {}))
        self._dirty = True  # a new run's epoch must be saved before its first frame
        self.saving = Saving()  # whether the runtime can save it (bridge.core.saving)
        self.codec = frame_codec_for(self.table, auth)
        self.frame_bytes = mission.node_modem(node).frame_bytes
        self.address = mission.address_of(node)
        self.store = OutboundStore.for_node(self.table.channels, node)
        self.drops = DropLedger(node)  # payloads dropped: counted, told at a bounded rate
        self.stats = NodeStats(payloads_dropped=self.drops.by_key)
        self.thresholds = LinkThresholds.for_mission(mission)
        self.heartbeat_s = heartbeat_s(mission)
        self.schedule: Schedule = schedule_for(mission, node, seed=seed)
        self.modem_ranging: str | None = None  # how the modem ranges (set by the runtime)
        self.link_states: dict[str, LinkState] = {}
        self._link_watch = LinkWatch(self.thresholds, self.table.foreign_nodes(node))
        self.last_heard: dict[str, float] = {}
        self.received_at: dict[str, float] = {}
        self.last_tx: float | None = None
        self._started: float | None = None
        self.positioning = Positioning(mission, node) if needs_positioning(mission, node) \
            else None
        # output key -> anchor: live anchor positions this bridge decodes from frames itself
        self.anchor_keys = {key: anchor for anchor, key in mission.ranging.anchor_keys.items()
                             if self.positioning is not None
                             and anchor in self.positioning.anchors}
        self._ranged_last = False  # a range never takes two transmit opportunities in a row
        self.bindings: dict[str, list[tuple[ChannelCodec, int, ElementCodec]]] = {}
        self.families = Families(self.table, node)
        self.queries = Queries(mission, self.table, node) if self.table.queries else None
        self.surfacing = Surfacing(node, mission.surfacing.republish) \
            if mission.surfacing is not None else None
        self.interest = Interest(self.table.interest, mission.demand.refresh_s) \
            if self.table.interest is not None and mission.demand is not None else None
        for channel in self.table.channels:
            if channel.index in self.store.states and channel.family is None:
                for i, element in enumerate(channel.elements):
                    key = element.input_key(node)
                    self.bindings.setdefault(key, []).append((channel, i, element))
        self._ros2_inputs = {key: next((e.ros2 for _, _, e in found if e.ros2 is not None), None)
                             for key, found in self.bindings.items()}
        self._caps = {key: payload_cap(max(e.layout.bits for _, _, e in found))
                      for key, found in self.bindings.items()}
        self._cap = payload_cap(max((e.layout.bits for c in self.table.channels
                                     for e in c.elements), default=0))
        retry_s = default_retry_s(mission)
        self.senders: dict[int, ReliableSender | TransferSender] = {
            c.index: (TransferSender if c.fragmented else ReliableSender)(
                c, c.destinations(node), retry_s, rng.randrange(SEQ_MOD))
            for c in self.table.streams if c.index in self.store.states}
        self.receivers: dict[tuple[str, int], ReliableReceiver | TransferReceiver] = {}
        self._restore(state)
        self._acks: dict[tuple[str, int], None] = {}  # (sender, channel index) owed an ack now
        self._ack_repeats: dict[tuple[str, int], int] = {}  # and in this many more frames
        self._foreign: dict[str, int] = {}  # a peer's last fingerprint not ours
        self._peer_status: dict[str, float] = {}  # when each peer's status was last put
        self.mismatched: dict[str, str] = {}  # peers known to run another mission file
        self.lanes = lanes_for(self)  # input keys with a short way to their frame
        self.expressible = frozenset(  # channels whose lane's frame may go by express
            lane.state.channel.index for lane in self.lanes.values()
            if lane.frame is not None and len(lane.state.channel.elements) == 1)
        self._clearance: Clearance | None = None  # the last lane frame's (bridge.core.lanes)
        self._express_books_wait = False  # among the books: what a lane reads (the store, MAC)
        self._unsettled: list[Callable[[], None]] = []  # books hear() and sent() left, in order
        self._plain_rx = hears_plainly(self)
        self._hear_plans: dict[tuple[str, int], HearPlan] = {}  # (sender, entry's wire index)

    # -- state across restarts -----------------------------------------------------------------

    @property
    def needs_save(self) -> bool:
        """:meth:`state` changed in a way a restart must not lose: save it before carrying out
        the outputs or sending the frame just built."""
        return self._dirty or (self.auth is not None and self.auth.changed)

    def storage(self, error: str | None, now: float) -> None:
        """The runtime's saves of :meth:`state` fail (``error``: why) or work (None); while
        they fail, new reliable values are refused (:mod:`bridge.core.saving`)."""
        event = self.saving.changed(error, now)
        if event is not None:
            self._status("state", event.to_dict())
            self._event(event)

    def saved(self) -> None:
        """The runtime saved :meth:`state`."""
        self._dirty = False
        if self.auth is not None:
            self.auth.changed = False

    def state(self) -> dict[str, Any]:
        """Everything a restart must resume, as msgpack-able plain data."""
        return {
            "version": STATE_VERSION, "mission": self.mission.mission, "node": self.node,
            "fingerprint": self.table.fingerprint.hex(), "epoch": self.epoch,
            "peer_epochs": dict(self.peer_epochs),
            "senders": {s.channel.name: s.state() for s in self.senders.values()},
            "receivers": [[src, self.table.channels[index].name, r.state()]
                          for (src, index), r in self.receivers.items()],
            "auth": self.auth.state() if self.auth is not None else None,
        }

    def _usable(self, state: Mapping[str, Any] | None) -> Mapping[str, Any]:
        """``state`` if it is this node's under this mission file; else nothing (and every
        value it left unfinished reported failed)."""
        if not state:
            return {}
        same = (state.get("version") == STATE_VERSION and state.get("node") == self.node
                and state.get("fingerprint") == self.table.fingerprint.hex())
        if same:
            return state
        log.warning("%s: the saved state is from another mission file or version: starting "
                    "afresh (its unfinished values are reported failed)", self.node)
        for name, sender in (state.get("senders") or {}).items():
            items = [*sender.get("queue", ()), *sender.get("flight", ()),
                     *sender.get("items", ())]
            for item in items:
                for dst in item.get("waiting", item.get("dests", ())):
                    self._reports([Delivery(
                        0.0, name, item["id"], dst, "failed",
                        reason="restarted with another mission file",
                        attempts=item.get("attempts", 0), key=item.get("key"),
                        ref=item.get("ref"))])
        return {}

    def _restore(self, state: Mapping[str, Any]) -> None:
        by_name = {s.channel.name: s for s in self.senders.values()}
        for name, saved in (state.get("senders") or {}).items():
            if name in by_name:
                by_name[name].restore(saved)
        for src, name, saved in state.get("receivers") or ():
            channel = self.table.by_name(name)
            self.receivers[(src, channel.index)] = (
                TransferReceiver.from_state(channel, saved) if channel.fragmented
                else ReliableReceiver.from_state(saved))

    # -- outputs -------------------------------------------------------------------------------

    def take(self) -> list[Output]:
        """Everything produced since the last call, in order."""
        if self.queries is not None:
            self._outputs.extend(self.queries.take())
        out, self._outputs = self._outputs, []
        return out

    def _event(self, event: Event) -> None:
        self._outputs.append(event)

    def _status(self, topic: str, payload: dict[str, Any]) -> None:
        self._outputs.append(Status(topic, payload))

    # -- samples in ----------------------------------------------------------------------------

    def ingest(self, key: str, data: bytes, encoding: str, now: float,
               ref: str | None = None, sample_key: str | None = None) -> None:
        """A sample arrived on an input key: pack it for every channel that reads the key.

        ``ref`` (the publisher's correlation text) is echoed in delivery reports;
        ``sample_key`` is the sample's own key when ``key`` has wildcards (ROS 2 inputs)."""
        self.settle()
        if len(data) > (cap := self.payload_cap(key)):
            self.drop_payload(key, f"{len(data)} bytes, over this key's cap of {cap}", now,
                              "too_large")
            return
        bindings = self.bindings.get(key, ())
        ros2 = self._ros2_inputs.get(key)  # (ros2_input, per sample)
        try:
            value = (ros2.decode(data, sample_key or key) if ros2 is not None
                     else decode_payload(data, encoding))
        except DecodeError as exc:
            self.drop_payload(key, str(exc), now, "undecodable")
            return
        for channel, index, element in bindings:
            try:
                packed = element.layout.pack(value)
            except EncodeError as exc:
                self.drop_payload(key, f"channel {channel.name!r}: {exc}", now)
                continue
            sender = self.senders.get(channel.index)
            if sender is None:
                self.store.update(channel.index, index, packed, now)
            elif self.store.update_value(channel.index, index, packed, now):
                payload = self.store.states[channel.index].payload()
                refused = self.saving.refusal()
                self._reports(sender.offer(payload, now, key, ref) if refused is None
                              else sender.refuse(now, key, ref, refused))
                self._dirty = True
        if self.families.senders:
            for problem in self.families.ingest(key, value, now):
                self.drop_payload(key, problem, now)
        if self.surfacing is not None and self.surfacing.reachable:  # full fidelity over IP
            outs = [(d, element.output_key(self.node, d))
                    for channel, _, element in self.bindings.get(key, ()) if not channel.stream
                    for d in channel.destinations(self.node)]
            self._outputs.extend(self.surfacing.relays(
                key, outs + self.families.outputs_for(key), data, encoding))

    def ros2_input(self, key: str) -> Ros2Element | None:
        """The ROS 2 topic read on input ``key``, or None (asked per sample: looked up once)."""
        return self._ros2_inputs.get(key)

    def payload_cap(self, key: str) -> int:
        """The longest payload input ``key`` takes (:func:`~bridge.wire.payloads.payload_cap`
        of the bits its channels keep): a longer one is dropped before it is decoded."""
        return self._caps.get(key, self._cap)

    def drop_payload(self, key: str, reason: str, now: float, cause: str = "unfit") -> None:
        """Count a payload that cannot be used, by key and ``cause`` (logged and summarised at
        a bounded rate: :mod:`bridge.core.drops`)."""
        self.settle()
        summary = self.drops.drop(key, cause, reason, now)
        if summary is not None:
            self._event(summary)

    def numbers(self, key: str, data: bytes, encoding: str, names: tuple[str, ...],
                now: float) -> tuple[float, ...] | None:
        """The finite numbers ``names`` of a payload, or None (counted as a dropped payload)."""
        self.settle()
        try:
            if len(data) > self._cap:
                raise DecodeError(f"{len(data)} bytes, over the cap of {self._cap}")
            value = decode_payload(data, encoding)
            numbers = tuple(float(value[k]) for k in names)
            if not all(map(math.isfinite, numbers)):
                raise ValueError("not finite")
            return numbers
        except (DecodeError, TypeError, KeyError, ValueError) as exc:
            self.drop_payload(key, f"needs numbers {', '.join(names)}: {exc}", now)
            return None

    # -- frames out ----------------------------------------------------------------------------

    def next_due(self, now: float | None = None) -> float | None:
        """When something (data, an acknowledgement, a retransmission or a heartbeat) is next
        due; None while nothing is pending."""
        self.settle()
        if now is not None:
            self._begin(now)
        if self._acks or (self.auth is not None and self.auth.owed):
            return float("-inf")  # (a peer waits for an acknowledgement, or for its @mark)
        times = [self._store_next_due(now), self.next_heartbeat()]
        if self.families.senders:
            times.append(self.families.next_due(now, self.wants))
        if self.interest is not None:
            times.append(self.interest.next_due())
        if self.queries is not None:
            times.append(self.queries.next_due())
        if self.senders:
            times += [s.next_time() for s in self.senders.values()]
        if self.positioning is not None:
            times.append(self.positioning.next_ping())
        return min([t for t in times if t is not None], default=None)

    def _begin(self, now: float) -> None:
        """The node first plans at ``now``: its first heartbeat is due one period later."""
        if self._started is None:
            self._started = now

    def next_heartbeat(self) -> float | None:
        if self.heartbeat_s is None:
            return None
        since = self._started if self.last_tx is None else self.last_tx
        return float("-inf") if since is None else since + self.heartbeat_s

    def heartbeat_due(self, now: float) -> bool:
        beat = self.next_heartbeat()
        return beat is not None and beat <= now + 1e-9

    # -- the MAC: when to wake, what to do --------------------------------------------------

    def wake_at(self, now: float) -> float | None:
        """When this node's MAC next has an opportunity for what is due (None: nothing is,
        wait for data or a frame); the runtime sleeps until then and calls :meth:`act`."""
        opp = self.schedule.next_opportunity(now, self.next_due(now))
        return None if opp is None else opp.start

    def act(self, now: float, at: float) -> Action | None:
        """What to do now, if an opportunity is open: a frame built to start at modem time
        ``at``, or a ping (``ranging.ping`` with a modem that pings); None: nothing (the
        opportunity, if any, is given up). Report how it went with :meth:`done`."""
        self.settle()
        return self._act(now, at, None)

    def _act(self, now: float, at: float, lone: Lane | None) -> Action | None:
        """:meth:`act`; ``lone``: the lane of the one channel due (:meth:`ingest_and_act`)."""
        opp = self.schedule.next_opportunity(now, self.next_due(now))
        if opp is None or opp.start > now + 1e-9:
            return None
        peer = self.range_due(now) if self.modem_ranging and opp.poll is None else None
        if peer is not None and self.modem_ranging == "ping":
            return Ping(peer)
        if lone is not None and peer is None:
            out: OutFrame | None = self._lone_frame(lone, now, at)
        else:
            always = opp.must_send or self.heartbeat_due(now) or peer is not None
            out = self.build_frame(now, at, always=always)
        if out is None:
            self.schedule.on_skipped(now)
            return None
        if opp.poll is not None:  # the poll rides on the frame's destination address
            out = replace(out, dest=self.mission.address_of(opp.poll))
        if peer is not None:  # the modem measures the range when the peer acknowledges
            out = replace(out, dest=peer, ack=True)
        return SendFrame(out, ranged=peer is not None)

    def ingest_and_act(self, key: str, data: bytes, encoding: str, now: float, at: float,
                       ref: str | None = None, sample_key: str | None = None) -> Action | None:
        """:meth:`ingest`, then :meth:`act`: the same outcome, in fewer steps when the key has
        a lane and its channel is the one thing due (:mod:`bridge.core.lanes`). A lane's frame
        leaves the books :meth:`hear` and :meth:`sent` left waiting: a plain node's books
        touch nothing it reads, and it outputs nothing of its own on the way. An express's
        books hold the store and the MAC: those are kept first."""
        lane = self.lanes.get(key)
        if lane is not None and not (self._acks or self._ack_repeats):
            if self._express_books_wait:
                self.settle()
            try:
                packed = lane.element.layout.pack(decode_payload(data, encoding))
            except (DecodeError, EncodeError):
                pass  # ingest counts it
            else:
                state = lane.state
                self.store.update(state.channel.index, lane.index, packed, now)
                if self.store.lone_due(now) is not state:
                    return self.act(now, at)
                if not self.schedule.open_now(now):  # (False: closed; None: ask it)
                    self.settle()
                    return self._act(now, at, lane)
                self._begin(now)  # (as next_due would)
                return SendFrame(self._lone_frame(lane, now, at))
        self.ingest(key, data, encoding, now, ref, sample_key)
        return self.act(now, at)

    def _lone_frame(self, lane: Lane, now: float, at: float) -> OutFrame:
        """:meth:`build_frame`'s frame when ``lane``'s channel alone is due (and the node is
        plain: nothing else could go in it)."""
        state = lane.state
        data = self.codec.encode([(state.channel, state.payload())], (), self.epoch) \
            if lane.frame is None else lane.frame(state.payload())
        return self._lane_frame(lane, data, now, at)

    def _lane_frame(self, lane: Lane, data: bytes, now: float, at: float) -> OutFrame:
        """The frame ``data`` of ``lane``'s channel alone, built at ``now`` for modem time
        ``at``."""
        return OutFrame(data, lane.dest, lane.ack, at, FramePlan((lane.state,), ()), now)

    def done(self, action: Action, start: float, end: float, *,
             confirmed: bool | None = None, error: str | None = None) -> None:
        """``action`` was carried out from ``start`` to ``end`` (runtime clock); ``error``:
        it failed (a frame's data stays due); ``confirmed``: the modem's acknowledgement."""
        self.settle()
        peer = action.peer if isinstance(action, Ping) else (
            action.frame.dest if action.ranged else None)
        if peer is not None:
            self.range_asked(peer, start, error)
        if isinstance(action, SendFrame):
            if error is None:
                self.frame_sent(action.frame, start, confirmed)
            else:
                self.frame_failed(action.frame, error, start)
        if error is None:
            self.schedule.on_sent(start, end)
        else:
            self.schedule.on_skipped(start)

    def sent(self, action: SendFrame, start: float, end: float) -> bool:
        """:meth:`done` for a frame the modem took, keeping the books of a plain node's frame
        of latest values alone (its counters and :class:`FrameSent`, as a lane sends) for
        :meth:`settle`: what decides the next frame (the store, the MAC, the last send) is
        done at once. Returns whether books wait."""
        out = action.frame
        if not self.lanes or action.ranged or out.streams or out.acks or out.extras:
            self.done(action, start, end)
            return False
        self._recorded(out, start, end)
        self._unsettled.append(partial(self._count_sent, out, start))
        self._clearance = clearance_after(self, out.plan.chosen, out.built, start)
        return True

    def express(self, key: str, data: bytes, encoding: str, now: float
                ) -> tuple[Lane, int, bytes] | None:
        """:meth:`ingest_and_act` for a sample on ``key`` at ``now`` that the last lane frame's
        clearance admits (:mod:`bridge.core.lanes`): its lane, packed value and frame, worked out
        without reading or changing anything else. Report with :meth:`expressed` or
        :meth:`unexpressed`. None: take :meth:`ingest_and_act`."""
        clearance, lane = self._clearance, self.lanes.get(key)
        if clearance is None or lane is None or self._acks or self._ack_repeats or self._dirty \
                or not clearance.admits(lane.state, now, self.store.changes):
            return None
        try:
            packed = lane.element.layout.pack(decode_payload(data, encoding))
        except (DecodeError, EncodeError):
            return None  # ingest_and_act counts it
        assert lane.frame is not None  # (a clearance's channel is expressible)
        return lane, packed, lane.frame(packed)

    def expressed(self, lane: Lane, packed: int, data: bytes, now: float, end: float,
                  at: float) -> None:
        """The express frame ``data`` of ``packed`` left at ``now`` (runtime clock; modem time
        ``at``), the modem done at ``end``: the clearance moves on; the store, the MAC, the last
        send and the counters are kept with the books."""
        assert self._clearance is not None
        self._clearance.moved_on(now)
        self._unsettled.append(partial(self._express_books, lane, packed, data, now, end, at))
        self._express_books_wait = True

    def unexpressed(self, lane: Lane, packed: int, data: bytes, now: float, at: float
                    ) -> SendFrame:
        """The express frame did not leave (the modem refused it): the value is taken as
        :meth:`ingest_and_act` takes it, and the lane's action returned, for :meth:`done` to
        report how it failed (the value stays due)."""
        self.settle()
        self._take_value(lane, packed, now)
        return SendFrame(self._lane_frame(lane, data, now, at))

    def _express_books(self, lane: Lane, packed: int, data: bytes, now: float, end: float,
                       at: float) -> None:
        """What :meth:`expressed` left: as :meth:`ingest_and_act` and :meth:`sent` keep it."""
        clearance = self._clearance
        current = clearance is not None and clearance.stamp == self.store.changes
        self._take_value(lane, packed, now)
        out = self._lane_frame(lane, data, now, at)
        self._recorded(out, now, end)
        self._count_sent(out, now)
        if current:  # (nothing else changed the store meanwhile: the clearance still holds)
            clearance.stamp = self.store.changes

    def _take_value(self, lane: Lane, packed: int, now: float) -> None:
        """``packed`` stored on ``lane``, as :meth:`ingest_and_act` stores it for its frame."""
        self.store.update(lane.state.channel.index, lane.index, packed, now)
        self._begin(now)  # (as next_due would)

    def _recorded(self, out: OutFrame, start: float, end: float) -> None:
        """What decides the next frame, after a lane's frame ``out`` (the modem busy from
        ``start`` to ``end``): the store, the last send and the MAC."""
        self.store.mark_sent(out.plan.chosen, out.built)
        self.last_tx = out.built
        self.schedule.on_sent(start, end)

    def build_frame(self, now: float, at: float, *, always: bool = False) -> OutFrame | None:
        """A frame of what is due at ``now``, to start at modem time ``at``; None when there is
        nothing to send and ``always`` is false. Pair with :meth:`frame_sent` or
        :meth:`frame_failed`."""
        self.settle()
        codec = self.codec
        budget = codec.body_capacity_bits(self.frame_bytes) - codec.count_bits
        room = (1 << codec.count_bits) - 1
        items: list[tuple[ChannelCodec | AckCodec, int]] = []
        targets: set[str] = set()
        acks: list[tuple[str, int]] = []
        if self._acks or self._ack_repeats:  # acknowledgements first: they unblock the peer
            ack_codec = self.table.ack
            assert ack_codec is not None
            cost = codec.channel_cost_bits(ack_codec)
            for src, index in {**self._acks, **dict.fromkeys(self._ack_repeats)}:
                if cost > budget or len(items) >= room:
                    break
                items.append((ack_codec, self._ack_bits(src, index)))
                budget -= cost
                acks.append((src, index))
                targets.add(src)
        picked, left = fill(codec, self._candidates(now), budget, room - len(items))
        chosen: list[ChannelState] = []
        streams: list[tuple[ReliableSender | TransferSender, Any]] = []
        extras: list[Extra] = []
        asks_ack = False  # a channel in the frame asks for the modem's acknowledgement
        node = self.node
        for candidate in picked:
            what, channel = candidate.what, candidate.channel
            if isinstance(what, ChannelState):
                chosen.append(what)
                items.append((channel, what.payload()))
            elif isinstance(what, Extra):
                extras.append(what)
                items.append((what.channel, what.bits))
                continue
            else:
                sender, item = what
                streams.append((sender, item))
                items.append((channel, sender.entry(item)))
            targets.update(channel.destinations(node))
            asks_ack = asks_ack or channel.ack
        left_out = tuple(c.what for c in left if isinstance(c.what, ChannelState))
        self.stats.left_out += len(left_out)
        if not items and not always:
            return None
        delays = self.positioning.on_transmit(at) if self.positioning and self.table.dlbl \
            else ()
        data = codec.encode(items, delays, self.epoch)
        dest, ack = self.addressing(targets, asks_ack)
        return OutFrame(data, dest, ack, at, FramePlan(tuple(chosen), left_out), now,
                        tuple(streams), tuple(acks), tuple(extras))

    def addressing(self, targets: Collection[str],
                   asks_ack: bool) -> tuple[int | None, bool | None]:
        """Where a frame for ``targets`` goes: the unicast address when they are one node
        (else None, broadcast), and the modem's acknowledgement, asked only of a unicast."""
        dest = self.mission.address_of(next(iter(targets))) if len(targets) == 1 else None
        return dest, (True if dest is not None and asks_ack else None)

    def _store_next_due(self, now: float | None) -> float | None:
        """When a latest-value channel somebody wants becomes due."""
        if self.interest is None and self.surfacing is None:
            return self.store.next_due(now)
        times = [t for s in self.store.states.values()
                 if self.wants(s.channel) and (t := s.ready_at(now)) is not None]
        return min(times, default=None)

    def _candidates(self, now: float) -> list[Candidate]:
        """Everything that could go in a frame sent at ``now``."""
        due = self.store.due(now)
        if self.interest is not None or self.surfacing is not None:
            due = [s for s in due if self.wants(s.channel)]
        out = [Candidate(s.channel, s.last_sent, s) for s in due]
        if self.interest is not None and (want := self.interest.candidate(now)) is not None:
            out.append(want)
        if self.queries is not None:
            out += self.queries.candidates(now)
        for sender in self.senders.values():
            out += [Candidate(sender.channel, getattr(item, "last_sent", None), (sender, item), n)
                    for n, item in enumerate(sender.due(now))]
        if self.families.senders:
            out += self.families.candidates(now, self.wants)
        if self.auth is not None and self.auth.owed:
            out += self._marks()
        return out

    def _marks(self) -> list[Candidate]:
        """The ``@mark`` entries owed to senders whose frames were refused as replayed
        (:mod:`bridge.wire.marks`)."""
        codec, auth = self.table.marks, self.auth
        assert codec is not None and auth is not None
        out = []
        for address, mark in auth.hints():
            peer = self.mission.name_of(address)
            if peer is not None:
                out.append(Candidate(codec, None, Extra(  # type: ignore[arg-type]
                    codec, codec.pack(self.table.nodes.index(peer), mark),
                    lambda _built, a=address: auth.hinted(a))))
        return out

    def wants(self, channel: ChannelCodec) -> bool:
        """Whether some destination reached acoustically wants ``channel`` now (always,
        without demand or surfacing)."""
        if (self.interest is None and self.surfacing is None) or channel.stream:
            return True
        destinations = channel.destinations(self.node)
        if self.surfacing is not None:
            destinations = self.surfacing.acoustic(destinations)
        return bool(destinations) and (self.interest is None
                                       or self.interest.wants(channel, destinations))

    def ip_reachable(self, peer: str, up: bool, now: float) -> None:
        """The peer's bridge became reachable over IP (``up``) or stopped being so."""
        self.settle()
        if self.surfacing is not None and self.surfacing.changed(peer, up, now):
            event = Surfaced(now, peer, up)
            self._status(f"surfaced/{peer}", event.to_dict())
            self._event(event)

    def _ack_bits(self, src: str, index: int) -> int:
        ack_codec = self.table.ack
        assert ack_codec is not None
        receiver = self.receivers[(src, index)]
        stream = next(i for i, c in enumerate(self.table.streams) if c.index == index)
        if isinstance(receiver, TransferReceiver):
            tid, base, bitmap = receiver.ack()
        else:
            (base, bitmap), tid = receiver.ack(), 0
        return ack_codec.pack(self.table.nodes.index(src), stream, self.peer_epochs.get(src, 0),
                              tid, base, bitmap)

    def frame_sent(self, out: OutFrame, now: float, confirmed: bool | None = None) -> None:
        """The modem accepted ``out``; ``confirmed``: its own acknowledgement said the frame
        reached ``out.dest`` (reliable entries in it are then not re-sent, only awaited)."""
        self.settle()
        self.store.mark_sent(out.plan.chosen, out.built)
        by_sender: dict[int, tuple[ReliableSender | TransferSender, list[Any]]] = {}
        for sender, item in out.streams:
            by_sender.setdefault(id(sender), (sender, []))[1].append(item)
        dest = self.mission.name_of(out.dest) if out.dest is not None else None
        for sender, group in by_sender.values():
            self._reports(sender.sent(group, out.built))  # type: ignore[arg-type]
            if confirmed and dest is not None:
                sender.confirmed(group, dest)  # type: ignore[arg-type]
        for key in out.acks:
            self._acks.pop(key, None)
            left = self._ack_repeats.get(key, 0) - 1
            if left > 0:
                self._ack_repeats[key] = left
            else:
                self._ack_repeats.pop(key, None)
        if out.streams:
            self._dirty = True
        for extra in out.extras:
            extra.on_sent(out.built)
        self.last_tx = out.built
        self._count_sent(out, now)

    def _count_sent(self, out: OutFrame, now: float) -> None:
        """A frame sent: its counters and its event."""
        self.stats.frames_sent += 1
        names = [s.channel.name for s in out.plan.chosen]
        if out.streams:
            names += [s.channel.name for s, _ in out.streams]
        for name in names:
            self.stats.sent_per_channel[name] += 1
        dest = self.mission.name_of(out.dest) if out.dest is not None else None
        self._event(FrameSent(now, len(out.data), names, dest, out.data))

    def frame_failed(self, out: OutFrame, error: str, now: float) -> None:
        """The modem refused ``out``: its data stays due."""
        self.settle()
        if self.positioning is not None:
            self.positioning.forget_transmit(out.at)
        self.stats.send_errors += 1
        self._event(SendFailed(now, error))

    # -- frames in -----------------------------------------------------------------------------

    def receive(self, rx: Reception, now: float, modem_now: float | None = None) -> None:
        """Decode one received frame and publish what it carries for this node.

        ``modem_now`` is the modem clock at the call (DLBL times are in the modem's clock).
        """
        self.settle()
        src = self._source(rx, now)
        if src is None:
            return
        frame = self._decode(rx, src, now)
        if frame is not None:
            self._accept(rx, src, frame, now, modem_now)

    def hear(self, rx: Reception, now: float, modem_now: float | None = None
             ) -> list[tuple[HearPlan, list[dict]]] | None:
        """:meth:`receive`, keeping the books of a plain frame for :meth:`settle`.

        A *plain* frame (from a peer whose link is up, in its known epoch, holding only
        latest-value channels, to a node whose MAC ignores what it hears and that has no
        queries, surfacing or anchors to decode) has its values returned, for the caller to
        publish at once (the :class:`Publish` outputs :meth:`receive` would give, as a plan and
        the element values per entry: see :func:`publications`); counters, link and MAC
        records, ranging, status and its :class:`FrameReceived` wait for :meth:`settle`, which
        every other method runs first. Any other frame takes :meth:`receive`'s way whole
        (None: see :meth:`take`)."""
        src = self.mission.name_of(rx.src)
        if not self._plain_rx or src is None or self.link_states.get(src) is not LinkState.UP \
                or (self.auth is not None and self.codec.sender_fingerprint(rx.data) not in (
                    None, self.codec.fingerprint16)):
            self.receive(rx, now, modem_now)
            return None
        try:
            frame = self.codec.decode(rx.data, rx.src)
        except FrameError as exc:
            if self.auth is None:  # (decoding is pure: receive decodes it again, says why)
                self.receive(rx, now, modem_now)
            else:  # (its fingerprint is ours, and its replay window moved: no second look)
                self._refused(rx, src, exc, now)
            return None
        delivered = self._plain_entries(src, frame)
        if delivered is None:
            self.settle()
            self._accept(rx, src, frame, now, modem_now)
            return None
        if self.auth is not None:
            self._dirty = True  # the replay window moved: saved before anything is published
        values: dict[str, list[dict]] = {}
        published = []
        for plan, entry in delivered:
            if plan:
                values[entry.channel.name] = elements = entry.values
                published.append((plan, elements))
                self.stats.values_published += len(plan)
        self._unsettled.append(partial(self._heard_books, rx, src, frame.delays, now, modem_now,
                                       values))
        return published

    def _plain_entries(self, src: str, frame: DecodedFrame) -> list[tuple[HearPlan, Entry]] | None:
        """Each entry of ``frame`` with what :meth:`hear` outputs for it; None if the frame is
        not plain."""
        if frame.epoch is not None and self.peer_epochs.get(src) != frame.epoch:
            return None
        plans = self._hear_plans
        delivered = []
        for entry in frame.entries:
            key = (src, entry.channel.index)  # (a channel's own hash would look at every field)
            plan = plans.get(key)
            if plan is None:
                plan = self._hear_plan(src, entry.channel)
                if plan is None:
                    return None
                plans[key] = plan
            delivered.append((plan, entry))
        return delivered

    def _hear_plan(self, src: str, channel: Any) -> HearPlan | None:
        """What :meth:`hear` outputs for an entry of ``channel`` from ``src``: each element's
        key, encoding, latching and ROS 2 type (none if it is not for this node); None if the
        entry is not a latest-value channel ``src`` sends."""
        if channel.__class__ is not ChannelCodec or channel.stream or channel.family is not None \
                or src not in channel.senders:
            return None
        if not channel.reaches(src, self.node):
            return ()
        return tuple((e.output_key(src, self.node), e.encoding, channel.latching, e.ros2)
                     for e in channel.elements)

    def settle(self) -> bool:
        """Keep the books :meth:`hear` and :meth:`sent` left, in order (every other method
        runs this first, so none sees them missing); whether there were any."""
        if not self._unsettled:
            return False
        books, self._unsettled = self._unsettled, []
        self._express_books_wait = False
        for keep in books:
            keep()
        return True

    def _heard_books(self, rx: Reception, src: str, delays: tuple[int | None, ...], now: float,
                     modem_now: float | None, values: dict[str, list[dict]]) -> None:
        """What :meth:`hear` left of a plain frame's reception."""
        self._heard_from(rx, src, now)
        for name in values:
            self.stats.received_per_channel[name] += 1
            self.received_at[name] = now
        self._heard_tail(rx, src, delays, now, modem_now, {}, values, {})

    def _source(self, rx: Reception, now: float) -> str | None:
        """The sender of ``rx`` if it is a peer under this mission file; else the frame is
        counted dropped (or foreign) and None."""
        src = self.mission.name_of(rx.src)
        sender_print = self.codec.sender_fingerprint(rx.data)
        if sender_print is not None and sender_print != self.codec.fingerprint16 \
                and src != self.node:
            self._foreign_frame(src or f"address {rx.src}", sender_print, rx, now)
            return None
        if src is None or src == self.node:
            self.stats.frames_dropped["unknown_source"] += 1
            self._event(FrameDropped(now, src, "unknown_source", data=rx.data))
            return None
        return src

    def _decode(self, rx: Reception, src: str, now: float) -> DecodedFrame | None:
        """The frame ``rx`` carries, or None (counted dropped, books kept first)."""
        try:
            return self.codec.decode(rx.data, rx.src)
        except FrameError as exc:
            self._refused(rx, src, exc, now)
            return None

    def _refused(self, rx: Reception, src: str, error: FrameError, now: float) -> None:
        """``rx`` from ``src`` did not decode: counted dropped (books kept first)."""
        self.settle()
        self.stats.frames_dropped[error.reason] += 1
        self._event(FrameDropped(now, src, error.reason, str(error), rx.data))

    def _heard_from(self, rx: Reception, src: str, now: float) -> None:
        """A valid frame from ``src``: counters, the MAC and the link record it."""
        self.stats.frames_received += 1
        self.schedule.on_heard(src, rx.dest == self.address, now)
        self._foreign.pop(src, None)
        if self.mismatched:
            self._matched(src, now)
        self.last_heard[src] = now
        self._link_watch.heard(src, now)

    def _accept(self, rx: Reception, src: str, frame: DecodedFrame, now: float,
                modem_now: float | None) -> None:
        """The rest of :meth:`receive`, for a frame that decoded."""
        self._heard_from(rx, src, now)
        if self.auth is not None:
            self._dirty = True  # the replay window moved: saved before anything is published
        if frame.epoch is not None and self.peer_epochs.get(src) != frame.epoch:
            self._peer_epoch(src, frame.epoch, now)  # (new to us, or changed)
        if self.link_states.get(src) is not LinkState.UP:
            self.update_links(now)
        values: dict[str, list[dict]] = {}
        anchors: dict[str, tuple[float, float, float]] = {}  # live anchor positions it carried
        members: dict[str, dict[str, list[dict]]] = {}  # key families: per member
        for entry in frame.entries:
            channel = entry.channel
            if channel.__class__ is not ChannelCodec:  # an acknowledgement or a system entry
                if isinstance(channel, AckCodec):
                    self._on_ack(src, entry.header, now)
                    continue
                if self._on_system(src, entry, now):
                    continue
            if src not in channel.senders:
                self.stats.frames_dropped["unexpected_sender"] += 1
                continue
            if not channel.reaches(src, self.node):
                continue  # overheard: addressed to others
            if self.surfacing is not None and src in self.surfacing.reachable \
                    and not channel.stream:
                self.surfacing.duplicates += 1  # it reaches us over IP at full fidelity
                continue
            if channel.fragmented:
                delivered = self._on_fragment(src, channel, entry.header, entry.chunk, now)
            elif channel.reliable:
                receiver = self._receiver(src, channel)
                assert isinstance(receiver, ReliableReceiver)
                delivered = receiver.on_entry(*entry.header, entry.values)
                self._owe_ack(src, channel.index)
            else:
                delivered = [entry.values]
            member = "*"
            if channel.family is not None:
                name = self.families.member_name(src, channel, entry.header[0])
                if name is None:  # a learned member whose @key entry has not arrived yet
                    self.stats.frames_dropped["unknown_member"] += 1
                    continue
                member = name
            cname, family, latching = channel.name, channel.family, channel.latching
            for elements in delivered:
                values[cname] = elements
                if family is not None:
                    members.setdefault(cname, {})[member] = elements
                self.stats.received_per_channel[cname] += 1
                self.received_at[cname] = now
                for element, value in zip(channel.elements, elements, strict=True):
                    key = element.output_key(src, self.node, member)
                    if family is not None:
                        self.families.arrived(key, now)
                    if latching and self.queries is not None:
                        self.queries.remember(key, value, element.encoding, now)
                    if key in self.anchor_keys:
                        self._anchor_value(self.anchor_keys[key], value, anchors, now)
                    self._publish(key, value, element.encoding, latching, element.ros2)
        self._heard_tail(rx, src, frame.delays, now, modem_now, anchors, values, members)

    def _heard_tail(self, rx: Reception, src: str, delays: tuple[int | None, ...], now: float,
                    modem_now: float | None, anchors: dict[str, tuple[float, float, float]],
                    values: dict[str, list[dict]],
                    members: dict[str, dict[str, list[dict]]]) -> None:
        """After a frame's values: its ranges, its peer's status and its event."""
        if self.positioning is not None and self.table.dlbl:
            t_start = float(rx.meta.get("start", rx.time))
            self._ranging(src, t_start, delays, modem_now if modem_now is not None else now,
                          now, anchors)
        elif anchors and self.positioning is not None:  # (only its anchors: anchor_keys)
            for anchor, position in anchors.items():
                self.positioning.set_anchor(anchor, position, now)
        meta = plain(rx.meta)
        if now - self._peer_status.get(src, -math.inf) >= PEER_STATUS_S:  # not every frame
            self._peer_status[src] = now
            self._status(f"peers/{src}", {"last_heard": now, "meta": dict(meta)})
        self._event(FrameReceived(now, src, len(rx.data), list(values), rx.data, meta,
                                  values, members or None))

    def _receiver(self, src: str, channel: ChannelCodec) -> ReliableReceiver | TransferReceiver:
        key = (src, channel.index)
        receiver = self.receivers.get(key)
        if receiver is None:
            receiver = self.receivers[key] = (TransferReceiver(channel) if channel.fragmented
                                              else ReliableReceiver())
        return receiver

    def _on_fragment(self, src: str, channel: ChannelCodec, header: tuple[int, ...],
                     chunk: bytes, now: float) -> list[list[dict]]:
        receiver = self._receiver(src, channel)
        assert isinstance(receiver, TransferReceiver)
        tid, index, count = header
        data = receiver.on_fragment(tid, index, count, chunk)
        self._owe_ack(src, channel.index)
        self._status(f"transfer/{channel.name}", {**receiver.progress(), "peer": src,
                                                  "time": now})
        if data is None:
            return []
        try:
            return [channel.unpack(from_bytes(channel, data))]
        except DecodeError as exc:
            self.stats.frames_dropped["malformed"] += 1
            self._event(FrameDropped(now, src, "malformed",
                                     f"transfer on {channel.name!r}: {exc}"))
            return []

    def _on_system(self, src: str, entry: Entry, now: float) -> bool:
        """An ``@key``, ``@want`` or query entry from ``src``; False for anything else."""
        channel = entry.channel
        if isinstance(channel, NameCodec):
            self.families.on_name(src, entry.header)
        elif isinstance(channel, InterestCodec):
            if self.interest is not None:
                self.interest.on_heard(src, entry.header, now)
        elif isinstance(channel, QueryCodec):
            if self.queries is not None:
                handle = self.queries.on_reply if channel.reply else self.queries.on_request
                handle(src, channel, entry.header, entry.values, now)
        elif isinstance(channel, MarkCodec):
            peer, mark = entry.header
            if self.table.nodes[peer] == self.node and self.auth is not None \
                    and self.auth.resume_past(mark):
                log.info("%s: %s refused its frames as replayed: its counter resumes past %d",
                         self.node, src, mark)
        else:
            return False
        return True
    def _owe_ack(self, src: str, index: int) -> None:
        self._acks[(src, index)] = None
        self._ack_repeats[(src, index)] = ACK_REPEATS
        self._dirty = True

    def _peer_epoch(self, src: str, epoch: int, now: float) -> None:
        """``src``'s frames carry ``epoch``: when it changed, ``src`` started without its saved
        state: open fresh windows for it and send it again everything outstanding."""
        known = self.peer_epochs.get(src)
        if known == epoch:
            return
        self.peer_epochs[src] = epoch
        self._dirty = True
        if known is None:
            return
        for key in [k for k in self.receivers if k[0] == src]:
            del self.receivers[key]
            self._acks.pop(key, None)
            self._ack_repeats.pop(key, None)
        for sender in self.senders.values():
            if src in sender.dests:
                sender.resync(src)
        log.info("%s: %s started afresh (epoch %d -> %d): streams resynchronised",
                 self.node, src, known, epoch)
        self._event(PeerRestarted(now, src, epoch, known))

    def _foreign_frame(self, src: str, fingerprint: int, rx: Reception, now: float) -> None:
        """A frame whose check gives another fingerprint: corrupt, or sent with another
        mission file — the same fingerprint twice in a row from one sender says which; in an
        authenticated mission, only a tag a key holder made under that fingerprint does."""
        if self.auth is not None:
            mismatch = self.codec.vouch(rx.data, rx.src, fingerprint) is not None
        else:
            mismatch = self._foreign.get(src) == fingerprint
            self._foreign[src] = fingerprint
        reason = "mission_mismatch" if mismatch else "check"
        self.stats.frames_dropped[reason] += 1
        self._event(FrameDropped(now, src, reason,
                                 f"check failed (fingerprint {fingerprint:04x})", rx.data))
        text = f"{fingerprint:04x}"
        if mismatch and self.mismatched.get(src) != text:
            self.mismatched[src] = text
            ours = f"{self.codec.fingerprint16:04x}"
            log.warning("%s: peer %s runs a different mission file (fingerprint %s, ours %s): "
                        "its frames are dropped", self.node, src, text, ours)
            event = MissionMismatch(now, src, text, ours)
            self._status(f"mismatch/{src}", event.to_dict())
            self._event(event)

    def _matched(self, src: str, now: float) -> None:
        """A frame of this mission file from ``src``: it no longer runs another one."""
        if self.mismatched.pop(src, None) is not None:
            log.warning("%s: peer %s runs this mission file again", self.node, src)
            self._status(f"mismatch/{src}", {"time": now, "peer": src, "fingerprint": None,
                                             "ours": f"{self.codec.fingerprint16:04x}"})

    def _on_ack(self, src: str, header: tuple[int, ...], now: float) -> None:
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
            self._reports(sender.on_ack(src, tid, base, bitmap, now))
            progress = sender.progress()
            if progress is not None:
                self._status(f"transfer/{channel.name}", {**progress, "time": now})
        else:
            self._reports(sender.on_ack(src, base, bitmap, now))

    def _reports(self, reports: list[Delivery]) -> None:
        if reports:
            self._dirty = True
        for report in reports:
            self._status(f"delivery/{report.channel}", report.to_dict())
            self._event(report)

    def _publish(self, key: str, value: Any, encoding: str, latched: bool,
                 ros2: Ros2Element | None = None) -> None:
        self._outputs.append(Publish(key, value, encoding, latched, ros2))
        self.stats.values_published += 1

    def _ranging(self, src: str, t_rx_start: float, delays: tuple[int | None, ...],
                 modem_now: float, now: float,
                 anchors: dict[str, tuple[float, float, float]] | None = None) -> None:
        """Ranges (and a fix) from a frame's DLBL delays (``anchors``: the live anchor
        positions the same frame carried)."""
        assert self.positioning is not None
        self._positioned(self.positioning.on_receive(src, t_rx_start, delays, modem_now, now,
                                                     anchors), now)

    def _anchor_value(self, anchor: str, value: Any, anchors: dict[str, tuple[float, ...]],
                      now: float) -> None:
        """An anchor's live position (``ranging.anchor_keys``) decoded from a frame: kept for
        the frame's ranges (counted as a dropped payload if it has no finite x, y, depth)."""
        try:
            position = tuple(float(value[k]) for k in ("x", "y", "depth"))
            if not all(map(math.isfinite, position)):
                raise ValueError("not finite")
        except (TypeError, KeyError, ValueError) as exc:
            key = self.mission.ranging.anchor_keys[anchor]
            self.drop_payload(key, f"needs numbers x, y, depth: {exc}", now)
            return
        anchors[anchor] = position  # type: ignore[assignment]

    def modem_range(self, rng: ModemRange, now: float) -> None:
        """The modem measured a range itself (a ping, a propagation time): publish it like a
        DLBL range, and the fix attempted with it."""
        self.settle()
        peer = self.mission.name_of(rng.peer)
        if self.positioning is None or peer is None:
            return
        self._positioned(self.positioning.on_modem_range(peer, rng.travel_time_s, rng.method,
                                                         rng.time), now)

    def range_due(self, now: float) -> int | None:
        """The address this node should ask its modem to range to at this transmit opportunity
        (``ranging.ping``); never at two opportunities in a row, so frames still go out."""
        self.settle()
        if self.positioning is None or self._ranged_last:
            self._ranged_last = False
            return None
        peer = self.positioning.ping_due(now)
        return None if peer is None else self.mission.address_of(peer)

    def range_asked(self, dest: int, now: float, error: str | None = None) -> None:
        """A range to ``dest`` was asked of the modem; ``error`` says why it failed."""
        self.settle()
        peer = self.mission.name_of(dest)
        if self.positioning is None or peer is None:
            return
        self._ranged_last = True
        self.positioning.pinged(peer, now)
        if error is not None:
            self._event(RangeFailed(now, peer, error))

    def _positioned(self, update: Update, now: float) -> None:
        """Publish the ranges of ``update`` and its fix (or why there is none)."""
        assert self.positioning is not None
        for rng in update.ranges:
            event = Range(**{**self.positioning.range_payload(rng), "time": now})
            self._status(f"range/{rng.peer}", event.to_dict())
            self._event(event)
        found = update.estimate if update.estimate is not None else update.fix
        if found is not None:  # the tracker's estimate; a bare fix where there is no tracker
            position = Position(now, found)
            self._status("position", position.to_dict())
            self._event(position)

    # -- health --------------------------------------------------------------------------------

    def tick(self, now: float) -> None:
        """Periodic work: link states, and reliable values past their TTL or retries."""
        self.settle()
        self.update_links(now)
        for sender in self.senders.values():
            self._reports(sender.expire(now))
        if self.positioning is not None and (estimate := self.positioning.report(now)):
            self._positioned(Update((), None, estimate), now)  # coasting, or lost, is news
        if self.queries is not None:
            self.queries.expire(now)
        if (summary := self.drops.due(now)) is not None:
            self._event(summary)

    def ask(self, key: str, parameters: Any, now: float) -> Ticket | str:
        """A Zenoh get on ``key`` with ``parameters`` (a dict): the acoustic query's ticket it
        waits on (replies come as QueryAnswer / QueryEnd outputs), or why it ends at once."""
        self.settle()
        found = self.queries.spec_for(key) if self.queries is not None else None
        if found is None:
            return f"{key!r} is not a query of mission {self.mission.mission!r} at {self.node}"
        spec, server = found
        self.update_links(now)
        return self.queries.ask(spec, server, parameters, now,  # type: ignore[union-attr]
                                self.link_states.get(server))

    def query_served(self, ticket: tuple[int, str, int], values: list[Any],
                     error: str | None = None) -> None:
        """The local get of a request ended: queue its replies for the asker."""
        self.settle()
        if self.queries is not None:
            self.queries.served(ticket, values, error)

    def update_links(self, now: float) -> None:
        """Re-evaluate the peers whose link may have changed; report changes on ``link/<peer>``."""
        self.settle()
        for peer in self._link_watch.due(now, self.last_heard):
            heard = self.last_heard.get(peer)
            state = self.thresholds.state(heard, now)
            previous = self.link_states.get(peer)
            if previous is state:
                continue
            self.link_states[peer] = state
            if self.interest is not None and state is LinkState.UP \
                    and previous in (None, LinkState.DOWN):
                self.interest.repeat()  # a peer back from silence (a restart?) hears it again
            payload = {"peer": peer, "state": state.value, "last_heard": heard,
                       "silent_s": None if heard is None else now - heard}
            self._status(f"link/{peer}", payload)
            self._event(Link(now, **payload))

    def snapshot(self, now: float) -> dict[str, Any]:
        """Counters and channel ages as plain data."""
        self.settle()
        ages = {s.channel.name: s.age(now) for s in self.store.states.values()}
        return {
            "node": self.node,
            "time": now,
            "frames_sent": self.stats.frames_sent,
            "frames_received": self.stats.frames_received,
            "frames_dropped": dict(self.stats.frames_dropped),
            "payloads_dropped": dict(self.stats.payloads_dropped),
            "payload_drop_causes": self.drops.causes(),
            "clamped": clamps(self.bindings),
            "values_published": self.stats.values_published,
            "send_errors": self.stats.send_errors,
            "left_out": self.stats.left_out,
            "channel_age_s": ages,
            "received_age_s": {k: now - t for k, t in self.received_at.items()},
            "last_heard": dict(self.last_heard),
            "links": {peer: state.value for peer, state in self.link_states.items()},
            "epoch": self.epoch,
            "state": self.saving.snapshot(),
            "mismatched_peers": dict(self.mismatched),
            "unfinished": {s.channel.name: s.pending() for s in self.senders.values()},
            "sent_per_channel": dict(self.stats.sent_per_channel),
            **({"queries": self.queries.snapshot()} if self.queries else {}),
            **({"surfacing": self.surfacing.snapshot()} if self.surfacing else {}),
            **({"interest": self.interest.snapshot(self.table)} if self.interest else {}),
            **({"families": self.families.snapshot(now)} if self.table.names is not None
               or any(c.family for c in self.table.channels) else {}),
        }


_SCALARS = (int, float, str, bool, type(None))
_PLAIN_TYPES = frozenset(_SCALARS)  # exactly these (not subclasses): plain already


def publications(heard: list[tuple[HearPlan, list[dict]]]) -> list[Publish]:
    """:meth:`NodeCore.hear`'s values as the :class:`Publish` outputs :meth:`receive` gives."""
    return [Publish(key, value, encoding, latching, ros2)
            for plan, values in heard
            for (key, encoding, latching, ros2), value in zip(plan, values, strict=True)]


def plain(meta: Mapping[str, Any]) -> dict[str, Any]:
    """Link metadata reduced to msgpack-able scalars (a copy when it is plain already, as a
    simulator's is: its types are checked first)."""
    for k, v in meta.items():
        if k.__class__ is not str or v.__class__ not in _PLAIN_TYPES:
            return {str(k): v for k, v in meta.items() if isinstance(v, _SCALARS)}
    return dict(meta)
