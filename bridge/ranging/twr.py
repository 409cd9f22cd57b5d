"""Explicit two-way ranging and seed 001's scheduled anchor replies, pure and clock-free.

A requester sends a packet with the ranging flag at ``t_tx`` (its clock). Each responder notes
its processing time ``Tp`` (request reception to reply transmission, its clock) and sends it
in the reply; the requester receives the reply at ``t_rx`` (its clock), so the one-way travel
time is ``Tw = (t_rx − t_tx − Tp) / 2`` (seed 001 eq. 1) and the distance ``d = c·Tw`` (eq. 2).
Both ends must timestamp the same point of a packet (start, or end, of the signal).

With several anchors (seed 001 section III-B), anchors answer one request in order: anchor 0
at once, anchor ``i`` as soon as it hears anchor ``i − 1``'s reply, or at the latest ``tmax``
after the previous anchor's deadline; a round ends when every reply is in or ``(n + 1)·tmax``
after the request. :class:`AnchorReplier` runs an anchor's side and :class:`RangingRound` the
requester's; both take times as arguments and report deadlines, the caller sleeps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from bridge.ranging.dlbl import Range


def travel_time(t_tx: float, t_rx: float, t_processing: float) -> float:
    """One-way travel time ``(t_rx − t_tx − t_processing) / 2`` in seconds (seed 001 eq. 1)."""
    return (t_rx - t_tx - t_processing) / 2.0


def tmax(d_max: float, c: float, packet_bytes: int, bitrate: float, guard_s: float = 0.0) -> float:
    """Seed 001 eq. 6: ``tmax = d_max / c + l / R`` (+ a guard), in seconds.

    ``l`` is the reply length in bits (``8·packet_bytes``) and ``R`` the bit rate. Take ``c``
    as the slowest sound speed expected. Note: with the paper's own numbers (150 m, 1400 m/s,
    15 B, 266 bit/s) eq. 6 gives 0.56 s while the paper quotes 1.06 s; pass ``guard_s`` for
    modem turnaround and clock slack.
    """
    if d_max < 0 or c <= 0 or packet_bytes < 0 or bitrate <= 0:
        raise ValueError("tmax needs d_max ≥ 0, c > 0, packet_bytes ≥ 0 and bitrate > 0")
    return d_max / c + 8.0 * packet_bytes / bitrate + guard_s


def reply_slot(anchor_index: int, tmax_s: float) -> float:
    """Latest reply time of anchor ``anchor_index`` (0-based) after it heard the request.

    Anchor 0 replies at once; anchor ``i`` at ``i·tmax`` if it heard no earlier reply.
    """
    if anchor_index < 0:
        raise ValueError("anchor_index must be ≥ 0")
    return anchor_index * tmax_s


def round_timeout(n_anchors: int, tmax_s: float) -> float:
    """How long after its request a requester waits for ``n_anchors`` replies: ``(n+1)·tmax``."""
    return (n_anchors + 1) * tmax_s


@dataclass
class AnchorReplier:
    """One anchor's side of a ranging round: when to send its reply.

    Call :meth:`on_request` when the flagged request arrives, :meth:`on_reply_heard` for each
    earlier anchor's reply overheard (at the end of its reception), and transmit when
    :meth:`due` says so (or sleep until :attr:`deadline`). :meth:`processing_time` gives the
    ``Tp`` to put in the reply.
    """

    index: int
    tmax_s: float
    request_rx: float | None = None
    deadline: float | None = None
    sent: bool = False

    def on_request(self, t_rx: float) -> float:
        """A ranging request arrived at ``t_rx``: start a round; return the reply deadline."""
        self.request_rx, self.sent = t_rx, False
        self.deadline = t_rx + reply_slot(self.index, self.tmax_s)
        return self.deadline

    def on_reply_heard(self, anchor_index: int, t_end: float) -> float | None:
        """Anchor ``anchor_index``'s reply ended at ``t_end``: move the deadline earlier.

        Hearing anchor ``j < index`` means anchor ``index`` is at most ``index − 1 − j``
        timeouts away; hearing the previous anchor means reply now.
        """
        if self.deadline is None or self.sent or not 0 <= anchor_index < self.index:
            return self.deadline
        self.deadline = min(self.deadline, t_end + (self.index - 1 - anchor_index) * self.tmax_s)
        return self.deadline

    def due(self, now: float) -> bool:
        """Whether the reply should go out at ``now``."""
        return self.deadline is not None and not self.sent and now >= self.deadline

    def processing_time(self, t_tx: float) -> float:
        """Mark the reply sent at ``t_tx``; return ``Tp = t_tx − request reception``."""
        if self.request_rx is None:
            raise ValueError("no ranging request to reply to")
        self.sent = True
        return t_tx - self.request_rx


@dataclass
class RangingRound:
    """The requester's side of one round: collects replies into :class:`Range` values."""

    t_tx: float
    anchors: tuple[str, ...]
    tmax_s: float
    max_travel_s: float = math.inf
    ranges: dict[str, Range] = field(default_factory=dict)
    rejected: int = 0

    @property
    def deadline(self) -> float:
        """When the round ends even if replies are missing."""
        return self.t_tx + round_timeout(len(self.anchors), self.tmax_s)

    def on_reply(self, anchor: str, t_rx: float, t_processing: float) -> Range | None:
        """A reply from ``anchor`` arrived at ``t_rx`` carrying its ``Tp``: its range, or None."""
        if anchor not in self.anchors or anchor in self.ranges or t_rx > self.deadline:
            self.rejected += 1
            return None
        tw = travel_time(self.t_tx, t_rx, t_processing)
        if not 0.0 <= tw <= self.max_travel_s:
            self.rejected += 1
            return None
        rng = Range(anchor, tw, "twr", t_rx, t_processing)
        self.ranges[anchor] = rng
        return rng

    def done(self, now: float) -> bool:
        """Whether every anchor replied or the round timed out."""
        return len(self.ranges) == len(self.anchors) or now >= self.deadline
