"""Medium access: when may this node start a transmission (pure, time passed in).

Every MAC is a :class:`Mac` (the rules of its kind over a whole mission: schedules, mission
problems, ``zab check``'s lines, retry and heartbeat timing, DLBL travel bounds) and gives each
node a :class:`Schedule` with one small interface, so the runtime's transmit loop and the
virtual-clock simulator drive them all alike:

- :meth:`Schedule.next_opportunity` ``(now, due)`` → the next :class:`Opportunity`, or ``None``
  (wait for data or for a reception). ``due`` is when data (or a heartbeat) is next due, or
  ``None`` when nothing is pending. The caller sleeps until ``start`` (asking again if data
  or a frame arrives meanwhile) and then transmits. An opportunity with ``must_send`` carries
  a frame even when nothing is due (TDMA with DLBL, a master's poll, a slave's reply, a ranging
  request or answer); ``poll`` names the node that frame polls; ``kind`` says why it is offered
  (:class:`OpportunityKind`); ``until`` ends the turn (a TDMA slot's end): the frame's
  :class:`~bridge.core.node.SendFrame` carries it to the modem, which begins no transmission
  of it, nor a retry, from then on.
- :meth:`Schedule.on_sent` ``(start, end)``: a frame went out (``end``: the modem was done);
  :meth:`Schedule.on_skipped` ``(now)``: the opportunity passed without a frame.
- :meth:`Schedule.on_heard` ``(src, polled_me, end)``: a valid frame from ``src`` ended at ``end``
  (``polled_me``: it polls this node).

One module per kind, registered by its mission ``type`` in :data:`MACS`: ``tdma``
(:mod:`.tdma`), ``none`` (:mod:`.free`), ``polled`` (:mod:`.polled`), ``aloha``
(:mod:`.aloha`); ``none`` and ``aloha`` may reserve seed 001's ranging rounds
(:mod:`.ranging`, :mod:`.random_access`). A new MAC is a module here, its entry in
:data:`MACS`, and its model in :mod:`bridge.mission.model`.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

from bridge.core.mac.aloha import Aloha, AlohaSchedule, aloha_slot_s
from bridge.core.mac.base import (
    EPS,
    LATE_S,
    Loc,
    Mac,
    MacReport,
    Opportunity,
    OpportunityKind,
    Schedule,
)
from bridge.core.mac.free import Free, FreeSchedule
from bridge.core.mac.polled import (
    Polled,
    PolledSchedule,
    poll_sequence,
    polled_ipg_s,
    polled_slaves,
)
from bridge.core.mac.ranging import RangingSchedule, ranging_tmax_s
from bridge.core.mac.tdma import Slot, Tdma, TdmaSchedule
from bridge.core.mac.timing import busy_s, frame_time_s, max_distance_m, node_preset
from bridge.mission.model import Mission

__all__ = [
    "EPS", "LATE_S", "MACS", "Aloha", "AlohaSchedule", "Free", "FreeSchedule", "Loc", "Mac",
    "MacReport", "Opportunity", "OpportunityKind", "Polled", "PolledSchedule",
    "RangingSchedule", "Schedule", "Slot", "Tdma", "TdmaSchedule", "aloha_slot_s", "busy_s",
    "frame_time_s", "mac_for", "mac_problems", "mac_report", "max_distance_m", "node_preset",
    "poll_sequence", "polled_ipg_s", "polled_slaves", "ranging_tmax_s", "schedule_for",
]

MACS: dict[str, type[Mac]] = {"tdma": Tdma, "none": Free, "polled": Polled, "aloha": Aloha}
"""Each kind of MAC, by the ``type`` its mission model gives."""


def mac_for(mission: Mission) -> Mac:
    """The rules of ``mission``'s MAC."""
    return MACS[mission.mac.type](mission)


def schedule_for(mission: Mission, node: str, *, seed: int | None = None) -> Schedule:
    """The schedule of ``node``. Raises ValueError when a needed time cannot be computed
    (the mission loader reports those first, see :func:`mac_problems`)."""
    return mac_for(mission).schedule(node, seed)


def mac_problems(mission: Mission) -> Iterable[tuple[Loc, str]]:
    """Cross-references and missing times of the MAC, as ``(location, message)``."""
    return mac_for(mission).problems()


def mac_report(mission: Mission, node: str, airtime_s: float | None,
               data_per_s: float = math.inf) -> MacReport:
    """Worst-case interval and airtime share of ``node`` (see :meth:`Mac.report`)."""
    return mac_for(mission).report(node, airtime_s, data_per_s)
