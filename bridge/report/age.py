"""Age of information, the one definition every runtime and report uses (pure).

The age of a channel at a receiver is the time since it last arrived there: a sawtooth that
drops to zero at each arrival. Its mean is the area under the sawtooth divided by the time
since the first arrival, computed exactly from the arrivals (not sampled).
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class AgeOfInformation:
    """Age of each channel at each receiver (time since it last arrived), exactly: the area
    under the sawtooth between arrivals, from the first arrival on."""

    first: dict[tuple[str, str], float] = field(default_factory=dict)
    last: dict[tuple[str, str], float] = field(default_factory=dict)
    area: dict[tuple[str, str], float] = field(default_factory=dict)
    worst: dict[tuple[str, str], float] = field(default_factory=dict)

    def arrived(self, channel: str, node: str, t: float) -> None:
        key = (channel, node)
        last = self.last.get(key)
        if last is not None:
            gap = t - last
            self.area[key] += gap * gap / 2
            if gap > self.worst[key]:
                self.worst[key] = gap
        else:
            self.first[key], self.area[key], self.worst[key] = t, 0.0, 0.0
        self.last[key] = t

    def summary(self, end: float) -> dict[str, dict[str, float]]:
        """Per channel over its receivers: mean and max age, seconds."""
        area: dict[str, float] = {}
        span: dict[str, float] = {}
        worst: dict[str, float] = {}
        for (channel, node), last in self.last.items():
            tail = end - last
            area[channel] = area.get(channel, 0.0) + self.area[(channel, node)] + tail * tail / 2
            span[channel] = span.get(channel, 0.0) + end - self.first[(channel, node)]
            worst[channel] = max(worst.get(channel, 0.0), self.worst[(channel, node)], tail)
        return {c: {"mean_s": round(area[c] / span[c], 3), "max_s": round(worst[c], 3)}
                for c in area if span[c] > 0}
