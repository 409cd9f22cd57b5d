"""What every MAC has: opportunities, one node's :class:`Schedule`, and the mission-level
rules of its kind (:class:`Mac`) (pure, time passed in)."""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Iterable
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, ClassVar

from bridge.frozen import direct_init
from bridge.mission.model import Mission

__all__ = ["EPS", "LATE_S", "Loc", "Mac", "MacReport", "Opportunity", "OpportunityKind",
           "Schedule", "airtime_share"]

LATE_S = 0.05
"""How long a TDMA slot start stays usable for an adapter that woke late, seconds."""

EPS = 1e-9

DEFAULT_RETRY_S = 10.0
"""A reliable value's first retransmission without a MAC cycle to follow."""

FREE_HEARTBEAT_S = 10.0
"""How often a node sends at least a frame under random access, by default."""

Loc = tuple[str | int, ...]
"""Where a problem is in the mission file (a field path)."""


class OpportunityKind(StrEnum):
    """Why an opportunity is offered."""

    SLOT = "slot"
    DUE = "due"
    POLL = "poll"
    REPLY = "reply"
    RANGING_REQUEST = "ranging_request"
    RANGING_REPLY = "ranging_reply"


@direct_init
@dataclass(frozen=True)
class Opportunity:
    """A transmit opportunity: start at ``start`` (now if already past), never after ``latest``;
    ``until``: the end of the turn it grants (a TDMA slot's end): the modem begins no
    transmission of its frame from then on, neither the first try nor a retry (inf: no end,
    under random access)."""

    start: float
    latest: float = math.inf
    must_send: bool = False
    poll: str | None = None
    kind: OpportunityKind = OpportunityKind.DUE
    until: float = math.inf


class Schedule(ABC):
    """One node's view of a MAC (see :mod:`bridge.core.mac`)."""

    fixed: ClassVar[bool] = False
    """True when opportunities depend only on time and this node's own sends, never on what
    it hears or has due: a driver need not re-plan after a reception."""

    @abstractmethod
    def next_opportunity(self, now: float, due: float | None) -> Opportunity | None:
        """The next opportunity not yet used, or None (wait for data or a reception)."""

    def on_sent(self, start: float, end: float) -> None:  # noqa: B027 - optional hook
        """A frame started at ``start``; the modem was done at ``end``."""

    def on_skipped(self, now: float) -> None:  # noqa: B027 - optional hook
        """The opportunity offered before ``now`` passed without a frame."""

    def on_heard(self, src: str, polled_me: bool, end: float) -> None:  # noqa: B027
        """A valid frame from ``src`` ended at ``end``; ``polled_me``: it polls this node."""


@dataclass(frozen=True)
class MacReport:
    """One node's worst case under the MAC: the longest wait between two of its transmit
    opportunities while it has data (None: it never sends, or no bound), and the share of
    time its modem transmits when it uses every opportunity with its largest frame."""

    worst_interval_s: float | None
    airtime_share: float | None
    note: str = ""
    random_access: bool = False
    turns_per_s: float | None = None
    """Its transmit opportunities per second on average while it has data (what its turns
    carry over time: ``zab check``'s relay budgets); None: as many as its worst interval
    allows."""

    def mean_turns_per_s(self) -> float:
        """:attr:`turns_per_s`, else one per worst interval (0: it never sends)."""
        if self.turns_per_s is not None:
            return self.turns_per_s
        return 1.0 / self.worst_interval_s if self.worst_interval_s else 0.0


def airtime_share(airtime_s: float | None, per_s: float | None,
                  data_per_s: float | None = None) -> float | None:
    """The share of time a node transmits, sending ``per_s`` frames of ``airtime_s`` a
    second (no more than its data fills, ``data_per_s``, where given)."""
    if airtime_s is None or per_s is None:
        return None
    if data_per_s is not None:
        per_s = min(per_s, data_per_s)
    return round(min(1.0, airtime_s * per_s), 4)


class Mac(ABC):
    """The rules of one kind of MAC over a whole mission: each node's schedule, what the
    mission file must give, and what ``zab check``, link health, reliable retries and
    ranging need to know of it. One subclass per kind, registered in :data:`MACS`."""

    def __init__(self, mission: Mission) -> None:
        self.mission = mission

    @abstractmethod
    def schedule(self, node: str, seed: int | None = None) -> Schedule:
        """``node``'s schedule (``seed``: random draws). Raises ValueError when a needed
        time cannot be computed (:meth:`problems` reports those first)."""

    def problems(self) -> Iterable[tuple[Loc, str]]:
        """Cross-references and missing times, as ``(location, message)``."""
        return ()

    def turn_missing(self, node: str) -> str | None:
        """Why ``node`` never gets a turn to send under this MAC and what gives it one (said
        to the user), or None when it does get turns (every node does, by default)."""
        return None

    @abstractmethod
    def report(self, node: str, airtime_s: float | None, data_per_s: float) -> MacReport:
        """``node``'s worst-case interval and airtime share: ``airtime_s`` is its largest
        frame, ``data_per_s`` the most frames per second its channels (and heartbeat) can
        fill; random access sends no more than that, scheduled MACs use every turn."""

    def check_node(self, node: str, need_s: float | None,
                   airtime_s: float | None) -> tuple[dict[str, Any], list[str]]:
        """What ``zab check`` adds to ``node``'s entry, and its warnings (``need_s``: the time
        its largest frame needs, latency and propagation included; ``airtime_s``: its
        airtime)."""
        return {}, []

    def check(self, nodes: list[dict[str, Any]]) -> tuple[dict[str, Any], list[str]]:
        """``zab check``'s MAC section (times used, given or computed) and its warnings;
        ``nodes``: each node's entry, its :meth:`report` under ``mac``."""
        return {}, []

    def cycle_s(self) -> float | None:
        """How long a cycle of every node's turns lasts, where the MAC has one."""
        return None

    def heartbeat_s(self) -> float | None:
        """How often a node sends at least a frame by default (None: the MAC makes every node
        send anyway)."""
        return FREE_HEARTBEAT_S

    def retry_s(self) -> float:
        """When a reliable value is first sent again, by default."""
        return DEFAULT_RETRY_S

    def dlbl_travel_s(self, node: str) -> float:
        """The longest travel time a DLBL reply to ``node`` may have, so that it never
        matches two of its transmissions."""
        return 1.0

    def clock_limits(self) -> tuple[float, float] | None:
        """(the largest clock offset that keeps the nodes' turns apart, the guard it comes
        from), or None where the MAC does not depend on the wall clock."""
        return None
