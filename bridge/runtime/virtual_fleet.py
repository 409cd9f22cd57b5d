"""A whole fleet on a virtual clock: every node's :class:`NodeCore` over the pure :class:`Ocean`.

No Zenoh, no sockets, no sleeping: a discrete-event loop jumps from one event to the next
(a MAC opportunity, a frame arriving, an application sample, a health tick), so an hour of
mission runs in seconds and the same seed gives the same run. Applications are played by
:meth:`FastFleet.put` (scheduled samples on input keys); what nodes publish is collected in
:attr:`FastFleet.outputs` and passed to ``on_output``.

Nodes with a scripted ``path`` follow it from the start time. A mission with several links
has an ocean per link (each modem kind with its own preset: range, rate, delay), and each node
a transmitter on each of its links. What it leaves out compared with ``zab sim``: Zenoh itself
(keys, latching queries), modem drivers, and clock offsets (every node shares the virtual
clock).
"""

from __future__ import annotations

import heapq
import itertools
import random
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

import msgpack

from bridge.core.events import Event
from bridge.core.interest import own_subscriptions, wanted_by
from bridge.core.loaded import LoadedMission
from bridge.core.mac import Schedule
from bridge.core.node import NodeCore, Publish, SendFrame, Status, Taken
from bridge.core.surfacing import Relay
from bridge.errors import EncodeError, FrameError
from bridge.frozen import direct_init
from bridge.mission.presets import Preset
from bridge.modems.base import Reception
from bridge.runtime.keys import keys_for_run
from bridge.runtime.virtual_queries import VirtualQueries
from bridge.sim.ocean import Delivery, Ocean, TransmitRefused
from bridge.sim.scenario import surface_script, water_of, water_stats, waters_of
from bridge.wire.frame import DecodedFrame
from bridge.wire.payloads import MSGPACK, encode_payload
from bridge.wire.seal import KeyRing

TICK_S = 1.0

Port = tuple[str, str | None]
"""A node's transmitter on one link: (node, link name; None in a mission of one link)."""

DECODED_KEPT = 64
"""Frames whose decoding the receivers share at a time (a frame's receptions end within
a few seconds of each other)."""


class SharedDecoder:
    """Decodes each frame once for all its receivers, for missions without authentication
    (decoding is then a pure function of the bytes and the sender). Receivers share the
    decoded values, as they share the frame's bytes: read-only. :meth:`fingerprint` shares
    the frame's sender fingerprint (a function of the bytes) the same way."""

    def __init__(self, decode: Callable[..., DecodedFrame],
                 fingerprint: Callable[[bytes], int | None] | None = None) -> None:
        self._decode = decode
        self._fingerprint = fingerprint
        self._kept: dict[tuple[bytes, int | None], DecodedFrame | FrameError] = {}
        self._prints: dict[bytes, int | None] = {}

    def fingerprint(self, frame: bytes) -> int | None:
        """The codec's ``sender_fingerprint(frame)``, computed once per frame."""
        found = self._prints.get(frame, -1)  # (-1: not yet; a fingerprint is 16 bits or None)
        if found == -1:
            assert self._fingerprint is not None
            found = self._fingerprint(frame)
            if len(self._prints) >= DECODED_KEPT:
                self._prints.clear()
            self._prints[frame] = found
        return found

    def __call__(self, frame: bytes, src: int | None = None,
                 now: float | None = None, start: int = 0) -> DecodedFrame:
        key = (frame, src)
        done = self._kept.get(key)
        if done is None:
            try:
                done = self._decode(frame, src, start=start) if start else self._decode(frame, src)
            except FrameError as exc:
                done = exc
            if len(self._kept) >= DECODED_KEPT:
                self._kept.clear()
            self._kept[key] = done
        if isinstance(done, FrameError):
            raise FrameError(str(done), done.reason)
        return done


@direct_init
@dataclass(frozen=True, slots=True)
class Timed:
    """An output of ``node`` at virtual time ``time``."""

    time: float
    node: str
    output: Taken


class FastFleet:
    """Every node of a mission and the water between them, driven by a virtual clock."""

    def __init__(
        self,
        loaded: LoadedMission,
        *,
        seed: int = 0,
        loss: float | None = None,
        preset: Preset | None = None,
        start: float = 0.0,
        on_output: Callable[[Timed], None] | None = None,
        keep_outputs: bool = True,
        key: bytes | KeyRing | None = None,
        kinds: tuple[type, ...] = (Publish, Status, Event, Relay),
    ) -> None:
        """``keep_outputs`` false: outputs only go to ``on_output`` (long runs); ``kinds``:
        the output types kept and passed on (others are dropped unseen). ``key``: the frame
        key of an authenticated mission (default: the mission key if present, else a
        throwaway one, see :attr:`throwaway_key`)."""
        mission = loaded.mission
        self.key, self.throwaway_key = key, False
        if key is None and mission.wire.auth is not None:
            self.key, self.throwaway_key = keys_for_run(mission.wire.auth)
        self.loaded = loaded
        self.mission = mission
        network = loaded.network
        waters = {None: water_of(loaded, seed, loss, preset)} if not network.several \
            else waters_of(loaded, seed, loss)
        self.oceans: dict[str | None, Ocean] = {}
        """The water of each link (one, None, in a mission of one link)."""
        self._names: dict[str | None, dict[int, str]] = {}
        self._addresses: dict[str | None, dict[str, int]] = {}
        for link, water in waters.items():
            info = network.links[0] if link is None else network.link(link)
            ocean = self.oceans[link] = Ocean(water.preset, water.seed, {
                address: water.positions.get(address, (0.0, 0.0, 0.0))
                for address in info.addresses.values()}, loss=water.loss)
            for address, path in water.paths.items():
                ocean.set_path(address, path, start)
            self._addresses[link] = dict(info.addresses)
            self._names[link] = {a: n for n, a in reversed(info.addresses.items())}
        self.ocean = next(iter(self.oceans.values()))
        """The first link's water."""
        self.ports: dict[str, tuple[Port, ...]] = {
            name: tuple((name, link) for link, a in self._addresses.items() if name in a)
            for name in mission.nodes}
        self.cores = {name: NodeCore(loaded, name, rng=random.Random(f"{seed}/{name}"),
                                     key=self.key, seed=seed, outputs=kinds)
                      for name in mission.nodes}
        self._shared: SharedDecoder | None = None
        if mission.wire.auth is None:  # every core's codec is the same pure function
            codec = next(iter(self.cores.values())).codec
            self._shared = SharedDecoder(codec.decode, codec.sender_fingerprint)
            for core in self.cores.values():
                self._share(core)
        self.now = start
        self.outputs: list[Timed] = []
        self.on_output = on_output
        self.keep_outputs = keep_outputs
        self.kinds = kinds
        self.stopped: set[str] = set()
        self.subscriptions: dict[str, list[str]] = {}
        self.queries = VirtualQueries(self)  # applications' gets and queryables
        self.seed = seed
        self.restarts = 0
        self.saved: dict[str, dict[str, Any]] = {}  # each node's saved state, as on its disk
        links = {link: i for i, link in enumerate(self.oceans)}
        self._order = {(name, link): i * len(links) + links[link]
                       for i, name in enumerate(mission.nodes) for link in self.oceans}
        self._next_tx: dict[Port, float | None] = {}
        # every value _next_tx took, as (time, port order, port): stale ones leave lazily
        self._tx_heap: list[tuple[float, int, Port]] = []
        self._timers: list[tuple[float, int, Callable[[], None]]] = []
        self._seq = itertools.count()
        self._packer = msgpack.Packer(use_bin_type=True)
        for name in mission.nodes:
            self._interest(name)
            self._plan(name)
        self._next_tick = start
        self.surface = surface_script(loaded, start)  # scripted surfacings, from the paths
        self._ip: set[tuple[str, str]] = set()
        if self.surface is not None:
            self.call_at(start, self._surface_step)

    # -- scheduling application behaviour --------------------------------------------------------

    def call_at(self, t: float, fn: Callable[[], None]) -> None:
        """Run ``fn`` when the virtual clock reaches ``t``."""
        heapq.heappush(self._timers, (t, next(self._seq), fn))

    def put(self, node: str, key: str, value: Any, *, at: float | None = None,
            encoding: str = "application/msgpack", ref: str | None = None) -> None:
        """An application on ``node`` puts ``value`` on ``key`` (now, or at virtual time
        ``at``); ``ref`` is its correlation text, echoed in delivery reports."""
        if encoding == "json":
            data, enc = encode_payload(value, encoding)
        elif isinstance(value, bytes) and encoding != MSGPACK:  # encoded already (a picture)
            data, enc = value, encoding
        else:  # encode_payload's msgpack, by one packer for the run (one thread)
            data, enc = self._packer.pack(value), MSGPACK
        sample_key = None
        ros2 = self.cores[node].ros2_input(key)
        if ros2 is not None:  # a ROS 2 node: CDR on its exact rmw_zenoh key
            try:
                data, enc = ros2.encode(value, self.now), ""
            except EncodeError as exc:
                self.cores[node].drop_payload(key, str(exc), self.now)
                return
            sample_key = ros2.publisher_key(node)

        if at is None or at <= self.now:
            self._ingest(node, key, data, enc, ref, sample_key)
        else:
            self.call_at(at, lambda: self._ingest(node, key, data, enc, ref, sample_key))

    def _ingest(self, node: str, key: str, data: bytes, enc: str, ref: str | None,
                sample_key: str | None) -> None:
        """A sample :meth:`put` reaches ``node``'s bridge now."""
        if node in self.stopped:
            return
        core = self.cores[node]
        core.ingest(key, data, enc, self.now, ref, sample_key=sample_key)
        self._collect(node, core)
        self._replan(node, core)

    def subscribe(self, node: str, key: str) -> None:
        """An application on ``node`` subscribes to ``key`` (demand-driven missions: the
        channels whose outputs it meets become wanted there)."""
        self.subscriptions.setdefault(node, []).append(key)
        self._interest(node)

    def unsubscribe(self, node: str, key: str) -> None:
        """Undo one :meth:`subscribe` of ``key`` at ``node``."""
        self.subscriptions.get(node, []).remove(key)
        self._interest(node)

    def ip_link(self, a: str, b: str, up: bool) -> None:
        """Nodes ``a`` and ``b`` reach each other over IP (surfaced, ``up``) or no longer
        (dived): what their bridges learn from each other's liveliness token in Zenoh."""
        for x, y in ((a, b), (b, a)):
            self.cores[x].ip_reachable(y, up, self.now)
            self.collect_and_replan(x)

    def _surface_step(self) -> None:
        """Put the pairs the scripted surfacings join on the IP link, take the others off,
        and come back at the next surfacing or dive."""
        assert self.surface is not None
        now = self.surface.ip_pairs(self.now)
        for a, b in sorted(self._ip - now):
            self.ip_link(a, b, False)
        for a, b in sorted(now - self._ip):
            self.ip_link(a, b, True)
        self._ip = now
        if (at := self.surface.next_any(self.now)) is not None:
            self.call_at(at, self._surface_step)

    def _share(self, core: NodeCore) -> None:
        """``core`` decodes through the fleet's :class:`SharedDecoder`."""
        assert self._shared is not None
        core.codec.decode = self._shared  # type: ignore[method-assign]
        core.codec.sender_fingerprint = self._shared.fingerprint  # type: ignore[method-assign]

    def collect_and_replan(self, node: str) -> None:
        """Carry out ``node``'s outputs and plan its next transmission again."""
        core = self.cores[node]
        self._collect(node, core)
        self._replan(node, core)

    def _interest(self, node: str) -> None:
        core = self.cores[node]
        own = own_subscriptions(self.mission, [*core.bindings, *core.families.subscriptions()])
        if core.interest is not None and core.interest.set_local(
                wanted_by(self.loaded.table, node, [*own, *self.subscriptions.get(node, [])])):
            self._replan(node, core)

    def stop(self, node: str) -> None:
        """Silence ``node``: it neither sends nor hears from now on."""
        self.stopped.add(node)
        for port in self.ports[node]:
            self._set_next_tx(port, None)

    def resume(self, node: str) -> None:
        self.stopped.discard(node)
        self._plan(node)

    def restart(self, node: str, *, keep_state: bool = True) -> None:
        """``node`` is killed and starts again now: a new core from its last saved state
        (``keep_state``) or from nothing (its disk was lost), and a fresh MAC schedule."""
        self.restarts += 1
        state = self.saved.get(node) if keep_state else None
        self.cores[node] = NodeCore(self.loaded, node, state=state, key=self.key,
                                    rng=random.Random(f"{self.seed}/{node}/{self.restarts}"),
                                    seed=self.seed + self.restarts, outputs=self.kinds)
        if self._shared is not None:
            self._share(self.cores[node])
        self.stopped.discard(node)
        self._collect(node, self.cores[node])
        self._plan(node)

    def published(self, node: str, key: str | None = None) -> list[tuple[float, Publish]]:
        """What ``node`` published on application keys (optionally only ``key``)."""
        return [(t.time, t.output) for t in self.outputs
                if t.node == node and isinstance(t.output, Publish)
                and (key is None or t.output.key == key)]

    # -- the loop ------------------------------------------------------------------------------

    def run_until(self, t_end: float) -> None:
        """Advance the virtual clock to ``t_end``, handling every event on the way: at each
        step, in this order, what the water settles, the timers due, the transmissions due
        and the health tick (one loop, no call per step: an hour of 64 nodes is ~4·10^5)."""
        oceans, timers, next_tx = self.oceans, self._timers, self._next_tx
        single = self.ocean if len(oceans) == 1 else None
        while True:
            t = self._next_tick
            water = single.next_event_time() if single is not None else min(
                (w for o in oceans.values() if (w := o.next_event_time()) is not None),
                default=None)
            if water is not None and water < t:
                t = water
            if timers and timers[0][0] < t:
                t = timers[0][0]
            heap = self._tx_heap  # the earliest planned transmission (rebuilt now and then)
            while heap and next_tx.get(heap[0][2]) != heap[0][0]:
                heapq.heappop(heap)  # stale: the node's plan changed since
            if heap and heap[0][0] < t:
                t = heap[0][0]
            if t > t_end:
                self.now = t_end
                return
            if t > self.now:
                self.now = t
            now = self.now
            if water is not None and water <= now:
                if single is None:
                    self._carry_out(self._water_events(now))
                else:  # now's events, and the next ones while nothing else comes first
                    self._settle(single, t_end)
                    now = self.now
            while timers and timers[0][0] <= now:
                heapq.heappop(timers)[2]()
            if self._tx_heap and self._tx_heap[0][0] <= now:
                for name in self._due_transmitters(now):
                    self._transmit(name)
            if self._next_tick <= now:
                self._tick(now)

    def _settle(self, ocean: Ocean, t_end: float) -> None:
        """Carry out the events of a mission's only water up to now, then one time after
        another for as long as each comes before any timer, planned transmission (or a stale
        plan: :meth:`run_until` looks at those) and tick, and no later than ``t_end``: what
        :meth:`run_until` would do, one step per event, without looking at everything else at
        every step."""
        timers, link, deliver = self._timers, next(iter(self.oceans)), self._deliver
        while True:
            for event in ocean.advance(self.now):  # (:meth:`_carry_out`, inlined)
                if event.__class__ is Delivery:
                    deliver(event, link)
            water, heap = ocean.next_event_time(), self._tx_heap  # (a plan may rebuild the heap)
            if water is None or water > t_end or water >= self._next_tick \
                    or (timers and timers[0][0] <= water) or (heap and heap[0][0] <= water):
                return
            if water > self.now:
                self.now = water

    def _carry_out(self, events: Iterable[tuple[str | None, Any]]) -> None:
        """The water's events, each on its link: deliveries received (a transmission ending
        or a frame lost changes nothing here: the cores learn of neither from the water)."""
        for link, event in events:
            if event.__class__ is Delivery:
                self._deliver(event, link)

    def _water_events(self, now: float) -> Iterable[tuple[str | None, Any]]:
        """What every link's water settled up to ``now``, in time order (the ocean's clock
        moves when it is asked; a mission of one water: :meth:`_settle`)."""
        found = [(event.time, i, link, event) for i, (link, ocean) in
                 enumerate(self.oceans.items()) for event in ocean.advance(now)]
        found.sort(key=lambda e: (e[0], e[1]))
        return [(link, event) for _, _, link, event in found]

    def _set_next_tx(self, port: Port, t: float | None) -> None:
        self._next_tx[port] = t
        if t is not None:
            heapq.heappush(self._tx_heap, (t, self._order[port], port))
            if len(self._tx_heap) > 4 * len(self._order) + 64:  # mostly stale: rebuild
                self._tx_heap = [(at, self._order[p], p) for p, at in self._next_tx.items()
                                 if at is not None]
                heapq.heapify(self._tx_heap)

    def _due_transmitters(self, now: float) -> list[Port]:
        """Transmitters whose planned transmission is due at ``now``, in mission order."""
        heap, due = self._tx_heap, {}
        while heap and heap[0][0] <= now:
            t, order, port = heapq.heappop(heap)
            if self._next_tx.get(port) == t:
                due[order] = port
        return [due[k] for k in sorted(due)]

    def _tick(self, now: float) -> None:
        """Every running core's periodic work, and the next tick planned."""
        stopped, collect = self.stopped, self._collect
        for name, core in self.cores.items():
            if name not in stopped:
                core.tick(now)
                collect(name, core)
        self._next_tick = now + TICK_S

    def water_stats(self) -> dict[str, Any]:
        """The counters of every link's water (:func:`~bridge.sim.scenario.water_stats`)."""
        return water_stats({link: ocean.stats() for link, ocean in self.oceans.items()})

    @property
    def schedules(self) -> dict[str, Schedule]:
        """Each node's MAC schedule (owned by its core)."""
        return {name: core.schedule for name, core in self.cores.items()}

    def _plan(self, name: str) -> None:
        """When ``name`` next gets to transmit on each of its links: its MACs' next
        opportunities."""
        for port in self.ports[name]:
            self._plan_port(port)

    def _plan_port(self, port: Port) -> None:
        name, link = port
        if name in self.stopped:
            self._set_next_tx(port, None)
            return
        wake = self.cores[name].wake_at(self.now, link)
        busy = self.oceans[link].busy_until(self._addresses[link][name])  # a busy modem refuses
        self._set_next_tx(port, None if wake is None else max(wake, self.now, busy))

    def _replan(self, name: str, core: NodeCore) -> None:
        """New data or a reception may change the next opportunity of ``name``'s ``core`` (a
        poll, a ranging turn), unless the schedule is fixed (TDMA: time and own sends only)."""
        if len(self.ports[name]) > 1 or not core.schedule.fixed:
            self._plan(name)

    def _transmit(self, port: Port) -> None:
        """Carry out what a node's core does at this opportunity of one of its links, as its
        modem would (the simulated modem, like ``zab sim``'s, sends frames and does not
        range)."""
        name, link = port
        core, now, ocean = self.cores[name], self.now, self.oceans[link]
        action = core.act(now, now + ocean.preset.intrinsic_delay_s, link)
        if isinstance(action, SendFrame):
            out = action.frame
            try:
                end = ocean.transmit(now, self._addresses[link][name], out.data, out.dest)
            except TransmitRefused as exc:
                core.done(action, now, now, error=str(exc))
            else:
                core.done(action, now, end)
        elif action is not None:  # a ping: the simulated modem cannot
            core.done(action, now, now, error="the simulated modem does not ping")
        self._collect(name, core)
        if len(self.ports[name]) > 1:
            self._plan(name)  # (what is due on its other links changed too)
        else:
            self._plan_port(port)

    def _deliver(self, event: Delivery, link: str | None = None) -> None:
        name = self._names[link].get(event.dst)
        if name is None or name in self.stopped:
            return
        meta = event.meta  # (the delivery's own, made for it by the water)
        meta["start"] = event.start
        core, now = self.cores[name], self.now
        core.receive(Reception(event.data, event.src, event.end, meta), now, now, link)
        self._collect(name, core)
        self._replan(name, core)

    def _collect(self, name: str, core: NodeCore) -> None:
        """Carry out the outputs of ``name``'s ``core``."""
        if core.needs_save:  # what a real node writes to its state file before the outputs
            self.saved[name] = msgpack.unpackb(msgpack.packb(core.state(), use_bin_type=True),
                                               raw=False, strict_map_key=False)
            core.saved()
        outputs = core.take()
        if not outputs:
            return
        handle = self.queries.handle if core.queries is not None else None  # its query outputs
        kinds, keep, on_output, now = self.kinds, self.keep_outputs, self.on_output, self.now
        for output in outputs:
            if handle is not None:
                handle(name, output)
            if not isinstance(output, kinds):
                continue
            timed = Timed(now, name, output)
            if keep:
                self.outputs.append(timed)
            if on_output is not None:
                on_output(timed)
