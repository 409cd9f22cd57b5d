"""The S2C's 32-bit microsecond clock as continuous seconds (sans-I/O: host times passed in).

Every modem timestamp (``SENDEND``, ``RECVEND``, ``RECVIMS``) and the send time of
``AT*SENDIMS`` is a 32-bit µs counter that wraps every ~71.6 min [V §1.9]. :class:`ModemClock`
maps counter values to seconds on one scale, anchored at the first reading so that it starts
near the host's clock; differences of modem times are then exact to the µs whatever the host
does (that is what DLBL needs). The host-to-modem offset is re-estimated at every reading
(:meth:`ModemClock.sync`, as far as the reading's round trip allows), only to tell "now" on the
modem clock (:meth:`ModemClock.now`) and to pick the right wrap of a counter value; it
follows host–modem drift without moving the scale.

Readings come from ``AT?CLOCK``. [U] ``modem-protocols.md`` lists ``AT?CLOCK`` as "uint system
clock (DUNE keep-alive)" without its unit: that it is the same µs counter as the timestamps and
the ``AT*SENDIMS`` time is an assumption to check on a real modem.
"""

from __future__ import annotations

import math

__all__ = ["WRAP_US", "ModemClock"]

WRAP_US = 1 << 32
"""The counter wraps modulo 2³² µs [V: 10-digit timestamps just under 2³² in BIR tests]."""


class ModemClock:
    """Counter values ↔ seconds, and the modem's "now" from the host clock."""

    def __init__(self) -> None:
        self._anchor: tuple[float, int] | None = None  # (seconds, unwrapped counter µs)
        self._offset = 0.0  # modem seconds minus host seconds
        self.readings = 0

    @property
    def synced(self) -> bool:
        """Whether a reading has anchored the scale."""
        return self._anchor is not None

    def sync(self, host_s: float, counter_us: int, uncertainty_s: float = 0.0) -> None:
        """A reading ``counter_us`` of the modem clock, taken at host time ``host_s`` give or
        take ``uncertainty_s`` (the query's round trip: the middle of it, ± half). The offset
        moves only as far as the reading proves it wrong: a slow round trip (a loaded host
        answering late) cannot drag a better estimate off by half its delay."""
        if not 0 <= counter_us < WRAP_US:
            raise ValueError(f"modem clock reading {counter_us} outside 0..2^32-1")
        if self._anchor is None:
            self._anchor = (host_s, counter_us)
            self._offset = 0.0
        else:
            measured = self.seconds(counter_us, self.now(host_s)) - host_s
            self._offset = min(max(self._offset, measured - uncertainty_s),
                               measured + uncertainty_s)
        self.readings += 1

    def now(self, host_s: float) -> float:
        """The modem clock, in seconds, at host time ``host_s``."""
        return host_s + self._offset

    def seconds(self, counter_us: int, near: float) -> float:
        """The time of counter value ``counter_us``, taking the wrap nearest to ``near`` (s)."""
        a_s, a_us = self._anchored()
        expected = a_us + (near - a_s) * 1e6
        wraps = round((expected - counter_us) / WRAP_US)
        return a_s + (counter_us + wraps * WRAP_US - a_us) * 1e-6

    def counter(self, seconds: float) -> int:
        """The counter value (µs, modulo 2³²) at ``seconds`` on this clock's scale."""
        if not math.isfinite(seconds):
            raise ValueError(f"not a time: {seconds}")
        a_s, a_us = self._anchored()
        return round(a_us + (seconds - a_s) * 1e6) % WRAP_US

    def _anchored(self) -> tuple[float, int]:
        if self._anchor is None:
            raise ValueError("the modem clock has not been read yet")
        return self._anchor
