"""A fake-clock driver: MAC schedules taking turns in the pure simulated ocean (no cores).

Each node sends frames of a fixed size; a frame's first byte says whom it polls (0 = nobody).
The loop jumps from one event (an opportunity starting, a reception ending) to the next, so a
long run takes milliseconds and the outcome depends only on the seeds.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from bridge.core.mac import Schedule
from bridge.mission.presets import Preset
from bridge.sim.ocean import Delivery, Loss, Ocean, Position, TransmitRefused


@dataclass
class Sent:
    node: str
    start: float
    end: float
    kind: str
    poll: str | None


@dataclass
class Medium:
    """Nodes (name → address, position) with their schedules and frame sizes."""

    preset: Preset
    nodes: Mapping[str, tuple[int, Position]]
    schedules: Mapping[str, Schedule]
    frame_bytes: Mapping[str, int]
    has_data: Mapping[str, bool] = field(default_factory=dict)
    seed: int = 0
    sent: list[Sent] = field(default_factory=list)
    heard: list[tuple[str, str, float]] = field(default_factory=list)
    lost: list[tuple[str, str, str, float]] = field(default_factory=list)
    refused: int = 0

    def __post_init__(self) -> None:
        self.ocean = Ocean(self.preset, self.seed, {a: p for a, p in self.nodes.values()})
        self._names = {a: n for n, (a, _) in self.nodes.items()}
        self._ids = {n: i + 1 for i, n in enumerate(self.nodes)}
        self._by_id = {i: n for n, i in self._ids.items()}

    def _due(self, name: str) -> float | None:
        return 0.0 if self.has_data.get(name, False) else None

    def run(self, t_end: float, start: float = 0.0) -> None:
        now = start
        while True:
            times = []
            for name, schedule in self.schedules.items():
                opp = schedule.next_opportunity(now, self._due(name))
                if opp is not None:
                    times.append(max(opp.start, now))
            if (t := self.ocean.next_event_time()) is not None:
                times.append(t)
            if not times or min(times) > t_end:
                return
            now = min(times)
            for event in self.ocean.advance(now):
                if isinstance(event, Delivery):
                    dst, src = self._names[event.dst], self._names[event.src]
                    polled = self._by_id.get(event.data[0])
                    self.heard.append((src, dst, event.end))
                    self.schedules[dst].on_heard(src, polled == dst, event.end)
                elif isinstance(event, Loss):
                    self.lost.append((self._names[event.src], self._names[event.dst],
                                      event.reason, event.time))
            for name, schedule in self.schedules.items():
                opp = schedule.next_opportunity(now, self._due(name))
                if opp is None or opp.start > now:
                    continue
                if not (opp.must_send or self.has_data.get(name, False)):
                    schedule.on_skipped(now)
                    continue
                data = bytes([self._ids.get(opp.poll, 0) if opp.poll else 0])
                data += bytes(self.frame_bytes[name] - 1)
                try:
                    end = self.ocean.transmit(now, self.nodes[name][0], data)
                except TransmitRefused:
                    self.refused += 1
                    schedule.on_skipped(now)
                    continue
                schedule.on_sent(now, end)
                self.sent.append(Sent(name, now, end, opp.kind, opp.poll))

    def collisions(self) -> int:
        return sum(1 for *_, reason, _ in self.lost if reason in ("collision", "half_duplex"))
