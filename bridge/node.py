"""The bridge runtime of one node: Zenoh sample → store → frame → MAC slot → modem, and back.

Asyncio adapter around the pure core. Zenoh callbacks run on Zenoh's own threads; they only
hand samples to the event loop (``call_soon_threadsafe``), so nothing here blocks Zenoh.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import msgpack
import zenoh

from bridge.auth import Authenticator, load_key
from bridge.backends.base import ModemBackend, Reception
from bridge.builder import plan_frame
from bridge.channels import ChannelCodec, ElementCodec
from bridge.errors import BackendError, DecodeError, EncodeError, FrameError
from bridge.frame import FrameCodec
from bridge.link import LinkState, LinkThresholds
from bridge.mac import FreeSchedule, TdmaSchedule, schedule_for
from bridge.mission_loader import LoadedMission
from bridge.payloads import decode_payload, encode_payload
from bridge.positioning import Positioning
from bridge.store import OutboundStore
from bridge.zenoh_session import close_quietly, is_bridged, open_session, origin_tag

log = logging.getLogger("zab.node")

STATS_PERIOD_S = 1.0
RETRY_MIN_S, RETRY_MAX_S = 0.5, 10.0
TX_LEAD_S = 0.01  # how far ahead a timed emission is scheduled


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


class BridgeNode:
    """Everything one vehicle runs: its Zenoh session, store, MAC loop and modem."""

    def __init__(
        self,
        loaded: LoadedMission,
        node: str,
        make_backend: Callable[[], ModemBackend],
        *,
        clock: Callable[[], float] = time.time,
        on_event: Callable[[str, dict[str, Any]], None] | None = None,
    ) -> None:
        if node not in loaded.mission.nodes:
            raise ValueError(f"node {node!r} is not in mission {loaded.mission.mission!r}")
        self.mission = loaded.mission
        self.table = loaded.table
        self.node = node
        self._make_backend = make_backend
        self.backend: ModemBackend | None = None
        self.clock = clock
        self.on_event = on_event or (lambda kind, info: None)
        auth = self.mission.wire.auth
        self.codec = FrameCodec(self.table, auth and Authenticator(
            load_key(auth.key_env, auth.key_file), self.table.fingerprint,
            self.mission.address_of(node), auth.tag_bytes))
        self.frame_bytes = self.mission.node_modem(node).frame_bytes
        self.schedule = schedule_for(self.mission, node)
        self.store = OutboundStore.for_node(self.table.channels, node)
        self.stats = NodeStats()
        self.thresholds = LinkThresholds.for_mission(self.mission)
        self.heartbeat_s = self.mission.link.heartbeat_s
        self.link_states: dict[str, LinkState] = {}
        self._tokens: dict[str, Any] = {}
        self._last_tx: float | None = None
        self.last_heard: dict[str, float] = {}
        self.positioning = Positioning(self.mission, node) if self.table.dlbl else None
        self.received_at: dict[str, float] = {}
        self.prefix = f"@zab/{self.mission.mission}/{node}"
        self._origin = origin_tag(self.mission.mission, node)
        self._bindings: dict[str, list[tuple[ChannelCodec, int, ElementCodec]]] = {}
        for channel in self.table.channels:
            if channel.index in self.store.states:
                for i, element in enumerate(channel.elements):
                    key = element.input_key(node)
                    self._bindings.setdefault(key, []).append((channel, i, element))
        self._warned_keys: set[str] = set()
        self._latest: dict[str, tuple[bytes, str]] = {}
        self._latched_keys: set[str] = set()
        self._publishers: dict[str, Any] = {}
        self._queryables: list[Any] = []
        self._data = asyncio.Event()
        self._modem_up = asyncio.Event()
        self.started = asyncio.Event()
        self.session: zenoh.Session | None = None

    # -- lifecycle ---------------------------------------------------------------------------

    async def run(self, stop: asyncio.Event) -> None:
        """Run until ``stop`` is set; always closes the session and the modem."""
        loop = asyncio.get_running_loop()
        self.session = open_session(self.mission.nodes[self.node].zenoh)
        try:
            for key in self._bindings:
                self.session.declare_subscriber(
                    key, lambda s, k=key: self._from_zenoh(loop, k, s)
                )
            self._subscribe_positions(loop)
            tasks = [
                asyncio.create_task(self._modem_loop(), name=f"{self.node}-modem"),
                asyncio.create_task(self._transmit_loop(), name=f"{self.node}-tx"),
                asyncio.create_task(self._stats_loop(), name=f"{self.node}-stats"),
                asyncio.create_task(self._health_loop(), name=f"{self.node}-health"),
            ]
            self.started.set()
            await stop.wait()
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
        finally:
            if self.backend is not None:
                await self.backend.close()
            close_quietly(self.session)

    # -- Zenoh → store -----------------------------------------------------------------------

    def _from_zenoh(
        self,
        loop: asyncio.AbstractEventLoop,
        key: str,
        sample: zenoh.Sample,
    ) -> None:
        """Zenoh thread: copy what we need and hand it to the loop."""
        if sample.kind != zenoh.SampleKind.PUT or is_bridged(sample):
            return
        data, encoding = sample.payload.to_bytes(), str(sample.encoding)
        loop.call_soon_threadsafe(self.ingest, key, data, encoding)

    def _subscribe_positions(self, loop: asyncio.AbstractEventLoop) -> None:
        """Live positions: this node's own (``nav_key``), anchors' and the CTD's."""
        assert self.session is not None

        def listen(key: str, handler: Callable[[str, tuple[float, ...]], None],
                   names: tuple[str, ...], bridged: bool = False) -> None:
            def on_sample(sample: zenoh.Sample) -> None:
                if sample.kind == zenoh.SampleKind.PUT and (bridged or not is_bridged(sample)):
                    data, encoding = sample.payload.to_bytes(), str(sample.encoding)
                    loop.call_soon_threadsafe(self._numbers, key, data, encoding, names, handler)

            self.session.declare_subscriber(key, on_sample)  # type: ignore[union-attr]

        nav_key = self.mission.nodes[self.node].nav_key
        if nav_key is not None:
            listen(nav_key, self.move, ("x", "y", "depth"))
        if self.positioning is None:
            return
        positioning = self.positioning
        for anchor, key in self.mission.ranging.anchor_keys.items():
            if anchor in positioning.anchors:
                listen(key, lambda _k, v, a=anchor: positioning.set_anchor(a, v),  # type: ignore[misc]
                       ("x", "y", "depth"), bridged=True)
        ctd_key = self.mission.ranging.ctd_key
        if ctd_key is not None:
            listen(ctd_key, lambda _k, v: positioning.set_water(*v),
                   ("temperature_c", "salinity_psu", "depth_m"), bridged=True)

    def _numbers(self, key: str, data: bytes, encoding: str, names: tuple[str, ...],
                 handler: Callable[[str, tuple[float, ...]], None]) -> None:
        """Decode a payload holding the numbers ``names`` and pass them on; count bad ones."""
        try:
            value = decode_payload(data, encoding)
            numbers = tuple(float(value[k]) for k in names)
            if not all(map(math.isfinite, numbers)):
                raise ValueError("not finite")
            handler(key, numbers)
        except (DecodeError, TypeError, KeyError, ValueError) as exc:
            self._drop_payload(key, f"needs numbers {', '.join(names)}: {exc}")

    def move(self, key: str, position: tuple[float, ...]) -> None:
        """This node's live position: move the (simulated) modem and keep the depth."""
        x, y, depth = position
        if self.backend is not None:
            self.backend.set_position(x, y, depth)
        if self.positioning is not None:
            self.positioning.set_depth(depth)

    def ingest(self, key: str, data: bytes, encoding: str) -> None:
        """A sample arrived on an input key: pack it for every channel that reads the key."""
        now = self.clock()
        try:
            value = decode_payload(data, encoding)
        except DecodeError as exc:
            self._drop_payload(key, str(exc))
            return
        for channel, index, element in self._bindings.get(key, ()):
            try:
                packed = element.layout.pack(value)
            except EncodeError as exc:
                self._drop_payload(key, f"channel {channel.name!r}: {exc}")
                continue
            self.store.update(channel.index, index, packed, now)
        self._data.set()

    def _drop_payload(self, key: str, reason: str) -> None:
        self.stats.payloads_dropped[key] += 1
        if key not in self._warned_keys:
            self._warned_keys.add(key)
            log.warning("%s: dropped a payload on %r: %s (counted; warned once)",
                        self.node, key, reason)
        self.on_event("payload_dropped", {"key": key, "reason": reason})

    # -- store → modem -------------------------------------------------------------------------

    async def _sleep_until(self, t: float) -> None:
        delay = t - self.clock()
        if delay > 0:
            await asyncio.sleep(delay)

    async def _transmit_loop(self) -> None:
        after = self.clock()
        last_start: float | None = None
        while True:
            await self._modem_up.wait()
            if isinstance(self.schedule, TdmaSchedule):
                slot = self.schedule.next_slot(after)
                if slot is None:
                    return  # this node owns no slot: it only listens
                await self._sleep_until(slot.start)
                after = slot.start
                await self.transmit(always=self.table.dlbl or self._heartbeat_due(slot.start))
                continue
            assert isinstance(self.schedule, FreeSchedule)
            due = min((t for t in (self.store.next_due(), self._next_heartbeat()) if t is not None),
                      default=None)
            if due is None:
                self._data.clear()
                await self._data.wait()
                continue
            now = self.clock()
            start = max(self.schedule.earliest(now, last_start), due)
            if start > now:
                self._data.clear()
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self._data.wait(), start - now)
                continue
            last_start = now
            await self.transmit(always=self._heartbeat_due(now))

    def _next_heartbeat(self) -> float | None:
        if self.heartbeat_s is None:
            return None
        return float("-inf") if self._last_tx is None else self._last_tx + self.heartbeat_s

    def _heartbeat_due(self, now: float) -> bool:
        beat = self._next_heartbeat()
        return beat is not None and beat <= now + 1e-9

    async def transmit(self, *, always: bool = False) -> bool:
        """Build one frame from what is due and send it. Returns whether a frame went out."""
        now = self.clock()
        plan = plan_frame(self.codec, self.store.due(now), self.frame_bytes)
        self.stats.left_out += len(plan.left_out)
        if not plan.chosen and not always:
            return False
        backend = self.backend
        if backend is None:
            return False
        # with a timed modem the emission starts exactly at t_tx, so DLBL delays are exact
        t_tx = backend.clock() + (TX_LEAD_S if backend.timed_send else 0.0)
        delays = self.positioning.on_transmit(t_tx) if self.positioning else []
        frame = self.codec.encode([(s.channel, s.payload()) for s in plan.chosen], delays, now)
        targets = {d for s in plan.chosen for d in s.channel.destinations(self.node)}
        dest = self.mission.address_of(next(iter(targets))) if len(targets) == 1 else None
        try:
            ack = True if dest is not None and any(s.channel.ack for s in plan.chosen) else None
            await backend.send(frame, dest, at=t_tx, ack=ack)
        except BackendError as exc:
            if self.positioning is not None:
                self.positioning.forget_transmit(t_tx)
            self.stats.send_errors += 1
            log.warning("%s: send failed: %s", self.node, exc)
            self.on_event("send_failed", {"error": str(exc)})
            if not backend.is_open:  # the modem is gone: wait until the modem loop reopens it
                self._modem_up.clear()
            return False
        self.store.mark_sent(plan.chosen, now)
        self._last_tx = now
        self.stats.frames_sent += 1
        for state in plan.chosen:
            self.stats.sent_per_channel[state.channel.name] += 1
        self.on_event("frame_sent", {"bytes": len(frame), "channels": [
            s.channel.name for s in plan.chosen], "time": now})
        return True

    # -- modem → Zenoh -------------------------------------------------------------------------

    async def _modem_loop(self) -> None:
        """Open the modem, read receptions; on failure, open a fresh one with backoff."""
        backoff = RETRY_MIN_S
        while True:
            backend = self.backend = self._make_backend()
            try:
                await backend.open()
                self._modem_up.set()
                backoff = RETRY_MIN_S
                while True:
                    self.receive(await backend.recv())
            except BackendError as exc:
                self._modem_up.clear()
                log.warning("%s: modem unavailable: %s (retry in %.1f s)", self.node, exc, backoff)
                self.on_event("modem_down", {"error": str(exc)})
                await backend.close()
                await asyncio.sleep(backoff)
                backoff = min(backoff * 2, RETRY_MAX_S)

    def receive(self, rx: Reception) -> None:
        """Decode one received frame and publish what it carries for this node."""
        src = self.mission.name_of(rx.src)
        if src is None or src == self.node:
            self.stats.frames_dropped["unknown_source"] += 1
            return
        try:
            frame = self.codec.decode(rx.data, rx.src)
        except FrameError as exc:
            self.stats.frames_dropped[exc.reason] += 1
            self.on_event("frame_dropped", {"src": src, "reason": str(exc)})
            return
        self.stats.frames_received += 1
        now = self.clock()
        self.last_heard[src] = now
        if self.link_states.get(src) is not LinkState.UP:
            self.update_links(now)
        if self.positioning is not None and self.backend is not None:
            self._ranging(src, float(rx.meta.get("start", rx.time)), frame.delays)
        for channel, values in frame.channels:
            if src not in channel.senders:
                self.stats.frames_dropped["unexpected_sender"] += 1
                continue
            if self.node not in channel.destinations(src):
                continue  # overheard: addressed to others
            self.stats.received_per_channel[channel.name] += 1
            self.received_at[channel.name] = now
            for element, value in zip(channel.elements, values, strict=True):
                key = element.output_key(src, self.node)
                self.publish(key, value, element.encoding, latched=channel.latching)
        self._publish_raw(f"{self.prefix}/peers/{src}",
                          {"last_heard": now, "meta": _plain(rx.meta)})
        self.on_event("frame_received", {"src": src, "bytes": len(rx.data), "channels": [
            c.name for c, _ in frame.channels], "time": now})

    def _ranging(self, src: str, t_rx_start: float, delays: tuple[int | None, ...]) -> None:
        """Ranges (and a fix) from a frame's DLBL delays, published under ``@zab``."""
        assert self.positioning is not None and self.backend is not None
        update = self.positioning.on_receive(src, t_rx_start, delays, self.backend.clock())
        wall = self.clock()
        for rng in update.ranges:
            payload = {**self.positioning.range_payload(rng), "time": wall}
            self._publish_raw(f"{self.prefix}/range/{rng.peer}", payload)
            self.on_event("range", payload)
        if update.fix is not None:
            payload = update.fix.payload(wall)
            self._publish_raw(f"{self.prefix}/position", payload)
            self.on_event("position", payload)

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
        self.stats.values_published += 1

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
        now = self.clock()
        ages = {s.channel.name: s.age(now) for s in self.store.states.values()}
        return {
            "node": self.node,
            "time": now,
            "frames_sent": self.stats.frames_sent,
            "frames_received": self.stats.frames_received,
            "frames_dropped": dict(self.stats.frames_dropped),
            "payloads_dropped": dict(self.stats.payloads_dropped),
            "values_published": self.stats.values_published,
            "send_errors": self.stats.send_errors,
            "left_out": self.stats.left_out,
            "channel_age_s": ages,
            "received_age_s": {k: now - t for k, t in self.received_at.items()},
            "last_heard": dict(self.last_heard),
            "links": {peer: state.value for peer, state in self.link_states.items()},
        }

    def update_links(self, now: float) -> None:
        """Re-evaluate every peer's link; publish changes and keep one liveliness token per
        live link under ``@zab/<mission>/<node>/link/<peer>``."""
        assert self.session is not None
        for peer in self.table.foreign_nodes(self.node):
            heard = self.last_heard.get(peer)
            state = self.thresholds.state(heard, now)
            if self.link_states.get(peer) is state:
                continue
            self.link_states[peer] = state
            key = f"{self.prefix}/link/{peer}"
            self._publish_raw(key, {"peer": peer, "state": state.value, "last_heard": heard,
                                    "silent_s": None if heard is None else now - heard})
            self.on_event("link", {"peer": peer, "state": state.value})
            token = self._tokens.get(peer)
            if state is LinkState.DOWN and token is not None:
                token.undeclare()
                del self._tokens[peer]
            elif state is not LinkState.DOWN and token is None:
                self._tokens[peer] = self.session.liveliness().declare_token(key)

    async def _health_loop(self) -> None:
        period = min(1.0, self.thresholds.degraded_after_s / 4)
        while True:
            self.update_links(self.clock())
            await asyncio.sleep(period)

    async def _stats_loop(self) -> None:
        while True:
            await asyncio.sleep(STATS_PERIOD_S)
            self._publish_raw(f"{self.prefix}/stats", self.snapshot())


def _plain(meta: Any) -> dict[str, Any]:
    """Link metadata reduced to msgpack-able scalars."""
    return {str(k): v for k, v in dict(meta).items()
            if isinstance(v, int | float | str | bool) or v is None}
