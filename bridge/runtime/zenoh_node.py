"""The bridge runtime of one node: the asyncio + Zenoh adapter around :class:`NodeCore`.

Zenoh callbacks run on Zenoh's own threads; they hand samples to the event loop
(``call_soon_threadsafe``). The loop feeds the pure core with samples, receptions and the
time, asks it for frames at each MAC opportunity of each of its links (one
:class:`~bridge.runtime.link_port.LinkPort` per modem), and carries out what it outputs:
publications, ``@zab`` status, liveliness tokens and events.

With a :attr:`~bridge.modems.base.ModemBackend.direct` backend (``udp``) the data path skips
the loop: the Zenoh callback itself ingests a sample and, when an opportunity is open, sends
the frame; the backend's reader thread decodes a frame heard and publishes it. One lock
(:attr:`BridgeNode.lock`) keeps the core to one caller at a time; events and query outputs
are still carried out on the loop.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import itertools
import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from functools import partial
from typing import TYPE_CHECKING, Any

import msgpack
import zenoh

from bridge.core.events import Event, notable
from bridge.core.interest import output_keys
from bridge.core.link import LinkState
from bridge.core.loaded import LoadedMission
from bridge.core.node import NodeCore, NodeStats, Publish, Status
from bridge.core.positioning import Positioning
from bridge.core.shared_inputs import keys_read_alike
from bridge.core.surfacing import Relay
from bridge.errors import DecodeError, EncodeError, NodeFailure
from bridge.modems.base import ModemBackend, Reception
from bridge.runtime.gate import EventGate
from bridge.runtime.heap import HEAP
from bridge.runtime.image_queries import ImageQueries
from bridge.runtime.intake import Intake
from bridge.runtime.ip_watch import IpWatch
from bridge.runtime.keys import load_key, with_next_key
from bridge.runtime.keyspace_watch import KeyspaceWatch
from bridge.runtime.link_port import LinkPort, ingest_sample
from bridge.runtime.persistence import Persistence
from bridge.runtime.ros2_graph import Ros2Graph
from bridge.runtime.session import (
    application_of,
    bridged_attachment,
    close_quietly,
    is_bridged,
    marked,
    open_session,
    origin_of,
    origin_tag,
)
from bridge.runtime.state_file import StateFile
from bridge.runtime.zenoh_queries import QueryBridge
from bridge.wire.payloads import decode_payload
from bridge.wire.proofs import sign_output
from bridge.wire.sample_meta import encode_as
from bridge.wire.seal import KeyRing

if TYPE_CHECKING:
    from bridge.ros2.element import Ros2Element

log = logging.getLogger("zab.node")

STATS_PERIOD_S = 1.0
TX_LEAD_S = 0.01  # how far ahead a timed emission is scheduled
EVENTS_S = 0.05  # how long events of the direct data path wait for the loop, at most
EVENTS_MAX = 1024  # events of the direct data path waiting for the loop (the oldest dropped)

BackendFactory = Callable[[], ModemBackend]


def _peer_water(positioning: Positioning, peer: str, values: tuple[float, ...]) -> None:
    """A peer's CTD reading (``sound_speed_mode: mean_of_ends``)."""
    temperature, salinity, depth = values
    positioning.set_peer_water(peer, temperature, salinity, depth)


def _matching(loop: asyncio.AbstractEventLoop, changed: Callable[[str, bool], None], key: str,
              status: zenoh.MatchingStatus) -> None:
    """Zenoh thread: whether some subscriber matches ``key`` now, told to the loop."""
    loop.call_soon_threadsafe(changed, key, status.matching)


class BridgeNode:
    """Everything one vehicle runs: its Zenoh session, the core, the MAC loop and the modem."""

    def __init__(
        self,
        loaded: LoadedMission,
        node: str,
        make_backend: BackendFactory | Mapping[str, BackendFactory],
        *,
        clock: Callable[[], float] = time.time,
        on_event: Callable[[Event], None] | None = None,
        state_file: StateFile | None = None,
        key: bytes | KeyRing | None = None,
    ) -> None:
        """``state_file``: where this node keeps what a restart must resume (None: nothing
        survives a restart; peers then see a new epoch and resynchronise); ``key``: the frame
        key (default: found as ``wire.auth`` says); ``on_event``: gets every event of the node
        (:mod:`bridge.core.events`); ``make_backend``: makes the node's modem backend, or
        with several links, each link's by name."""
        self.state_file = state_file
        self.persistence = Persistence(state_file, node)
        auth = loaded.mission.wire.auth
        if key is None and auth is not None:
            key = with_next_key(auth, load_key(auth.key_env, auth.key_file))
        # (proofs on the Zenoh side, bridge.wire.proofs: with the mission key)
        self._key = key.current if isinstance(key, KeyRing) else key
        self._sign = key is not None and auth is not None and auth.sign_outputs
        self._signed = itertools.count(time.time_ns())  # signed samples' counters
        self.ip_watch: IpWatch | None = None
        self._told_alike: set[str] = set()  # peers over IP whose shared keys were logged
        self.core = NodeCore(loaded, node, key=key,
                             state=state_file.load() if state_file is not None else None)
        self.mission = loaded.mission
        self.table = loaded.table
        self.node = node
        self.clock = clock
        self.on_event = on_event or (lambda event: None)
        self.prefix = f"@zab/{self.mission.mission}/{node}"
        self._origin = origin_tag(self.mission.mission, node)
        self._tokens: dict[str, Any] = {}
        self._latest: dict[str, tuple[bytes, str, bytes | None, zenoh.Timestamp | None]] = {}
        """Per latched output key: payload, encoding, the application's attachment and the
        timestamp published."""
        self._stamp_id: zenoh.TimestampId | None = None
        self._deleted: set[str] = set()  # output keys deleted (and not put since)
        self._latched_keys: set[str] = set()
        self._sources: dict[str, str] = {}  # latched output key -> the peer it comes from
        self._over_ip: dict[str, Any] = {}  # latched output key -> its subscriber while the
        # peer it comes from is reachable over IP (see _hear_over_ip)
        self._publishers: dict[str, Any] = {}
        self._queryables: list[Any] = []
        self._interest_entities: list[Any] = []
        self._query_bridge: QueryBridge | None = None
        self._image_queries: ImageQueries | None = None
        factories = make_backend if isinstance(make_backend, Mapping) \
            else {None: make_backend}
        links = list(self.core.linkset.sides)
        self.ports: dict[str | None, LinkPort] = {
            link: LinkPort(self, link, factory, primary=link in (None, links[0]))
            for link, factory in factories.items()}
        """Each link's modem and loops (one, None, in a mission of one link)."""
        self.port = next(iter(self.ports.values()))
        """The node's first link."""
        self.lock = threading.RLock()
        """Held while the core is used: the loop, Zenoh's threads and a direct backend's
        reader all come in."""
        self._loop: asyncio.AbstractEventLoop | None = None
        self._loop_thread: int | None = None
        self._settling = False  # a call of _settle is on its way to the loop
        self._closing = False  # run() is closing the session: nothing more goes out
        self._events: deque[Event] = deque(maxlen=EVENTS_MAX)  # the direct path's, for the loop
        self.events_dropped = 0  # of those, pushed out by newer ones before the loop took them
        self._gate = EventGate()  # what goes out on …/events, at a bounded rate
        self.intake: Intake | None = None
        self._events_timer = False  # the loop's timer that takes them is armed
        self.started = asyncio.Event()
        self.failure: str | None = None  # why the node cannot go on (see fail)
        self._ended: asyncio.Event | None = None  # set on stop or failure
        self.session: zenoh.Session | None = None
        self._ros2: Ros2Graph | None = None

    # the core's state, for observers (fleet reports, tests)
    @property
    def stats(self) -> NodeStats:
        return self.core.stats

    @property
    def received_at(self) -> dict[str, float]:
        return self.core.received_at

    @property
    def last_heard(self) -> dict[str, float]:
        return self.core.last_heard

    @property
    def link_states(self) -> dict[str, LinkState]:
        return self.core.link_states

    @property
    def positioning(self) -> Positioning | None:
        return self.core.positioning

    @property
    def backend(self) -> ModemBackend | None:
        """The modem of the node's first link."""
        return self.port.backend

    @backend.setter
    def backend(self, backend: ModemBackend | None) -> None:
        self.port.backend = backend

    async def transmit(self) -> bool:
        """Carry out the core's action at an open opportunity of the first link."""
        return await self.port.transmit()

    def receive(self, rx: Reception) -> None:
        """A frame heard by the modem of the node's first link."""
        self.port.receive(rx)

    # -- lifecycle ---------------------------------------------------------------------------

    async def run(self, stop: asyncio.Event) -> None:
        """Run until ``stop`` is set; always closes the session and the modem."""
        loop = self._loop = asyncio.get_running_loop()
        self._loop_thread = threading.get_ident()
        ended = self._ended = asyncio.Event()
        self.session = open_session(self.mission.nodes[self.node].zenoh, self.node)
        self._stamp_id = self.session.new_timestamp().get_id()
        try:
            with self.lock:  # this run's epoch saved (StateError if the disk cannot take it)
                self.persistence.save(self.core.state, self.clock(), first=True)
                self.core.saved()
            self._flush()  # what a changed mission file ended, reported
            intake = self.intake = Intake(self.session, loop, self.node)
            for key, bound in self.core.bindings.items():  # a reliable channel's: lose none
                intake.subscribe(key, functools.partial(self._from_zenoh, loop, key),
                                 fifo=any(channel.reliable for channel, _, _ in bound))
            for key in self.core.families.subscriptions():  # key families: concrete keys
                intake.subscribe(key, functools.partial(self._from_family, loop, key))
            self._subscribe_positions(loop)
            self._interest_entities += KeyspaceWatch(
                self.session, intake, self.core, self.lock, self.clock, self._flush,
                lambda: self.ip_watch is not None and bool(self.ip_watch.tokens)).entities
            if self.core.interest is not None:
                self._watch_interest(loop)
            if self.core.queries is not None:
                self._query_bridge = QueryBridge(self.session, self.core, self.lock,
                                                 self.clock, self._changed, loop,
                                                 self.taken_at)
            if self.core.images is not None and self.core.images.controls:
                self._image_queries = ImageQueries(self.session, self.core, self.lock,
                                                   self.clock, self._changed, loop)
            if self.core.surfacing is not None:
                self._watch_ip(loop)
            self._ros2 = Ros2Graph(self.session, self.mission.mission, self.node)
            self._ros2.announce(self.table, self.node)  # ROS 2 topics join the ROS 2 graph
            tasks = [
                *([] if self.ip_watch is None else [asyncio.create_task(
                    self.ip_watch.run(), name=f"{self.node}-surfacing")]),
                *(asyncio.create_task(loop(), name=f"{port.name}-{what}")
                  for port in self.ports.values()
                  for what, loop in (("modem", port.modem_loop), ("tx", port.transmit_loop))),
                asyncio.create_task(self._stats_loop(), name=f"{self.node}-stats"),
                asyncio.create_task(self._health_loop(), name=f"{self.node}-health"),
            ]
            for task in tasks:
                task.add_done_callback(self._task_ended)
            self.started.set()
            waits: list[asyncio.Task[Any]] = [asyncio.create_task(stop.wait()),
                                              asyncio.create_task(ended.wait())]
            await asyncio.wait(waits, return_when=asyncio.FIRST_COMPLETED)  # (or a failure)
            for task in (*waits, *tasks):
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            self._take_events()
            with self.lock:
                self._persist()
            if self.failure is not None:
                raise NodeFailure(self.failure)
        finally:
            self._closing = True  # (a _settle still on its way finds the session closed)
            if self._query_bridge is not None:
                self._query_bridge.close()
            if self._image_queries is not None:
                self._image_queries.close()
            for port in self.ports.values():
                await port.close()
            if self._ros2 is not None:
                self._ros2.close()
            if self.intake is not None:
                self.intake.close()  # (a thread waiting for room in a lane returns)
            close_quietly(self.session)
            if self.intake is not None:
                self.intake.join()
                with self.lock:  # what the intake took as the node stopped, for the next run
                    self._persist()

    def fail(self, message: str) -> None:
        """The node cannot go on (any thread): :meth:`run` stops everything and raises
        :class:`NodeFailure` with ``message``."""
        log.critical("%s: %s: stopping (a supervisor such as systemd restarts the bridge)",
                     self.node, message)
        if self.failure is None:
            self.failure = message
        if self._ended is not None:
            self._soon(self._ended.set)

    def _task_ended(self, task: asyncio.Task[None]) -> None:
        """A task of :meth:`run` ended: unless cancelled (the node stops), it failed."""
        if task.cancelled():
            return
        error = task.exception()
        if error is not None:
            log.critical("%s: the %s task failed", self.node, task.get_name(),
                         exc_info=error)
        what = f"{type(error).__name__}: {error}" if error is not None else "it returned"
        self.fail(f"the {task.get_name()} task ended ({what})")

    # -- Zenoh → core ------------------------------------------------------------------------

    def _from_family(self, loop: asyncio.AbstractEventLoop, expression: str,
                     sample: zenoh.Sample) -> None:
        """A key family's intake thread: the sample under its own key, handed to the loop in
        the subscription's lane (an application putting on ever new keys under the family's
        expression must not make a queue a key). A put on a key expression with wildcards
        names no one member: counted, as a payload no channel can take (so is a delete)."""
        key = str(sample.key_expr)
        if "*" in key:
            kind = "put" if sample.kind == zenoh.SampleKind.PUT else "delete"
            with self.lock:
                self.core.drop_payload(key, f"a {kind} on a key expression with wildcards "
                                       f"reaches key family {expression!r} but names none of "
                                       f"its members: {kind} each member's own key",
                                       self.clock(), "unfit")
                self._flush()
            return
        self._from_zenoh(loop, key, sample, lane=expression)

    def _from_zenoh(self, loop: asyncio.AbstractEventLoop, key: str, sample: zenoh.Sample,
                    lane: str | None = None) -> None:
        """The key's intake thread: copy what we need; ingest it here with a direct backend,
        else hand it to the loop (in ``lane``: the key's own by default). A payload over the
        key's cap is counted, never copied."""
        attachment = sample.attachment  # (each read of a sample's field builds an object)
        extra = attachment.to_bytes() if attachment is not None else b""
        if extra and bridged_attachment(extra):
            return
        sample_key = str(sample.key_expr) if "*" in key else None  # (else it is ``key``)
        if sample.kind != zenoh.SampleKind.PUT:
            self.intake.to_loop(lane or key, partial(self._delete, key))  # type: ignore[union-attr]
            return
        if self._oversized(key, sample):
            return
        data, encoding = sample.payload.to_bytes(), str(sample.encoding)
        ref = extra[4:].decode("utf-8", "replace") if extra[:4] == b"ref:" else None
        stamp = sample.timestamp  # (an application's own: when its value was taken)
        taken = stamp.get_time().timestamp() if stamp is not None else None
        backend = self._direct()
        if backend is not None:
            self.port.ingest(backend, (key, data, encoding, ref, sample_key, extra or None,
                                       taken))
        else:
            self.intake.to_loop(lane or key, partial(self.ingest, key, data, encoding, ref,  # type: ignore[union-attr]
                                             sample_key, extra or None, taken))

    def _delete(self, key: str) -> None:
        """On the loop: an application deleted input ``key``."""
        with self.lock:
            self.core.delete(key, self.clock())
            self._flush()
        self._wake_all()

    def _oversized(self, key: str, sample: zenoh.Sample) -> bool:
        """Whether ``sample``'s payload is over ``key``'s cap: then counted, never copied."""
        size, cap = len(sample.payload), self.core.payload_cap(key)
        if size <= cap:
            return False
        with self.lock:
            self.core.drop_payload(key, f"{size} bytes, over this key's cap of {cap}",
                                   self.clock(), "too_large")
            self._flush()
        return True

    def _direct(self) -> ModemBackend | None:
        """The node's one modem, if it is direct (:meth:`LinkPort.direct`); with several
        links, None: samples go through the loop."""
        return self.port.direct() if len(self.ports) == 1 else None

    def _on_loop(self) -> bool:
        return threading.get_ident() == self._loop_thread

    def _soon(self, callback: Callable[..., object], *args: Any) -> None:
        """Run ``callback`` on the loop: now if this is the loop's thread, else next."""
        if self._on_loop() or self._loop is None:
            callback(*args)
        else:
            with contextlib.suppress(RuntimeError):  # the loop has closed: the node is gone
                self._loop.call_soon_threadsafe(callback, *args)

    def _changed(self) -> None:
        """On the loop: the core has outputs to carry out and may have something due."""
        self._flush()
        self._wake_all()

    def _wake_all(self) -> None:
        """Every link's transmit loop asks the core again (on the loop)."""
        for port in self.ports.values():
            port.data.set()

    def wake_if_sooner(self, now: float) -> None:
        """Holding the lock: wake each link's transmit loop whose next opportunity comes
        before it would wake by itself."""
        for port in self.ports.values():
            port.wake_if_sooner(now)

    def _subscribe_positions(self, loop: asyncio.AbstractEventLoop) -> None:
        """Live positions: this node's own (``nav_key``), anchors' and the CTD's."""
        assert self.session is not None and self.intake is not None
        intake = self.intake

        def listen(key: str, names: tuple[str, ...],
                   handler: Callable[[tuple[float, ...]], None], bridged: bool = False,
                   own: bool = True) -> None:
            """``bridged``: samples other bridges published count too; ``own`` false: not
            those this bridge published (its core took them from the frames already)."""
            def numbers(data: bytes, encoding: str) -> None:
                with self.lock:
                    values = self.core.numbers(key, data, encoding, names, self.clock())
                    if values is not None:
                        try:
                            handler(values)
                        except ValueError as exc:  # e.g. an implausible CTD reading
                            self.core.drop_payload(key, str(exc), self.clock(),
                                                   "implausible")
                    self._flush()

            def on_sample(sample: zenoh.Sample) -> None:
                if sample.kind != zenoh.SampleKind.PUT or (not bridged and is_bridged(sample)):
                    return
                if not own and sample.attachment is not None \
                        and origin_of(sample.attachment.to_bytes()) == self._origin:
                    return
                if not self._oversized(key, sample):
                    data, encoding = sample.payload.to_bytes(), str(sample.encoding)
                    intake.to_loop(key, partial(numbers, data, encoding))

            intake.subscribe(key, on_sample)

        nav_key = self.mission.nodes[self.node].nav_key
        if nav_key is not None:
            listen(nav_key, ("x", "y", "depth"), self.move)
        positioning = self.core.positioning
        if positioning is None:
            return
        if nav_key is not None and positioning.tracker is not None:
            def steer(sample: zenoh.Sample) -> None:  # heading and speed, where nav has them
                if sample.kind == zenoh.SampleKind.PUT and not is_bridged(sample) \
                        and len(sample.payload) <= self.core.payload_cap(nav_key):
                    data, encoding = sample.payload.to_bytes(), str(sample.encoding)
                    intake.to_loop(f"{nav_key} (heading)", partial(self._steer, data, encoding))

            intake.subscribe(nav_key, steer)
        for anchor, key in self.mission.ranging.anchor_keys.items():
            if anchor in positioning.anchors:  # (what this bridge decodes, its core takes)
                listen(key, ("x", "y", "depth"),
                       functools.partial(self._anchor_at, positioning, anchor),
                       bridged=True, own=False)
        ctd_key = self.mission.ranging.ctd_key
        if ctd_key is not None:
            listen(ctd_key, ("temperature_c", "salinity_psu", "depth_m"),
                   lambda v: positioning.set_water(*v), bridged=True)
        for peer, key in positioning.peer_ctd_keys().items():  # sound_speed_mode: mean_of_ends
            listen(key, ("temperature_c", "salinity_psu", "depth_m"),
                   functools.partial(_peer_water, positioning, peer), bridged=True)

    def _anchor_at(self, positioning: Positioning, anchor: str,
                   position: tuple[float, ...]) -> None:
        """An anchor's live position, as another bridge published it."""
        x, y, depth = position
        positioning.set_anchor(anchor, (x, y, depth), self.clock())

    def _watch_interest(self, loop: asyncio.AbstractEventLoop) -> None:
        """Demand-driven missions: a matching listener on every output key this node publishes
        says whether some application (or this bridge's own input) subscribes to it."""
        assert self.session is not None
        keys = output_keys(self.table, self.node)
        matched: dict[str, bool] = {}

        def changed(key: str, matching: bool) -> None:
            matched[key] = matching
            wanted = {i for i, ks in keys.items() if any(matched.get(k) for k in ks)}
            assert self.core.interest is not None
            with self.lock:
                new = self.core.interest.set_local(wanted)
            if new:
                self._wake_all()  # the new @want is due at the next opportunity

        for key in sorted({k for ks in keys.values() for k in ks}):
            publisher = self.session.declare_publisher(key)
            self._interest_entities.append(publisher)
            self._interest_entities.append(publisher.declare_matching_listener(
                functools.partial(_matching, loop, changed, key)))
            # (the stub says bool; the binding gives a MatchingStatus, as the listener does)
            changed(key, publisher.matching_status.matching)  # type: ignore[attr-defined]

    def _watch_ip(self, loop: asyncio.AbstractEventLoop) -> None:
        """Surfacing: this bridge's liveliness token, and the peers' seen over IP, each proven
        with the mission key (:mod:`bridge.runtime.ip_watch`)."""
        assert self.session is not None
        self.ip_watch = IpWatch(self.session, self.mission.mission, self.node,
                                set(self.mission.nodes), self._key, self._ip_changed)
        self.ip_watch.start(loop)
        self._interest_entities.extend(self.ip_watch.entities)

    def _ip_changed(self, peer: str, up: bool) -> None:
        if up and peer not in self._told_alike:
            self._told_alike.add(peer)
            alike = keys_read_alike(self.mission, self.table, self.node, peer)
            if alike:  # (zab check warns of these too)
                log.warning("%s: %s is reachable over IP and reads %s as this node does: "
                            "their samples cannot be told apart from this vehicle's own, and "
                            "are taken as its own (name the sender in the mission's input "
                            "keys, e.g. '{node}/%s')", self.node, peer,
                            ", ".join(map(repr, alike)), alike[0])
        with self.lock:
            self.core.ip_reachable(peer, up, self.clock())
            self._flush()
        self._hear_over_ip(peer)
        self._wake_all()  # a dive makes the peer's channels due again

    def _steer(self, data: bytes, encoding: str) -> None:
        """This node's nav sample: its heading (and speed) steer the tracker, if it has them."""
        assert self.core.positioning is not None
        try:
            value = decode_payload(data, encoding)
            heading = float(value["heading"])
        except (DecodeError, TypeError, KeyError, ValueError):
            return  # no heading in this nav: ranges and depth alone
        try:
            speed: float | None = float(value["speed"])
        except (TypeError, KeyError, ValueError):
            speed = None
        with self.lock:
            self.core.positioning.set_heading(heading, speed, self.clock())

    def move(self, position: tuple[float, ...]) -> None:
        """This node's live position: move the (simulated) modem, unless a scripted path
        moves it, and keep the depth."""
        x, y, depth = position
        if self.mission.nodes[self.node].path is None:
            for port in self.ports.values():  # every modem of the vehicle moves with it
                if port.backend is not None:
                    port.backend.set_position(x, y, depth)
        if self.core.positioning is not None:
            with self.lock:
                self.core.positioning.set_depth(depth)

    def ingest(self, key: str, data: bytes, encoding: str, ref: str | None = None,
               sample_key: str | None = None, attachment: bytes | None = None,
               taken: float | None = None) -> None:
        """A sample arrived on an input key (``ref``: the publisher's correlation text;
        ``sample_key``: the sample's own key, under a wildcard input key; ``attachment``: the
        sample's; ``taken``: its own timestamp, if any). Any thread: with a direct backend an
        open opportunity's frame leaves from here, else from the loop."""
        sample = (key, data, encoding, ref, sample_key, attachment, taken)
        if len(self.ports) == 1:
            self.port.ingest(self._direct(), sample)
            return
        with self.lock:
            ingest_sample(self.core, sample, self.clock())
            self.settle_soon()

    def settle_soon(self) -> None:
        """Holding the lock, on any thread: the core took input. What it has to say goes out
        on the loop's next turn, once for all the input taken until then (:meth:`_settle`):
        a burst of samples costs one save of the state, not one each (a flood on a reliable
        channel's key with ``overflow: drop_oldest`` had the loop doing nothing but save, its
        frames all late)."""
        if self._settling:
            return
        if self._loop is None:  # (not running yet: at once)
            self._flush()
            return
        self._settling = True
        try:
            self._loop.call_soon_threadsafe(self._settle)
        except RuntimeError:  # the loop has closed: the node is gone
            self._settling = False

    def _settle(self) -> None:
        """On the loop: carry out what the input taken since :meth:`settle_soon` produced
        (the state saved first), then let each link's transmit loop look again."""
        with self.lock:
            self._settling = False
            if self._closing:  # (the node stops: its last state is saved by run())
                return
            self._flush()
        self._wake_all()  # each link's transmit loop decides when

    def _persist(self) -> None:
        """Save the core's state if a restart must not lose what changed; a save that fails
        is reported and retried (:mod:`bridge.runtime.persistence`), never raised."""
        if self.core.needs_save:
            saved = self.persistence.save(self.core.state, self.clock())
            if saved:
                self.core.saved()
            if saved is not None:
                self.core.storage(self.persistence.error, self.clock())

    def _flush(self) -> None:
        """Carry out the core's outputs, once what they depend on is saved. Off the loop,
        events and query outputs go to the loop (their consumers live there)."""
        with self.lock:
            self._persist()
            outputs = self.core.take()
            if outputs:
                self._carry_out(outputs)

    def _carry_out(self, outputs: list[Any]) -> None:
        later: list[Any] | None = None  # events and query outputs for the loop, off it
        asked = False  # (whether this is the loop's thread: asked once, past the publications)
        queries = False  # among ``later``
        for output in outputs:
            if output.__class__ is Publish:  # (the usual output: asked first)
                self._put(output)
                continue
            if not asked:
                asked = True
                later = [] if not self._on_loop() and self._loop is not None else None
            if isinstance(output, Status):
                self._publish_raw(f"{self.prefix}/{output.topic}", output.payload)
                if output.topic.startswith("link/"):
                    self._token(output.topic, output.payload["state"])
            elif later is not None and not isinstance(output, Relay):
                later.append(output)  # an event or a query output
                queries = queries or not isinstance(output, Event)
            elif isinstance(output, Event):
                self._event(output)
            elif isinstance(output, Relay):  # surfaced peer: the sample as it came, over IP
                self._relay(output)
            elif self._query_bridge is not None:
                self._query_bridge.handle(output)
        if later:
            self._to_loop(later, queries)

    def _to_loop(self, outputs: list[Any], queries: bool) -> None:
        """Off the loop, holding the lock: query outputs go to the loop at once; events wait
        there up to ``EVENTS_S``. The loop takes them by a timer of its own, re-armed while
        they keep coming, so the data path wakes the loop once when traffic starts."""
        if queries:
            self._soon(self._carry_out, outputs)
            return
        overflow = len(self._events) + len(outputs) - EVENTS_MAX
        if overflow > 0:
            self.events_dropped += overflow
        self._events.extend(outputs)
        self._loop_later()

    def _loop_later(self) -> None:
        """Holding the lock: the loop's timer takes the events within ``EVENTS_S`` (the first
        after a quiet spell starts it)."""
        if not self._events_timer:
            self._events_timer = True
            self._soon(self._arm_events)

    def _arm_events(self) -> None:
        assert self._loop is not None
        self._loop.call_later(EVENTS_S, self._events_due)

    def _events_due(self) -> None:
        """The loop's timer: carry out the events; again in ``EVENTS_S`` while they come."""
        took = self._take_events()
        with self.lock:  # (events that came meanwhile found the timer still on)
            self._events_timer = took or bool(self._events)
        if self._events_timer:
            self._arm_events()

    def _take_events(self) -> bool:
        """Carry out the events waiting for the loop; returns whether there were any."""
        with self.lock:
            events = list(self._events)
            self._events.clear()
        self._carry_out(events)
        return bool(events)

    def _event(self, event: Event) -> None:
        self.on_event(event)
        if notable(event) and self.session is not None \
                and (held := self._gate.admit(event, self.clock())) is not None:
            self._publish_raw(f"{self.prefix}/events", {
                "kind": event.kind, "node": self.node,
                **{k: v for k, v in event.to_dict().items() if not isinstance(v, bytes)},
                **({"held_back": held} if held else {})})

    def _token(self, topic: str, state: str) -> None:
        """One liveliness token per live link, on the link's key."""
        assert self.session is not None
        token = self._tokens.get(topic)
        if state == LinkState.DOWN.value and token is not None:
            token.undeclare()
            del self._tokens[topic]
        elif state != LinkState.DOWN.value and token is None:
            self._tokens[topic] = self.session.liveliness().declare_token(
                f"{self.prefix}/{topic}")

    def _put(self, output: Publish) -> None:
        """A decoded value out on Zenoh."""
        if output.ros2 is None:
            self.publish(output)
        else:
            self._publish_ros2(output.key, output.value, output.ros2)

    def publish(self, output: Publish) -> None:
        """Put a decoded value (or its delete) on Zenoh, marked as bridged so no bridge sends
        it back, stamped with when it was taken at the source, with the application's
        attachment where the channel carried it."""
        assert self.session is not None
        key = output.key
        publisher = self._publishers.get(key)
        if publisher is None:
            publisher = self.session.declare_publisher(key)
            self._publishers[key] = publisher
        stamp = self._stamp(output.taken)
        if output.delete:  # once: a latched tombstone comes again, the key stays deleted
            self._latest.pop(key, None)
            if key not in self._deleted:
                self._deleted.add(key)
                publisher.delete(attachment=self._attachment(key, b"", output.attachment),
                                 timestamp=stamp)
            return
        if self._deleted:
            self._deleted.discard(key)
        payload, enc = encode_as(output.value, output.encoding)
        self._latest[key] = (payload, enc, output.attachment, stamp)
        if output.latched and key not in self._latched_keys:
            self._latched_keys.add(key)
            self._queryables.append(
                self.session.declare_queryable(key, functools.partial(self._answer, key=key)))
            if output.src is not None:
                self._sources[key] = output.src
                self._hear_over_ip(output.src)
        publisher.put(payload, encoding=zenoh.Encoding(enc),
                      attachment=self._attachment(key, payload, output.attachment),
                      timestamp=stamp)

    def _relay(self, relay: Relay) -> None:
        """A surfaced peer's sample (or delete) as it came, over IP, with the attachment the
        acoustic path would publish."""
        assert self.session is not None
        attachment = self._attachment(relay.key, relay.data, relay.attachment)
        stamp = self._stamp(relay.taken)
        if relay.delete:
            self.session.delete(relay.key, attachment=attachment, timestamp=stamp)
        else:
            self.session.put(relay.key, relay.data, encoding=zenoh.Encoding(relay.encoding),
                             attachment=attachment, timestamp=stamp)

    def _stamp(self, taken: float | None) -> zenoh.Timestamp | None:
        """A Zenoh timestamp of this node's session for ``taken`` (seconds since the epoch)."""
        if taken is None or self._stamp_id is None:
            return None
        seconds = math.floor(taken)
        return zenoh.Timestamp(zenoh.NTP64(seconds, int((taken - seconds) * 1e9)),
                               self._stamp_id)

    def taken_at(self, key: str) -> zenoh.Timestamp | None:
        """The timestamp of the latched value last published on ``key``, if any."""
        latest = self._latest.get(key)
        return latest[3] if latest is not None else None

    def _publish_ros2(self, key: str, value: Any, ros2: Ros2Element) -> None:
        """Publish a decoded value as a ROS 2 message (rmw_zenoh's key, attachment, tokens)."""
        assert self._ros2 is not None
        try:
            self._ros2.publish(key, value, ros2, self.clock())
        except EncodeError as exc:
            self.core.drop_payload(key, str(exc), self.clock(), "unpublishable")

    def _hear_over_ip(self, peer: str) -> None:
        """Listen on the latched output keys ``peer``'s values come out on while it is
        reachable over IP, and only then: a surfaced vehicle's puts and deletes reach them
        over IP (its bridge's relays, or its applications' own where the key is the same), and
        a get here must answer those, not the older value that last crossed the water. (A
        subscriber here would say to the demand-driven channels that they are wanted: hence
        not while the peer is under water.)"""
        surfacing = self.core.surfacing
        up = surfacing is not None and peer in surfacing.reachable
        for key, source in self._sources.items():
            if source != peer:
                continue
            listening = self._over_ip.get(key)
            if up and listening is None:
                assert self.session is not None  # (sources: keys this session published)
                self._over_ip[key] = self.session.declare_subscriber(
                    key, functools.partial(self._heard, key=key),
                    allowed_origin=zenoh.Locality.REMOTE)
            elif not up and listening is not None:
                del self._over_ip[key]
                listening.undeclare()

    def _heard(self, sample: zenoh.Sample, key: str) -> None:
        """Zenoh thread: a latched output ``key`` put or deleted over IP by another session
        (:meth:`_hear_over_ip`): what a get on it answers from now on, unless older than what
        this node holds."""
        stamp = sample.timestamp
        held = self._latest.get(key)
        if stamp is not None and held is not None and held[3] is not None \
                and stamp.get_time() < held[3].get_time():
            return
        if sample.kind != zenoh.SampleKind.PUT:
            self._latest.pop(key, None)
            return
        attachment = sample.attachment
        self._latest[key] = (sample.payload.to_bytes(), str(sample.encoding),
                             application_of(attachment.to_bytes() if attachment else b""),
                             stamp)

    def _answer(self, query: zenoh.Query, key: str) -> None:
        """Zenoh thread: a late joiner asks for a latched key; reply with its last value."""
        latest = self._latest.get(key)
        if latest is not None:
            payload, enc, application, stamp = latest
            query.reply(key, payload, encoding=zenoh.Encoding(enc),
                        attachment=self._attachment(key, payload, application), timestamp=stamp)
        query.drop()

    def _publish_raw(self, key: str, value: dict[str, Any]) -> None:
        assert self.session is not None
        payload = msgpack.packb(value, use_bin_type=True)
        self.session.put(key, payload, encoding=zenoh.Encoding("application/msgpack"),
                         attachment=self._attachment(key, payload))

    def _attachment(self, key: str, payload: bytes, application: bytes | None = None
                    ) -> bytes:
        """What a sample this bridge puts on ``key`` carries: its origin tag (no bridge sends
        it back), then the sending ``application``'s attachment where a channel carries it
        (:func:`~bridge.runtime.session.marked`), signed where the mission asks
        (:func:`~bridge.wire.proofs.sign_output`)."""
        origin = marked(self._origin, application)
        if not self._sign:
            return origin
        assert self._key is not None
        return sign_output(self._key, origin, key, next(self._signed), payload)

    # -- health --------------------------------------------------------------------------------

    def snapshot(self) -> dict[str, Any]:
        """Counters and channel ages as plain data; ``modem``: the modem backend's counters
        (by link name with several links)."""
        with self.lock:
            snapshot = self.core.snapshot(self.clock())
        snapshot["state"].update(self.persistence.snapshot())
        if self._query_bridge is not None and "queries" in snapshot:
            snapshot["queries"]["refused_gets"] = self._query_bridge.refused
        if self.ip_watch is not None and "surfacing" in snapshot:
            snapshot["surfacing"]["unproven"] = self.ip_watch.unproven
        if self.intake is not None:
            snapshot["intake"] = {**self.intake.snapshot(), "events_dropped": self.events_dropped,
                                  "events_held_back": self._gate.held_back,
                                  "heap": HEAP.snapshot()}
        modems = {port.link: dict(port.backend.stats) for port in self.ports.values()
                  if port.backend is not None}  # (the drivers' counters: bad lines, retries...)
        if modems:
            snapshot["modem"] = modems.get(None, modems)
        return snapshot

    def update_links(self, now: float) -> None:
        """Re-evaluate every peer's link now."""
        with self.lock:
            self.core.update_links(now)
            self._flush()

    async def _health_loop(self) -> None:
        period = min(1.0, self.core.thresholds.degraded_after_s / 4)
        while True:
            with self.lock:
                self.core.tick(self.clock())
                self._flush()
            await asyncio.sleep(period)

    async def _stats_loop(self) -> None:
        while True:
            await asyncio.sleep(STATS_PERIOD_S)
            HEAP.check(time.monotonic())  # (freed heap back to the system, after huge samples)
            self._publish_raw(f"{self.prefix}/stats", self.snapshot())
