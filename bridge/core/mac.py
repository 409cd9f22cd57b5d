"""Medium access: when may this node start a transmission (pure, time passed in).

Every MAC is a :class:`Schedule` with one small interface, so the runtime's transmit loop and
the virtual-clock simulator drive them all alike:

- :meth:`Schedule.next_opportunity` ``(now, due)`` → the next :class:`Opportunity`, or ``None``
  (wait for data or for a reception). ``due`` is when data (or a heartbeat) is next due, or
  ``None`` when nothing is pending. The caller sleeps until ``start`` (asking again if data
  or a frame arrives meanwhile) and then transmits. An opportunity with ``must_send`` carries
  a frame even when nothing is due (TDMA with DLBL, a master's poll, a slave's reply, a ranging
  request or answer); ``poll`` names the node that frame polls.
- :meth:`Schedule.on_sent` ``(start, end)``: a frame went out (``end``: the modem was done);
  :meth:`Schedule.on_skipped` ``(now)``: the opportunity passed without a frame.
- :meth:`Schedule.on_heard` ``(src, polled_me, end)``: a valid frame from ``src`` ended at ``end``
  (``polled_me``: it polls this node).

The MACs (rules of each, as they apply to one node):

=========  ==================================================================================
``tdma``   slot ``k`` (starting ``k * slot_s`` after the Unix epoch) belongs to
           ``order[k % len(order)]``; vehicles with disciplined clocks agree without talking.
           The last ``guard_s`` of a slot stays silent. ``must_send`` with DLBL.
``none``   send whenever something is due, at least ``min_gap_s`` after the previous frame.
``polled`` the master sends every ``ipg_s`` (``must_send``), polling the next slave of its
           sequence; a slave sends once (``must_send``) right after hearing a frame polling it,
           within a quarter of the IPG, else the turn is lost. Other nodes never send.
``aloha``  send when due after a random backoff (uniform in ``[0, backoff_s]``; slotted:
           whole slots, starts on slot boundaries); after a frame of airtime ``a`` the next
           starts at least ``a / max_airtime_share`` later.
=========  ==================================================================================

``none`` and ``aloha`` may reserve seed 001's ranging rounds (:class:`RangingSchedule`).
"""

from __future__ import annotations

import bisect
import math
import random
from abc import ABC, abstractmethod
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import ClassVar

from bridge.frozen import direct_init
from bridge.mission.model import AlohaMac, Mission, NoMac, PolledMac, RangingSlots, TdmaMac
from bridge.modems.presets import Preset, UnknownPresetError, get_preset
from bridge.ranging.twr import AnchorReplier, round_timeout, tmax

__all__ = [
    "LATE_S",
    "AlohaSchedule",
    "FreeSchedule",
    "MacReport",
    "Opportunity",
    "PolledSchedule",
    "RangingSchedule",
    "Schedule",
    "Slot",
    "TdmaSchedule",
    "mac_problems",
    "mac_report",
    "poll_sequence",
    "schedule_for",
]

LATE_S = 0.05
"""How long a TDMA slot start stays usable for an adapter that woke late, seconds."""

EPS = 1e-9

SLOW_SOUND = 1400.0 / 1500.0
"""A ranging turn assumes sound this much slower than the preset's (seed 001 takes 1400 m/s,
the slowest speed it expects, against the nominal 1500 m/s)."""


@direct_init
@dataclass(frozen=True)
class Opportunity:
    """A transmit opportunity: start at ``start`` (now if already past), never after ``latest``."""

    start: float
    latest: float = math.inf
    must_send: bool = False
    poll: str | None = None
    kind: str = "due"
    """``slot``, ``due``, ``poll``, ``reply``, ``ranging_request`` or ``ranging_reply``."""


@dataclass(frozen=True)
class Slot:
    """A TDMA slot: start no earlier than ``start``, be silent by ``end``."""

    start: float
    end: float


class Schedule(ABC):
    """One node's view of a MAC (see the module docstring)."""

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


# -- TDMA and none ------------------------------------------------------------------------------


class TdmaSchedule(Schedule):
    """The static TDMA cycle as seen by one node."""

    fixed = True

    def __init__(self, mac: TdmaMac, node: str, *, always: bool = False) -> None:
        self.slot_s = mac.slot_s
        self.guard_s = mac.guard_s
        self.order = tuple(mac.order)
        self.owned = tuple(i for i, owner in enumerate(self.order) if owner == node)
        self.cycle_s = self.slot_s * len(self.order)
        self.always = always
        self._used = -math.inf

    def next_slot(self, after: float) -> Slot | None:
        """This node's first slot starting strictly after ``after``; None if it owns none."""
        if not self.owned:
            return None
        k = math.floor(after / self.slot_s) + 1
        n, owned = len(self.order), self.owned  # owned: ascending slot indices
        phase = k % n
        i = bisect.bisect_left(owned, phase)  # the first owned slot at or after k's phase
        k += owned[i] - phase if i < len(owned) else owned[0] + n - phase
        start = k * self.slot_s
        return Slot(start, start + self.slot_s - self.guard_s)

    def next_opportunity(self, now: float, due: float | None) -> Opportunity | None:
        late = min(LATE_S, self.usable_s() / 10)
        slot = self.next_slot(max(self._used, now - late - EPS))
        if slot is None:
            return None
        return Opportunity(slot.start, slot.start + late, self.always, None, "slot")

    def on_sent(self, start: float, end: float) -> None:
        self._used = max(self._used, start)

    def on_skipped(self, now: float) -> None:
        self._used = max(self._used, now)

    def usable_s(self) -> float:
        """Seconds of each slot in which a frame must fit (airtime + propagation)."""
        return self.slot_s - self.guard_s

    def worst_gap_s(self) -> float | None:
        """Longest wait between two of this node's slot starts."""
        if not self.owned:
            return None
        n = len(self.order)
        starts = sorted(self.owned)
        gaps = [(b - a) for a, b in zip(starts, [*starts[1:], starts[0] + n], strict=True)]
        return max(gaps) * self.slot_s


class FreeSchedule(Schedule):
    """No access control: any time, with a minimum gap between frames."""

    def __init__(self, mac: NoMac) -> None:
        self.min_gap_s = mac.min_gap_s
        self._last: float | None = None

    def earliest(self, now: float, last_start: float | None) -> float:
        """When the next frame may start."""
        if last_start is None:
            return now
        return max(now, last_start + self.min_gap_s)

    def next_opportunity(self, now: float, due: float | None) -> Opportunity | None:
        if due is None:
            return None
        return Opportunity(max(self.earliest(now, self._last), due))

    def on_sent(self, start: float, end: float) -> None:
        self._last = start


# -- polled -------------------------------------------------------------------------------------


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
            return Opportunity(self._next, self._next + self.ipg_s, True, self.poll_target(),
                               "poll")
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
            self._reply = Opportunity(end, end + self.reply_window_s, True, None, "reply")

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


# -- ALOHA --------------------------------------------------------------------------------------


class AlohaSchedule(Schedule):
    """Pure or slotted ALOHA with a random backoff and an airtime cap."""

    def __init__(self, mac: AlohaMac, slot_s: float | None, rng: random.Random) -> None:
        if mac.slotted and (slot_s is None or slot_s <= 0):
            raise ValueError("slotted ALOHA needs slot_s > 0")
        self.slotted = mac.slotted
        self.slot_s = slot_s
        self.backoff_s = mac.backoff_s
        self.share = mac.max_airtime_share
        self._rng = rng
        self._start: float | None = None  # this frame's start, backoff included, until used
        self._free_at = -math.inf

    def _draw(self) -> float:
        if self.backoff_s <= 0:
            return 0.0
        if self.slotted:
            assert self.slot_s is not None
            return self._rng.randint(0, int(self.backoff_s / self.slot_s + EPS)) * self.slot_s
        return self._rng.uniform(0.0, self.backoff_s)

    def next_opportunity(self, now: float, due: float | None) -> Opportunity | None:
        if due is None:
            return None
        earliest = max(now, due, self._free_at)
        if self._start is None:
            if earliest > now:  # not due yet (say, a heartbeat): wake then, draw then
                return Opportunity(earliest)
            self._start = earliest + self._draw()  # a new frame: draw its backoff once
        start = max(self._start, due, self._free_at)
        if self.slotted:
            assert self.slot_s is not None
            start = math.ceil(start / self.slot_s - EPS) * self.slot_s
        return Opportunity(start)

    def on_sent(self, start: float, end: float) -> None:
        self._start = None
        self._free_at = start + max(0.0, end - start) / self.share

    def on_skipped(self, now: float) -> None:
        self._start = None


# -- ranging rounds ------------------------------------------------------------------------------


class RangingSchedule(Schedule):
    """Seed 001's ranging rounds reserved inside another schedule (``none`` or ``aloha``).

    Every frame of the requester opens a round (it sends one at least every ``interval_s``);
    anchor ``i`` answers at once (``i == 0``) or right after hearing anchor ``i - 1``, and at
    the latest ``tmax`` after the previous anchor's turn (:class:`AnchorReplier`); until the
    round ends (all answers heard, or ``(n + 1)·tmax``) every other frame waits. Having heard a
    request, a node also keeps the next one's round free: no frame of its own starts from
    ``2·tmax`` before the next request is due until that round's longest end.
    """

    def __init__(self, inner: Schedule, node: str, slots: RangingSlots, tmax_s: float) -> None:
        self.inner = inner
        self.node = node
        self.requester = slots.requester
        self.anchors = tuple(slots.anchors)
        self.interval_s = slots.interval_s
        self.tmax_s = tmax_s
        self.replier = (AnchorReplier(self.anchors.index(node), tmax_s)
                        if node in self.anchors else None)
        self._last_request: float | None = None
        self._quiet_until = -math.inf
        self._reserved = (math.inf, -math.inf)  # the next round, as expected by a listener
        self._answers = 0
        self._offered = ""  # kind of the last opportunity offered
        self.rounds = 0

    def _round_over(self, end: float) -> None:
        self._quiet_until = min(self._quiet_until, end)

    def next_opportunity(self, now: float, due: float | None) -> Opportunity | None:
        opp = self._next(now, due)
        self._offered = "" if opp is None else opp.kind
        return opp

    def _next(self, now: float, due: float | None) -> Opportunity | None:
        if self.replier is not None and self.replier.deadline is not None and not \
                self.replier.sent:
            deadline = self.replier.deadline
            if deadline + self.tmax_s >= now:
                return Opportunity(deadline, deadline + self.tmax_s, True, None, "ranging_reply")
            self.replier.sent = True  # missed our turn: the round has moved on
        inner = self.inner.next_opportunity(now, due)
        if inner is not None:
            start = max(inner.start, self._quiet_until)
            if self._reserved[0] < max(start, now) < self._reserved[1]:
                start = self._reserved[1]
            if start != inner.start:
                inner = Opportunity(start, max(inner.latest, start), inner.must_send,
                                    inner.poll, inner.kind)
        if self.node != self.requester:
            return inner
        request = (now if self._last_request is None
                   else max(self._last_request + self.interval_s, self._quiet_until))
        if inner is None or request <= inner.start + self.tmax_s:
            return Opportunity(request, math.inf, True, None, "ranging_request")
        return inner

    def on_sent(self, start: float, end: float) -> None:
        self.inner.on_sent(start, end)
        if self.replier is not None and self.replier.deadline is not None and \
                not self.replier.sent:
            self.replier.processing_time(start)
        if self.node == self.requester:
            self._last_request = start
            self._answers = 0
            self._quiet_until = end + round_timeout(len(self.anchors), self.tmax_s)
            self.rounds += 1

    def on_skipped(self, now: float) -> None:
        self.inner.on_skipped(now)
        if self._offered == "ranging_reply" and self.replier is not None:
            self.replier.sent = True  # this round's turn is gone
        if self._offered == "ranging_request":  # refused (modem busy?): try next interval
            self._last_request = now

    def on_heard(self, src: str, polled_me: bool, end: float) -> None:
        self.inner.on_heard(src, polled_me, end)
        n = len(self.anchors)
        if src == self.requester:
            self._answers = 0
            if self.replier is not None:
                self.replier.on_request(end)
            # the last anchor's turn starts at most n - 1 turns after the request
            self._quiet_until = end + n * self.tmax_s
            expected = end + self.interval_s
            self._reserved = (expected - 2 * self.tmax_s, expected + (n + 1) * self.tmax_s)
        elif src in self.anchors:
            self._answers += 1
            if self.replier is not None:
                self.replier.on_reply_heard(self.anchors.index(src), end)
            if self.anchors.index(src) == n - 1 or self._answers >= n:
                self._round_over(end)


# -- from the mission -----------------------------------------------------------------------------


def node_preset(mission: Mission, node: str) -> Preset | None:
    """The modem preset that gives ``node`` known timings, if any."""
    name = mission.node_modem(node).options.get("preset")
    if not isinstance(name, str):
        return None
    try:
        return get_preset(name)
    except UnknownPresetError:
        return None


def max_distance_m(mission: Mission, preset: Preset) -> float:
    """Farthest two places nodes can be (positions and scripted waypoints), or the modem's
    maximum range when a node has neither."""
    places: list[list[tuple[float, float, float]]] = []
    for node in mission.nodes.values():
        spots = [node.position] if node.position else []
        spots += node.path.waypoints if node.path else []
        places.append([(p.x, p.y, p.depth) for p in spots])
    if len(places) < 2 or not all(places):
        return preset.max_range_m
    return min(preset.max_range_m, max(
        math.dist(a, b) for i, mine in enumerate(places) for theirs in places[i + 1:]
        for a in mine for b in theirs))


def busy_s(mission: Mission, node: str) -> float | None:
    """How long ``node``'s modem is busy with its largest frame: latency + airtime."""
    preset = node_preset(mission, node)
    if preset is None:
        return None
    size = min(mission.node_modem(node).frame_bytes, preset.frame_bytes)
    return preset.intrinsic_delay_s + preset.airtime(size)


def frame_time_s(mission: Mission, node: str) -> float | None:
    """Worst-case send-to-reception-end time of ``node``'s largest frame (None: no preset)."""
    preset = node_preset(mission, node)
    if preset is None:
        return None
    size = min(mission.node_modem(node).frame_bytes, preset.frame_bytes)
    return preset.frame_time_s(size, max_distance_m(mission, preset))


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


def aloha_slot_s(mission: Mission, mac: AlohaMac) -> float | None:
    """The ALOHA slot: given, or the longest frame time of any node."""
    if mac.slot_s is not None:
        return mac.slot_s
    times = [frame_time_s(mission, n) for n in mission.nodes]
    if any(t is None for t in times):
        return None
    return max(t for t in times if t is not None)


def ranging_tmax_s(mission: Mission, slots: RangingSlots) -> float | None:
    """One anchor's turn: given, or seed 001 eq. 6 (``dmax/c + l/R``, ``c`` the slowest expected
    sound speed) plus the modem's latency (intrinsic delay + 3 sigma jitter and fixed frame
    overhead) for the largest anchor frame."""
    if slots.tmax_s is not None:
        return slots.tmax_s
    turns = []
    for anchor in slots.anchors:
        preset = node_preset(mission, anchor)
        if preset is None:
            return None
        size = min(mission.node_modem(anchor).frame_bytes, preset.frame_bytes)
        latency = preset.intrinsic_delay_s + 3 * preset.jitter_s + preset.overhead_s
        slowest = preset.sound_speed_mps * SLOW_SOUND
        turns.append(tmax(max_distance_m(mission, preset), slowest, size,
                          8 / preset.byte_time_s, guard_s=latency))
    return max(turns)


def _seed(mission: Mission, node: str, seed: int | None) -> str:
    base = seed if seed is not None else mission.modem.options.get("seed", 0)
    return f"{mission.mission}/{node}/{base}"


def schedule_for(mission: Mission, node: str, *, seed: int | None = None) -> Schedule:
    """The schedule of ``node``. Raises ValueError when a needed time cannot be computed
    (the mission loader reports those first, see :func:`mac_problems`)."""
    mac = mission.mac
    schedule: Schedule
    if isinstance(mac, TdmaMac):
        return TdmaSchedule(mac, node, always=mission.wire.dlbl)
    if isinstance(mac, PolledMac):
        ipg = polled_ipg_s(mission, mac)
        if ipg is None:
            raise ValueError("polled MAC: ipg_s is needed (no modem preset to compute it)")
        return PolledSchedule(node, mac.master, polled_slaves(mission, mac), ipg)
    if isinstance(mac, AlohaMac):
        slot = aloha_slot_s(mission, mac) if mac.slotted else None
        if mac.slotted and slot is None:
            raise ValueError("slotted aloha: slot_s is needed (no modem preset to compute it)")
        schedule = AlohaSchedule(mac, slot, random.Random(_seed(mission, node, seed)))
    else:
        schedule = FreeSchedule(mac)
    if mac.ranging is None:
        return schedule
    tmax_s = ranging_tmax_s(mission, mac.ranging)
    if tmax_s is None:
        raise ValueError("ranging: tmax_s is needed (no modem preset to compute it)")
    return RangingSchedule(schedule, node, mac.ranging, tmax_s)


Loc = tuple[str | int, ...]


def mac_problems(mission: Mission) -> Iterable[tuple[Loc, str]]:
    """Cross-references and missing times of the MAC, as ``(location, message)``."""
    mac, nodes = mission.mac, mission.nodes
    if isinstance(mac, TdmaMac):
        for i, owner in enumerate(mac.order):
            if owner not in nodes:
                yield (("mac", "order", i), f"unknown node {owner!r}")
        return
    if isinstance(mac, PolledMac):
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
        if not polled_slaves(mission, mac):
            yield (("mac",), "a polled MAC needs at least one slave")
        elif mac.ipg_s is None and mac.master in nodes and all(n in nodes for _, n in named) \
                and polled_ipg_s(mission, mac) is None:
            yield (("mac", "ipg_s"), "required: a node's modem has no preset to compute it from")
        return
    if isinstance(mac, AlohaMac) and mac.slotted and aloha_slot_s(mission, mac) is None:
        yield (("mac", "slot_s"), "required for slotted aloha: a node's modem has no preset "
               "to compute it from")
    slots = mac.ranging
    if slots is None:
        return
    if slots.requester not in nodes:
        yield (("mac", "ranging", "requester"), f"unknown node {slots.requester!r}")
    for i, anchor in enumerate(slots.anchors):
        if anchor not in nodes:
            yield (("mac", "ranging", "anchors", i), f"unknown node {anchor!r}")
        elif anchor == slots.requester:
            yield (("mac", "ranging", "anchors", i), "the requester cannot answer itself")
        elif anchor in slots.anchors[:i]:
            yield (("mac", "ranging", "anchors", i), f"{anchor!r} is listed twice")
    if all(a in nodes for a in slots.anchors) and ranging_tmax_s(mission, slots) is None:
        yield (("mac", "ranging", "tmax_s"), "required: an anchor's modem has no preset to "
               "compute it from")


# -- what zab check reports ------------------------------------------------------------------------


@dataclass(frozen=True)
class MacReport:
    """One node's worst case under the MAC: the longest wait between two of its transmit
    opportunities while it has data (None: it never sends, or no bound), and the share of
    time its modem transmits when it uses every opportunity with its largest frame."""

    worst_interval_s: float | None
    airtime_share: float | None
    note: str = ""
    random_access: bool = False


def mac_report(mission: Mission, node: str, airtime_s: float | None,
               data_per_s: float = math.inf) -> MacReport:
    """Worst-case interval and airtime share of ``node``: ``airtime_s`` is its largest frame,
    ``data_per_s`` the most frames per second its channels (and heartbeat) can fill; random
    access sends no more than that, scheduled MACs use every turn."""
    mac = mission.mac
    busy = busy_s(mission, node)

    def share(per_s: float | None, random_access: bool = False) -> float | None:
        if airtime_s is None or per_s is None:
            return None
        if random_access:
            per_s = min(per_s, data_per_s)
        return round(min(1.0, airtime_s * per_s), 4)

    if isinstance(mac, TdmaMac):
        tdma = TdmaSchedule(mac, node)
        gap = tdma.worst_gap_s()
        per_s = len(tdma.owned) / tdma.cycle_s
        return MacReport(gap, share(per_s), "" if gap else "owns no slot: listens only")
    if isinstance(mac, PolledMac):
        ipg = polled_ipg_s(mission, mac)
        if ipg is None:
            return MacReport(None, None, "no ipg_s")
        polled = PolledSchedule(node, mac.master, polled_slaves(mission, mac), ipg)
        gap = polled.worst_gap_s()
        note = "master" if polled.is_master else ("" if gap else "never polled: listens only")
        return MacReport(gap, share(polled.turns_per_s() if gap else None), note)
    slots = mac.ranging
    if slots is not None and node in (slots.requester, *slots.anchors):
        role = "ranging requester" if node == slots.requester else "ranging anchor"
        return MacReport(slots.interval_s, share(1 / slots.interval_s),
                         f"{role}: one frame per round")
    if isinstance(mac, AlohaMac):
        spacing = max(busy or 0.0, (airtime_s or 0.0) / mac.max_airtime_share)
        slot = aloha_slot_s(mission, mac) if mac.slotted else 0.0
        worst = spacing + mac.backoff_s + (slot or 0.0)
        per_s = 1 / (spacing + mac.backoff_s / 2) if spacing + mac.backoff_s > 0 else None
        return MacReport(round(worst, 4) if worst > 0 else None, share(per_s, True),
                         "random access: collisions possible", True)
    spacing = max(busy or 0.0, mac.min_gap_s)
    return MacReport(spacing or None, share(1 / spacing if spacing else None, True),
                     "no access control: collisions possible", True)
