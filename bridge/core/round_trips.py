"""The retransmission timer of a sender, from the round trips it measures (pure).

A mission's ``retry_s`` (or the default from the MACs and routes) is a worst case worked out
before the dive; what a frame really waits is only known at sea, and behind a relay it is
mostly queueing: a relay drains a fast link's traffic into a slow one's turns, so each
fragment in flight waits behind the ones sent before it, minutes on an acoustic hop. A timer
shorter than that sends again what is still queued, and the copies queue too.

:class:`RoundTrips` estimates the round trip from the acknowledgements as TCP does (RFC 6298:
a smoothed mean and mean deviation, samples only of what was sent once, Karn's rule) and
gives the wait before a retransmission: the estimate plus four deviations, never below the
mission's ``retry_s``, doubling with each copy, and never above the longest wait ``retry_s``
alone gives (:data:`~bridge.core.reliable.BACKOFF_CAP` times it).
"""

from __future__ import annotations

__all__ = ["BACKOFF_CAP", "RoundTrips", "retry_wait"]

BACKOFF_CAP = 4.0
"""A retransmission waits at most this many times the first wait."""


def retry_wait(retry_s: float, attempts: int) -> float:
    """How long to wait for an acknowledgement after the ``attempts``-th send: ``retry_s``,
    doubling with each attempt up to ``BACKOFF_CAP`` times it."""
    return retry_s * min(2.0 ** (attempts - 1), BACKOFF_CAP)

GAIN = 1 / 8
"""How far one sample moves the smoothed round trip (RFC 6298's alpha)."""
DEVIATION_GAIN = 1 / 4
"""How far one sample moves the mean deviation (RFC 6298's beta)."""
DEVIATIONS = 4
"""Deviations above the mean that a timer waits (RFC 6298's K)."""


class RoundTrips:
    """Smoothed round-trip time and the retransmission wait it gives."""

    __slots__ = ("ceiling", "deviation", "floor", "initial", "mean")

    def __init__(self, floor: float, ceiling: float, initial: float | None = None) -> None:
        """``initial``: the timeout before any sample (default ``floor``)."""
        self.floor = floor
        self.ceiling = ceiling
        self.initial = floor if initial is None else initial
        self.mean: float | None = None
        self.deviation = 0.0

    def sample(self, seconds: float) -> None:
        """A round trip measured: something sent once was acknowledged ``seconds`` later."""
        if self.mean is None:
            self.mean, self.deviation = seconds, seconds / 2
            return
        self.deviation += DEVIATION_GAIN * (abs(self.mean - seconds) - self.deviation)
        self.mean += GAIN * (seconds - self.mean)

    @property
    def timeout(self) -> float:
        """How long to wait for the acknowledgement of a first copy."""
        if self.mean is None:
            return self.initial
        return min(max(self.floor, self.mean + DEVIATIONS * self.deviation), self.ceiling)

    def wait(self, attempts: int) -> float:
        """How long to wait after the ``attempts``-th copy: :attr:`timeout`, doubling with
        each copy, never past the ceiling (the longest wait a worst-case ``retry_s`` gives)."""
        return min(retry_wait(self.timeout, attempts), self.ceiling)
