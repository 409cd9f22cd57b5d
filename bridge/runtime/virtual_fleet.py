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

from bridge.core.mac import schedule_for
from bridge.core.node import NodeCore, Notice, Output, Publish, Status
from bridge.core.positioning import simulated_preset
from bridge.errors import FrameError
from bridge.mission.loader import LoadedMission
from bridge.modems.base import Reception
from bridge.sim.ocean import Delivery, Ocean, TransmitRefused, TxDone
from bridge.sim.path import Path
from bridge.sim.presets import Preset
from bridge.wire.frame import DecodedFrame
from bridge.wire.payloads import encode_payload

TICK_S = 1.0

DECODED_KEPT = 64
"""Frames whose decoding the receivers share at a time (a frame's receptions end within
a few seconds of each other)."""


class SharedDecoder:
    """Decodes each frame once for all its receivers, for missions without authentication
    (decoding is then a pure function of the bytes and the sender). Receivers share the
    decoded values, as they share the frame's bytes: read-only."""

    def __init__(self, decode: Callable[[bytes, int | None], DecodedFrame]) -> None:
        self._decode = decode
        self._kept: dict[tuple[bytes, int | None], DecodedFrame | FrameError] = {}

    def __call__(self, frame: bytes, src: int | None = None) -> DecodedFrame:
        key = (frame, src)
        done = self._kept.get(key)
        if done is None:
            try:
                done = self._decode(frame, src)
            except FrameError as exc:
                done = exc
            if len(self._kept) >= DECODED_KEPT:
                self._kept.clear()
            self._kept[key] = done
        if isinstance(done, FrameError):
            raise FrameError(str(done), done.reason)
        return done


@dataclass(frozen=True, slots=True)
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
        kinds: tuple[type, ...] = (Publish, Status, Notice),
    ) -> None:
        """``keep_outputs`` false: outputs only go to ``on_output`` (long runs); ``kinds``:
        the output types kept and passed on (others are dropped unseen)."""
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
        if mission.wire.auth is None:  # every core's codec is the same pure function
            shared = SharedDecoder(next(iter(self.cores.values())).codec.decode)
            for core in self.cores.values():
                core.codec.decode = shared  # type: ignore[method-assign]
        self.schedules = {name: schedule_for(mission, name, seed=seed) for name in mission.nodes}
        self.now = start
        self.outputs: list[Timed] = []
        self.on_output = on_output
        self.keep_outputs = keep_outputs
        self.kinds = kinds
        self.stopped: set[str] = set()
        self._order = {name: i for i, name in enumerate(mission.nodes)}
        self._names = {node.address: name for name, node in reversed(mission.nodes.items())}
        self._addresses = {name: node.address for name, node in mission.nodes.items()}
        self._next_tx: dict[str, float | None] = {}
        # every value _next_tx took, as (time, node order, name): stale ones leave lazily
        self._tx_heap: list[tuple[float, int, str]] = []
        self._pending: dict[int, tuple[str, Any]] = {}
        self._timers: list[tuple[float, int, Callable[[], None]]] = []
        self._seq = itertools.count()
        for name in mission.nodes:
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

    def stop(self, node: str) -> None:
        """Silence ``node``: it neither sends nor hears from now on."""
        self.stopped.add(node)
        self._set_next_tx(node, None)

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
            t = self._next_tick
            if (water := self.ocean.next_event_time()) is not None and water < t:
                t = water
            if self._timers and self._timers[0][0] < t:
                t = self._timers[0][0]
            if (tx := self._next_transmit()) is not None and tx < t:
                t = tx
            if t > t_end:
                self.now = t_end
                return
            self.now = max(self.now, t)
            self._step()

    def _set_next_tx(self, name: str, t: float | None) -> None:
        self._next_tx[name] = t
        if t is not None:
            heapq.heappush(self._tx_heap, (t, self._order[name], name))
            if len(self._tx_heap) > 4 * len(self._order) + 64:  # mostly stale: rebuild
                self._tx_heap = [(at, self._order[n], n) for n, at in self._next_tx.items()
                                 if at is not None]
                heapq.heapify(self._tx_heap)

    def _next_transmit(self) -> float | None:
        """The earliest planned transmission (stale heap entries dropped on the way)."""
        heap = self._tx_heap
        while heap and self._next_tx.get(heap[0][2]) != heap[0][0]:
            heapq.heappop(heap)
        return heap[0][0] if heap else None

    def _due_transmitters(self, now: float) -> list[str]:
        """Nodes whose planned transmission is due at ``now``, in mission order."""
        heap, due = self._tx_heap, {}
        if not heap or heap[0][0] > now:
            return []
        while heap and heap[0][0] <= now:
            t, order, name = heapq.heappop(heap)
            if self._next_tx.get(name) == t:
                due[order] = name
        return [due[k] for k in sorted(due)]

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
        for name in self._due_transmitters(now):
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
            self._set_next_tx(name, None)
            return
        opp = self.schedules[name].next_opportunity(self.now, self.cores[name].next_due(self.now))
        busy = self.ocean.busy_until(self._addresses[name])  # a busy modem refuses
        self._set_next_tx(name, None if opp is None else max(opp.start, self.now, busy))

    def _replan(self, name: str) -> None:
        """New data or a reception may change the next opportunity (a poll, a ranging turn),
        unless the schedule is fixed (TDMA: time and own sends only)."""
        if not self.schedules[name].fixed:
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
                out = replace(out, dest=self._addresses[opp.poll])
            try:
                end = self.ocean.transmit(now, self._addresses[name], out.data, out.dest)
            except TransmitRefused as exc:
                core.frame_failed(out, str(exc), now)
                schedule.on_skipped(now)
            else:
                core.frame_sent(out, now)
                schedule.on_sent(now, end)
            self._collect(name)
        self._plan(name)

    def _deliver(self, event: Delivery) -> None:
        name = self._names.get(event.dst)
        if name is None or name in self.stopped:
            return
        meta = {**event.meta, "start": event.start}
        core = self.cores[name]
        valid = core.stats.frames_received
        core.receive(Reception(event.data, event.src, event.end, meta), self.now, self.now)
        src = self._names.get(event.src)
        if core.stats.frames_received > valid and src is not None:  # a valid frame: tell the MAC
            self.schedules[name].on_heard(src, event.meta.get("dest") == event.dst, event.end)
        self._collect(name)
        self._replan(name)

    def _collect(self, name: str) -> None:
        for output in self.cores[name].take():
            if not isinstance(output, self.kinds):
                continue
            timed = Timed(self.now, name, output)
            if self.keep_outputs:
                self.outputs.append(timed)
            if self.on_output is not None:
                self.on_output(timed)
