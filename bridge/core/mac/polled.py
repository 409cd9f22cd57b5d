"""``polled``: the master sends every ``ipg_s`` (``must_send``), polling the next slave of its
sequence; a slave sends once (``must_send``) right after hearing a frame polling it, within a
quarter of the IPG, else the turn is lost. Other nodes never send (pure). A turn's ``until``
(no transmission begins from then on): the master's, its next poll; a slave's, the end of its
reply window."""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from bridge.core.mac.base import (
    Loc,
    Mac,
    MacReport,
    Opportunity,
    OpportunityKind,
    Schedule,
    airtime_share,
)
from bridge.core.mac.timing import frame_time_s
from bridge.mission.model import Mission, PolledMac

__all__ = ["Polled", "PolledSchedule", "poll_sequence", "polled_ipg_s", "polled_slaves"]


def poll_sequence(order: Sequence[str] | None, weights: Mapping[str, int] | None,
                  slaves: Sequence[str]) -> tuple[str, ...]:
    """One polling cycle: ``order`` as given, else ``weights`` interleaved (smooth weighted
    round robin: ``{a: 2, b: 1}`` → ``a, b, a``), else every slave once."""
    if order is not None:
        return tuple(order)
    if not weights:
        return tuple(slaves)
    total = sum(weights.values())
    credit = dict.fromkeys(weights, 0)
    cycle = []
    for _ in range(total):
        for name, weight in weights.items():
            credit[name] += weight
        pick = max(credit, key=lambda n: credit[n])  # first of the largest: stable
        credit[pick] -= total
        cycle.append(pick)
    return tuple(cycle)


class PolledSchedule(Schedule):
    """Master/slave polling as seen by one node (master, slave or bystander)."""

    def __init__(self, node: str, master: str, sequence: Sequence[str], ipg_s: float) -> None:
        if ipg_s <= 0:
            raise ValueError("ipg_s must be > 0")
        self.node = node
        self.master = master
        self.sequence = tuple(sequence)
        self.ipg_s = ipg_s
        self.reply_window_s = ipg_s / 4
        self._next: float | None = None  # master: next poll time
        self._turn = 0
        self._reply: Opportunity | None = None  # slave: pending reply
        self.missed_replies = 0

    @property
    def is_master(self) -> bool:
        return self.node == self.master

    def poll_target(self) -> str | None:
        """Whom the master's next poll addresses."""
        if not self.is_master or not self.sequence:
            return None
        return self.sequence[self._turn % len(self.sequence)]

    def next_opportunity(self, now: float, due: float | None) -> Opportunity | None:
        if self.is_master:
            if self._next is None:
                self._next = now
            elif self._next + self.ipg_s <= now:  # far behind: back onto the grid
                self._next += self.ipg_s * math.floor((now - self._next) / self.ipg_s)
            end = self._next + self.ipg_s  # the poll's cycle: its turn ends at the next poll
            return Opportunity(self._next, end, True, self.poll_target(), OpportunityKind.POLL,
                               end)
        reply = self._reply
        if reply is not None and reply.latest < now:
            self._reply = None
            self.missed_replies += 1
            return None
        return reply

    def _used(self, now: float) -> None:
        if self.is_master:
            base = self._next if self._next is not None else now
            self._next = base + self.ipg_s
            self._turn += 1
        else:
            self._reply = None

    def on_sent(self, start: float, end: float) -> None:
        self._used(start)

    def on_skipped(self, now: float) -> None:
        self._used(now)

    def on_heard(self, src: str, polled_me: bool, end: float) -> None:
        if src == self.master and polled_me and not self.is_master:
            window = end + self.reply_window_s  # a reply begins within the window, or never
            self._reply = Opportunity(end, window, True, None, OpportunityKind.REPLY, window)

    def worst_gap_s(self) -> float | None:
        """Longest time between two of this node's turns (None: it never sends)."""
        if self.is_master:
            return self.ipg_s
        turns = [i for i, name in enumerate(self.sequence) if name == self.node]
        if not turns:
            return None
        n = len(self.sequence)
        gaps = [b - a for a, b in zip(turns, [*turns[1:], turns[0] + n], strict=True)]
        return max(gaps) * self.ipg_s

    def turns_per_s(self) -> float:
        """How many frames this node sends per second when every poll is answered."""
        if self.is_master:
            return 1 / self.ipg_s
        return self.sequence.count(self.node) / (len(self.sequence) * self.ipg_s)


def polled_slaves(mission: Mission, mac: PolledMac) -> tuple[str, ...]:
    """The polling cycle of a polled mission."""
    others = [n for n in mission.nodes if n != mac.master]
    return poll_sequence(mac.order, mac.weights, others)


def polled_ipg_s(mission: Mission, mac: PolledMac) -> float | None:
    """The IPG: given, or the master's frame time + the slowest slave's + ``guard_s``."""
    if mac.ipg_s is not None:
        return mac.ipg_s
    master = frame_time_s(mission, mac.master)
    slaves = [frame_time_s(mission, s) for s in set(polled_slaves(mission, mac))]
    if master is None or any(t is None for t in slaves):
        return None
    return master + max((t for t in slaves if t is not None), default=0.0) + mac.guard_s


class Polled(Mac):
    """Master/slave polling (seed 002's token passing)."""

    def __init__(self, mission: Any) -> None:
        super().__init__(mission)
        assert isinstance(mission.mac, PolledMac)
        self.model: PolledMac = mission.mac

    def schedule(self, node: str, seed: int | None = None) -> PolledSchedule:
        ipg = polled_ipg_s(self.mission, self.model)
        if ipg is None:
            raise ValueError("polled MAC: ipg_s is needed (no modem preset to compute it)")
        return PolledSchedule(node, self.model.master, polled_slaves(self.mission, self.model),
                              ipg)

    def problems(self) -> Iterable[tuple[Loc, str]]:
        mac, nodes = self.model, self.mission.nodes
        if mac.master not in nodes:
            yield (("mac", "master"), f"unknown node {mac.master!r}")
        named: list[tuple[Loc, str]] = [(("mac", "order", i), n)
                                        for i, n in enumerate(mac.order or ())]
        named += [(("mac", "weights", n), n) for n in mac.weights or {}]
        for loc, name in named:
            if name not in nodes:
                yield (loc, f"unknown node {name!r}")
            elif name == mac.master:
                yield (loc, f"the master {name!r} cannot poll itself")
        if not polled_slaves(self.mission, mac):
            yield (("mac",), "a polled MAC needs at least one slave")
        elif mac.ipg_s is None and mac.master in nodes and all(n in nodes for _, n in named) \
                and polled_ipg_s(self.mission, mac) is None:
            yield (("mac", "ipg_s"), "required: a node's modem has no preset to compute it from")

    def turn_missing(self, node: str) -> str | None:
        mac = self.model
        if node == mac.master or node in polled_slaves(self.mission, mac):
            return None
        where = "mac.weights" if mac.weights is not None else "mac.order"
        return (f"the master {mac.master} never polls it (a slave sends only when polled); "
                f"add {node} to {where}")

    def report(self, node: str, airtime_s: float | None, data_per_s: float) -> MacReport:
        ipg = polled_ipg_s(self.mission, self.model)
        if ipg is None:
            return MacReport(None, None, "no ipg_s")
        polled = PolledSchedule(node, self.model.master, polled_slaves(self.mission, self.model),
                                ipg)
        gap = polled.worst_gap_s()
        note = "master" if polled.is_master else ("" if gap else "never polled: listens only")
        per_s = polled.turns_per_s() if gap else None
        return MacReport(gap, airtime_share(airtime_s, per_s), note, turns_per_s=per_s)

    def check(self, nodes: list[dict[str, Any]]) -> tuple[dict[str, Any], list[str]]:
        mission, mac = self.mission, self.model
        ipg = polled_ipg_s(mission, mac)
        needed = polled_ipg_s(mission, mac.model_copy(update={"ipg_s": None, "guard_s": 0.0}))
        data = {"ipg_s": _round(ipg), "needed_ipg_s": _round(needed),
                "sequence": list(polled_slaves(mission, mac))}
        warnings = []
        if ipg is not None and needed is not None and ipg < needed:
            warnings.append(
                f"polled: ipg_s {ipg:.3f} s is shorter than a poll plus the slowest reply "
                f"({needed:.3f} s: latency + 3 sigma jitter, airtime, propagation); replies "
                "may collide with the next poll")
        return data, warnings

    def heartbeat_s(self) -> None:
        return None  # every poll and every reply is a frame

    def retry_s(self) -> float:
        """A slave's longest wait between turns and a poll more: its value is acknowledged
        in the master's next poll and sent again at its next turn; the master's value to a
        slave is acknowledged in that slave's next reply (seed 002's link: 1.3 s, where ten
        seconds of silence made an operator's lost ROI wait that long)."""
        ipg = polled_ipg_s(self.mission, self.model)
        slaves = polled_slaves(self.mission, self.model)
        if ipg is None or not slaves:
            return super().retry_s()
        gaps = [PolledSchedule(s, self.model.master, slaves, ipg).worst_gap_s() or ipg
                for s in set(slaves)]
        return max(gaps) + ipg


def _round(value: float | None) -> float | None:
    return None if value is None else round(value, 4)
