"""A whole fleet on a virtual clock: every node's :class:`NodeCore` over the pure :class:`Ocean`.

No Zenoh, no sockets, no sleeping: a discrete-event loop jumps from one event to the next
(a MAC opportunity, a frame arriving, an application sample, a health tick), so an hour of
mission runs in seconds and the same seed gives the same run. Applications are played by
:meth:`FastFleet.put` (scheduled samples on input keys); what nodes publish is collected in
:attr:`FastFleet.outputs` and passed to ``on_output``.

Nodes with a scripted ``path`` follow it from the start time. What it leaves out compared with
``zab sim``: Zenoh itself (keys, latching queries), modem drivers, and clock offsets (every node
shares the virtual clock).
"""

from __future__ import annotations

import heapq
import itertools
import random
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

from bridge.core.interest import own_subscriptions, wanted_by
from bridge.core.mac import schedule_for
from bridge.core.node import NodeCore, Output, Publish
from bridge.core.positioning import simulated_preset
from bridge.mission.loader import LoadedMission
from bridge.modems.base import Reception
from bridge.runtime.virtual_queries import VirtualQueries
from bridge.sim.ocean import Delivery, Ocean, TransmitRefused, TxDone
from bridge.sim.path import Path
from bridge.sim.presets import Preset
from bridge.wire.payloads import encode_payload

TICK_S = 1.0


@dataclass(frozen=True)
class Timed:
    """An output of ``node`` at virtual time ``time``."""

    time: float
    node: str
    output: Output


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
    ) -> None:
        """``keep_outputs`` false: outputs only go to ``on_output`` (long runs)."""
        mission = loaded.mission
        self.loaded = loaded
        self.mission = mission
        options = mission.modem.options
        if preset is None:
            preset = simulated_preset(mission)
        self.ocean = Ocean(preset, seed, {
            node.address: (node.position.x, node.position.y, node.position.depth)
            if node.position is not None else (0.0, 0.0, 0.0)
            for node in mission.nodes.values()
        }, loss=float(options.get("loss", 0.0)) if loss is None else loss)
        for node in mission.nodes.values():
            if node.path is not None:
                self.ocean.set_path(node.address, Path.from_spec(node.path), start)
        self.cores = {name: NodeCore(loaded, name, rng=random.Random(f"{seed}/{name}"))
                      for name in mission.nodes}
        self.schedules = {name: schedule_for(mission, name, seed=seed) for name in mission.nodes}
        self.now = start
        self.outputs: list[Timed] = []
        self.on_output = on_output
        self.keep_outputs = keep_outputs
        self.stopped: set[str] = set()
        self.subscriptions: dict[str, list[str]] = {}
        self.queries = VirtualQueries(self)  # applications' gets and queryables
        self._next_tx: dict[str, float | None] = {}
        self._pending: dict[int, tuple[str, Any]] = {}
        self._timers: list[tuple[float, int, Callable[[], None]]] = []
        self._seq = itertools.count()
        for name in mission.nodes:
            self._interest(name)
            self._plan(name)
        self._next_tick = start

    # -- scheduling application behaviour --------------------------------------------------------

    def call_at(self, t: float, fn: Callable[[], None]) -> None:
        """Run ``fn`` when the virtual clock reaches ``t``."""
        heapq.heappush(self._timers, (t, next(self._seq), fn))

    def put(self, node: str, key: str, value: Any, *, at: float | None = None,
            encoding: str = "application/msgpack") -> None:
        """An application on ``node`` puts ``value`` on ``key`` (now, or at virtual time ``at``)."""
        data, enc = encode_payload(value, encoding)

        def deliver() -> None:
            if node in self.stopped:
                return
            self.cores[node].ingest(key, data, enc, self.now)
            self._collect(node)
            self._replan(node)

        if at is None or at <= self.now:
            deliver()
        else:
            self.call_at(at, deliver)

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

    def collect_and_replan(self, node: str) -> None:
        """Carry out ``node``'s outputs and plan its next transmission again."""
        self._collect(node)
        self._replan(node)

    def _interest(self, node: str) -> None:
        core = self.cores[node]
        own = own_subscriptions(self.mission, [*core.bindings, *core.families.subscriptions()])
        if core.interest is not None and core.interest.set_local(
                wanted_by(self.loaded.table, node, [*own, *self.subscriptions.get(node, [])])):
            self._replan(node)

    def stop(self, node: str) -> None:
        """Silence ``node``: it neither sends nor hears from now on."""
        self.stopped.add(node)
        self._next_tx[node] = None

    def resume(self, node: str) -> None:
        self.stopped.discard(node)
        self._plan(node)

    def published(self, node: str, key: str | None = None) -> list[tuple[float, Publish]]:
        """What ``node`` published on application keys (optionally only ``key``)."""
        return [(t.time, t.output) for t in self.outputs
                if t.node == node and isinstance(t.output, Publish)
                and (key is None or t.output.key == key)]

    # -- the loop ------------------------------------------------------------------------------

    def run_until(self, t_end: float) -> None:
        """Advance the virtual clock to ``t_end``, handling every event on the way."""
        while True:
            candidates = [self._next_tick]
            if (t := self.ocean.next_event_time()) is not None:
                candidates.append(t)
            if self._timers:
                candidates.append(self._timers[0][0])
            candidates.extend(t for t in self._next_tx.values() if t is not None)
            t = min(candidates)
            if t > t_end:
                self.now = t_end
                return
            self.now = max(self.now, t)
            self._step()

    def _step(self) -> None:
        now = self.now
        for event in self.ocean.advance(now):
            if isinstance(event, Delivery):
                self._deliver(event)
            elif isinstance(event, TxDone):
                self._pending.pop(event.frame_id, None)
        while self._timers and self._timers[0][0] <= now:
            _, _, fn = heapq.heappop(self._timers)
            fn()
        for name, t in list(self._next_tx.items()):
            if t is not None and t <= now:
                self._transmit(name)
        if self._next_tick <= now:
            for name, core in self.cores.items():
                if name not in self.stopped:
                    core.tick(now)
                    self._collect(name)
            self._next_tick = now + TICK_S

    def _plan(self, name: str) -> None:
        """When ``name`` next gets to transmit: its MAC's next opportunity."""
        if name in self.stopped:
            self._next_tx[name] = None
            return
        opp = self.schedules[name].next_opportunity(self.now, self.cores[name].next_due(self.now))
        busy = self.ocean.busy_until(self.mission.address_of(name))  # a busy modem refuses
        self._next_tx[name] = None if opp is None else max(opp.start, self.now, busy)

    def _replan(self, name: str) -> None:
        """New data or a reception may change the next opportunity (a poll, a ranging turn)."""
        self._plan(name)

    def _transmit(self, name: str) -> None:
        core, schedule, now = self.cores[name], self.schedules[name], self.now
        opp = schedule.next_opportunity(now, core.next_due(now))
        if opp is None or opp.start > now:
            self._plan(name)
            return
        at = now + self.ocean.preset.intrinsic_delay_s
        out = core.build_frame(now, at, always=opp.must_send or core.heartbeat_due(now))
        if out is None:
            schedule.on_skipped(now)
        else:
            if opp.poll is not None:  # the poll rides on the frame's destination address
                out = replace(out, dest=self.mission.address_of(opp.poll))
            try:
                end = self.ocean.transmit(now, self.mission.address_of(name), out.data, out.dest)
            except TransmitRefused as exc:
                core.frame_failed(out, str(exc), now)
                schedule.on_skipped(now)
            else:
                core.frame_sent(out, now)
                schedule.on_sent(now, end)
            self._collect(name)
        self._plan(name)

    def _deliver(self, event: Delivery) -> None:
        name = self.mission.name_of(event.dst)
        if name is None or name in self.stopped:
            return
        meta = {**event.meta, "start": event.start}
        core = self.cores[name]
        valid = core.stats.frames_received
        core.receive(Reception(event.data, event.src, event.end, meta), self.now, self.now)
        src = self.mission.name_of(event.src)
        if core.stats.frames_received > valid and src is not None:  # a valid frame: tell the MAC
            self.schedules[name].on_heard(src, event.meta.get("dest") == event.dst, event.end)
        self._collect(name)
        self._replan(name)

    def _collect(self, name: str) -> None:
        for output in self.cores[name].take():
            self.queries.handle(name, output)
            timed = Timed(self.now, name, output)
            if self.keep_outputs:
                self.outputs.append(timed)
            if self.on_output is not None:
                self.on_output(timed)
