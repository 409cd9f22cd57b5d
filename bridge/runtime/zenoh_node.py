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
import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

import msgpack
import zenoh

from bridge.core.events import Event, notable
from bridge.core.interest import output_keys
from bridge.core.link import LinkState
from bridge.core.loaded import LoadedMission
from bridge.core.node import NodeCore, NodeStats, Publish, Status
from bridge.core.positioning import Positioning
from bridge.core.surfacing import Relay
from bridge.errors import DecodeError, EncodeError
from bridge.modems.base import ModemBackend, Reception
from bridge.runtime.keys import load_key
from bridge.runtime.link_port import LinkPort
from bridge.runtime.ros2_graph import Ros2Graph
from bridge.runtime.session import (
    bridged_attachment,
    close_quietly,
    is_bridged,
    open_session,
    origin_tag,
)
from bridge.runtime.state_file import StateFile
from bridge.runtime.zenoh_queries import QueryBridge
from bridge.wire.payloads import decode_payload, encode_payload

if TYPE_CHECKING:
    from bridge.ros2.element import Ros2Element

log = logging.getLogger("zab.node")

STATS_PERIOD_S = 1.0
TX_LEAD_S = 0.01  # how far ahead a timed emission is scheduled
EVENTS_S = 0.05  # how long events of the direct data path wait for the loop, at most

BackendFactory = Callable[[], ModemBackend]


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
        key: bytes | None = None,
    ) -> None:
        """``state_file``: where this node keeps what a restart must resume (None: nothing
        survives a restart; peers then see a new epoch and resynchronise); ``key``: the frame
        key (default: found as ``wire.auth`` says); ``on_event``: gets every event of the node
        (:mod:`bridge.core.events`); ``make_backend``: makes the node's modem backend, or
        with several links, each link's by name."""
        self.state_file = state_file
        auth = loaded.mission.wire.auth
        if key is None and auth is not None:
            key = load_key(auth.key_env, auth.key_file)
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
        self._latest: dict[str, tuple[bytes, str]] = {}
        self._latched_keys: set[str] = set()
        self._publishers: dict[str, Any] = {}
        self._queryables: list[Any] = []
        self._interest_entities: list[Any] = []
        self._query_bridge: QueryBridge | None = None
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
        self._events: deque[Event] = deque()  # from the direct data path, for the loop
        self._events_timer = False  # the loop's timer that takes them is armed
        self.started = asyncio.Event()
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
        self.session = open_session(self.mission.nodes[self.node].zenoh, self.node)
        try:
            self._flush()  # this run's epoch saved; what a changed mission file ended, reported
            for key in self.core.bindings:
                self.session.declare_subscriber(
                    key, lambda s, k=key: self._from_zenoh(loop, k, s)
                )
            for key in self.core.families.subscriptions():  # key families: concrete keys
                self.session.declare_subscriber(
                    key, lambda s: self._from_zenoh(loop, str(s.key_expr), s))
            self._subscribe_positions(loop)
            if self.core.interest is not None:
                self._watch_interest(loop)
            if self.core.queries is not None:
                self._query_bridge = QueryBridge(self.session, self.core, self.lock,
                                                 self.clock, self._changed, loop)
            if self.core.surfacing is not None:
                self._watch_ip(loop)
            self._ros2 = Ros2Graph(self.session, self.mission.mission, self.node)
            self._ros2.announce(self.table, self.node)  # ROS 2 topics join the ROS 2 graph
            tasks = [
                *(asyncio.create_task(loop(), name=f"{port.name}-{what}")
                  for port in self.ports.values()
                  for what, loop in (("modem", port.modem_loop), ("tx", port.transmit_loop))),
                asyncio.create_task(self._stats_loop(), name=f"{self.node}-stats"),
                asyncio.create_task(self._health_loop(), name=f"{self.node}-health"),
            ]
            self.started.set()
            await stop.wait()
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            self._take_events()
            with self.lock:
                self._persist()
        finally:
            if self._query_bridge is not None:
                self._query_bridge.close()
            for port in self.ports.values():
                await port.close()
            if self._ros2 is not None:
                self._ros2.close()
            close_quietly(self.session)

    # -- Zenoh → core ------------------------------------------------------------------------

    def _from_zenoh(self, loop: asyncio.AbstractEventLoop, key: str, sample: zenoh.Sample) -> None:
        """Zenoh thread: copy what we need; ingest it here with a direct backend, else hand
        it to the loop."""
        if sample.kind != zenoh.SampleKind.PUT:
            return
        attachment = sample.attachment  # (each read of a sample's field builds an object)
        extra = attachment.to_bytes() if attachment is not None else b""
        if extra and bridged_attachment(extra):
            return
        data, encoding = sample.payload.to_bytes(), str(sample.encoding)
        ref = extra[4:].decode("utf-8", "replace") if extra[:4] == b"ref:" else None
        sample_key = str(sample.key_expr) if "*" in key else None  # (else it is ``key``)
        backend = self._direct()
        if backend is not None:
            self.port.ingest(backend, (key, data, encoding, ref, sample_key))
        else:
            loop.call_soon_threadsafe(self.ingest, key, data, encoding, ref, sample_key)

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
        assert self.session is not None

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
                            self.core.drop_payload(key, str(exc), self.clock())
                    self._flush()

            def on_sample(sample: zenoh.Sample) -> None:
                if sample.kind != zenoh.SampleKind.PUT or (not bridged and is_bridged(sample)):
                    return
                if not own and sample.attachment is not None \
                        and sample.attachment.to_bytes() == self._origin:
                    return
                data, encoding = sample.payload.to_bytes(), str(sample.encoding)
                loop.call_soon_threadsafe(numbers, data, encoding)

            self.session.declare_subscriber(key, on_sample)  # type: ignore[union-attr]

        nav_key = self.mission.nodes[self.node].nav_key
        if nav_key is not None:
            listen(nav_key, ("x", "y", "depth"), self.move)
        positioning = self.core.positioning
        if positioning is None:
            return
        if nav_key is not None and positioning.tracker is not None:
            def steer(sample: zenoh.Sample) -> None:  # heading and speed, where nav has them
                if sample.kind == zenoh.SampleKind.PUT and not is_bridged(sample):
                    data, encoding = sample.payload.to_bytes(), str(sample.encoding)
                    loop.call_soon_threadsafe(self._steer, data, encoding)

            self.session.declare_subscriber(nav_key, steer)
        for anchor, key in self.mission.ranging.anchor_keys.items():
            if anchor in positioning.anchors:  # (what this bridge decodes, its core takes)
                listen(key, ("x", "y", "depth"),
                       lambda v, a=anchor: positioning.set_anchor(  # type: ignore[misc]
                           a, v, self.clock()), bridged=True, own=False)
        ctd_key = self.mission.ranging.ctd_key
        if ctd_key is not None:
            listen(ctd_key, ("temperature_c", "salinity_psu", "depth_m"),
                   lambda v: positioning.set_water(*v), bridged=True)
        for peer, key in positioning.peer_ctd_keys().items():  # sound_speed_mode: mean_of_ends
            listen(key, ("temperature_c", "salinity_psu", "depth_m"),
                   lambda v, p=peer: positioning.set_peer_water(p, *v),  # type: ignore[misc]
                   bridged=True)

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
                lambda status, k=key: loop.call_soon_threadsafe(changed, k, status.matching)))
            changed(key, publisher.matching_status.matching)

    def _watch_ip(self, loop: asyncio.AbstractEventLoop) -> None:
        """Surfacing: this bridge's liveliness token, and the peers' tokens seen over IP."""
        assert self.session is not None
        liveliness = self.session.liveliness()
        self._interest_entities.append(liveliness.declare_token(f"{self.prefix}/bridge"))

        def on_token(sample: zenoh.Sample) -> None:  # Zenoh thread
            parts = str(sample.key_expr).split("/")
            up = sample.kind == zenoh.SampleKind.PUT
            if len(parts) == 4 and parts[2] in self.mission.nodes:
                loop.call_soon_threadsafe(self._ip_changed, parts[2], up)

        self._interest_entities.append(liveliness.declare_subscriber(
            f"@zab/{self.mission.mission}/*/bridge", on_token, history=True))

    def _ip_changed(self, peer: str, up: bool) -> None:
        with self.lock:
            self.core.ip_reachable(peer, up, self.clock())
            self._flush()
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
               sample_key: str | None = None) -> None:
        """A sample arrived on an input key (``ref``: the publisher's correlation text;
        ``sample_key``: the sample's own key, under a wildcard input key). Any thread: with
        a direct backend an open opportunity's frame leaves from here, else from the loop."""
        if len(self.ports) == 1:
            self.port.ingest(self._direct(), (key, data, encoding, ref, sample_key))
            return
        with self.lock:
            self.core.ingest(key, data, encoding, self.clock(), ref, sample_key)
            self._flush()
        self._soon(self._wake_all)  # each link's transmit loop decides when

    def _persist(self) -> None:
        """Save the core's state if a restart must not lose what changed."""
        if self.core.needs_save:
            if self.state_file is not None:
                self.state_file.save(self.core.state())
            self.core.saved()

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
                self._put(output.key, output.value, output.encoding, output.latched, output.ros2)
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
                assert self.session is not None
                self.session.put(output.key, output.data, encoding=zenoh.Encoding(output.encoding),
                                 attachment=self._origin)
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
        if notable(event) and self.session is not None:
            self._publish_raw(f"{self.prefix}/events", {
                "kind": event.kind, "node": self.node,
                **{k: v for k, v in event.to_dict().items() if not isinstance(v, bytes)}})

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

    def _put(self, key: str, value: Any, encoding: str, latched: bool,
             ros2: Ros2Element | None) -> None:
        """A decoded value out on Zenoh (a :class:`Publish`'s fields)."""
        if ros2 is None:
            self.publish(key, value, encoding, latched=latched)
        else:
            self._publish_ros2(key, value, ros2)

    def publish(self, key: str, value: Any, encoding: str, *, latched: bool = False) -> None:
        """Put a decoded value on Zenoh, marked as bridged so no bridge sends it back."""
        assert self.session is not None
        payload, enc = encode_payload(value, encoding)
        publisher = self._publishers.get(key)
        if publisher is None:
            publisher = self.session.declare_publisher(key, encoding=zenoh.Encoding(enc))
            self._publishers[key] = publisher
        self._latest[key] = (payload, enc)
        if latched and key not in self._latched_keys:
            self._latched_keys.add(key)
            self._queryables.append(
                self.session.declare_queryable(key, lambda q, k=key: self._answer(q, k))
            )
        publisher.put(payload, attachment=self._origin)

    def _publish_ros2(self, key: str, value: Any, ros2: Ros2Element) -> None:
        """Publish a decoded value as a ROS 2 message (rmw_zenoh's key, attachment, tokens)."""
        assert self._ros2 is not None
        try:
            self._ros2.publish(key, value, ros2, self.clock())
        except EncodeError as exc:
            self.core.drop_payload(key, str(exc), self.clock())

    def _answer(self, query: zenoh.Query, key: str) -> None:
        """Zenoh thread: a late joiner asks for a latched key; reply with its last value."""
        latest = self._latest.get(key)
        if latest is not None:
            query.reply(key, latest[0], encoding=zenoh.Encoding(latest[1]),
                        attachment=self._origin)
        query.drop()

    def _publish_raw(self, key: str, value: dict[str, Any]) -> None:
        assert self.session is not None
        self.session.put(key, msgpack.packb(value, use_bin_type=True),
                         encoding=zenoh.Encoding("application/msgpack"), attachment=self._origin)

    # -- health --------------------------------------------------------------------------------

    def snapshot(self) -> dict[str, Any]:
        """Counters and channel ages as plain data."""
        with self.lock:
            return self.core.snapshot(self.clock())

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
            self._publish_raw(f"{self.prefix}/stats", self.snapshot())
