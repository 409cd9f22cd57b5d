"""One node's ranging and localisation, fed by the frames it hears (pure: times passed in).

Ranges come from the DLBL delays every frame carries (:mod:`bridge.ranging.dlbl`) and from the
modem itself (:meth:`Positioning.on_modem_range`: a Micro-Modem ``ping``, an EvoLogics
``propagation`` time after an acknowledged IM). Ranges to anchors with known positions give a
fix (:func:`bridge.ranging.localise.attempt`); an attempt without one says why (:class:`NoFix`).
The runtime publishes what this returns under ``@zab/<mission>/<node>/range/<peer>`` and
``@zab/<mission>/<node>/position``.

Sound speed: this node's (the mission's ``ranging.sound_speed_mps``, else its ``ranging.water``'s,
replaced by live readings of ``ranging.ctd_key``); with ``ranging.sound_speed_mode:
mean_of_ends``, a range to a peer whose water is known (``ranging.peer_ctd_key``,
:meth:`Positioning.set_peer_water`) uses the mean of both ends' sound speeds (seed 001 II-A).
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

from bridge.core.mac import mac_for
from bridge.mission.model import Mission
from bridge.mission.path import Path
from bridge.mission.presets import Preset, get_preset
from bridge.ranging import DlblRanger, Fix, NoFix, Range, SoundSpeed, Track, attempt

if TYPE_CHECKING:
    from bridge.ranging.tracker import Estimate

# The range-domain tracker (and numpy with it) is imported when a node's positioning starts:
# a mission without ranging runs without numpy.

DEFAULT_SOUND_SPEED_MPS = 1500.0
MODEM_METHODS = ("ping", "propagation")
TRACK_RESTART_AFTER = 3
"""Fixes in a row the track refuses before it restarts at the latest one (it had diverged)."""
MAX_MODEM_TRAVEL_S = 20.0
"""Longest one-way travel time believed from a modem (30 km at 1500 m/s); beyond is garbage."""

RANGE_SIGMA_M = 0.15
"""Range error the tracker expects: DLBL stamps to tens of µs, clocks tens of ppm apart."""
NAV_SPEED_SIGMA_MPS = 0.05
"""1-σ of the speed a vehicle's own navigation reports (a DVL, a calibrated log: a few cm/s);
the tracker's default (0.1 m/s, a propeller's count) made MORPH's cv1 underconfident (NEES
below χ²₂'s 2.5 % bound 11 % of the time, none above the 97.5 %)."""
START_SIGMA_M = 2.0
"""How well a node knows where it starts (its mission position or first waypoint)."""
ANCHOR_SAMPLE_AGE_S = 0.5
"""Mean age of a live anchor position when its frame is built (a 1 Hz nav, sampled anywhere
in the second before); the frame's airtime comes on top (:attr:`Positioning.report_latency_s`)."""
ANCHOR_MAX_SPEED_MPS = 2.0
"""How fast a live anchor may have moved from its mission position before its first report:
until then, that position's 1-σ grows by half of this per second since the node started."""
REPORT_EVERY_S = 5.0
"""Without new ranges, the tracker's estimate (coasting, then lost) is still published this
often."""

WATER_LIMITS = {"temperature_c": (-2.0, 40.0), "salinity_psu": (0.0, 42.0),
                "depth_m": (0.0, 12000.0)}
"""What a CTD reading may hold (the mission's ``ranging.water`` bounds)."""


def water_sound_speed_of(mission: Mission) -> SoundSpeed | None:
    """The sound speed of the mission's ``ranging.water``, if it describes the water."""
    w = mission.ranging.water
    if w is None:
        return None
    return SoundSpeed.from_ctd(w.temperature_c, w.salinity_psu, w.depth_m,
                               equation=w.equation, lat_deg=w.latitude_deg)


def mission_sound_speed(mission: Mission) -> SoundSpeed:
    """The sound speed the bridge assumes: ``ranging.sound_speed_mps`` if given, else computed
    from ``ranging.water``, else 1500 m/s (docs/ranging.md)."""
    if mission.ranging.sound_speed_mps is not None:
        return SoundSpeed.fixed(mission.ranging.sound_speed_mps)
    return water_sound_speed_of(mission) or SoundSpeed.fixed(DEFAULT_SOUND_SPEED_MPS)


def simulated_preset(mission: Mission) -> Preset:
    """The simulated ocean's preset for the mission (``modem.options.preset``). Sound crosses
    the simulated ocean at the speed of ``ranging.water`` when the mission describes it (the
    truth), else at ``ranging.sound_speed_mps``: with both, the bridge assumes the latter, so a
    wrong assumption can be simulated."""
    preset = get_preset(mission.modem.options.get("preset", "evologics-s2c-im"))
    truth = water_sound_speed_of(mission)
    if truth is None and mission.ranging.sound_speed_mps is not None:
        truth = SoundSpeed.fixed(mission.ranging.sound_speed_mps)
    if truth is not None:
        preset = preset.replace(sound_speed_mps=truth.mps)
    return preset


def mission_anchors(mission: Mission) -> tuple[str, ...]:
    if mission.ranging.anchors is not None:
        return tuple(mission.ranging.anchors)
    return tuple(n for n, node in mission.nodes.items()
                 if node.role == "surface" and node.position is not None)


def ping_plan(mission: Mission, node: str) -> tuple[str, ...]:
    """The peers ``node`` asks its modem to range to, in turn (empty: it does not range).

    Raises ``ValueError`` naming ``ranging.ping`` if it names a node the mission lacks.
    """
    ping = mission.ranging.ping
    if ping is None:
        return ()
    for field, names in (("peers", ping.peers), ("nodes", ping.nodes)):
        unknown = [n for n in names or () if n not in mission.nodes]
        if unknown:
            raise ValueError(f"ranging.ping.{field}: unknown node(s) {', '.join(unknown)}")
    peers = tuple(ping.peers) if ping.peers is not None else mission_anchors(mission)
    rangers = ping.nodes if ping.nodes is not None else [n for n in mission.nodes
                                                         if n not in peers]
    if node not in rangers:
        return ()
    return tuple(p for p in peers if p != node)


def needs_positioning(mission: Mission, node: str) -> bool:
    """Whether ``node`` measures ranges at all: DLBL in every frame, or modem ranges."""
    return mission.wire.dlbl or bool(ping_plan(mission, node))


def initial_position(mission: Mission, node: str) -> tuple[float, float, float] | None:
    """Where ``node`` starts: its ``position``, else its path's first waypoint."""
    spec = mission.nodes[node]
    if spec.position is not None:
        return (spec.position.x, spec.position.y, spec.position.depth)
    if spec.path is not None:
        return Path.from_spec(spec.path).waypoints[0]
    return None


def water_sound_speed(temperature_c: float, salinity_psu: float, depth_m: float,
                      mission: Mission) -> SoundSpeed:
    """The sound speed of a CTD reading with the mission's equation; ``ValueError`` if the
    reading is not plausible water."""
    for (name, (low, high)), value in zip(WATER_LIMITS.items(),
                                          (temperature_c, salinity_psu, depth_m), strict=True):
        if not (math.isfinite(value) and low <= value <= high):
            raise ValueError(f"{name} {value} outside {low:g}..{high:g}")
    water = mission.ranging.water
    equation = water.equation if water is not None else "unesco"
    latitude = water.latitude_deg if water is not None else 45.0
    return SoundSpeed.from_ctd(temperature_c, salinity_psu, depth_m, equation, latitude)


@dataclass(frozen=True)
class Update:
    """What one measurement produced: ranges, the snapshot fix attempted with them (a
    :class:`Fix`, a :class:`NoFix` saying why not, or None when this node does not localise)
    and the range-domain tracker's estimate (:mod:`bridge.ranging.tracker`)."""

    ranges: tuple[Range, ...]
    fix: Fix | NoFix | None
    estimate: Estimate | None = None
    """The tracker's estimate after these ranges: what ``…/position`` publishes."""


class Positioning:
    """Ranges to each peer, anchor positions, sound speeds, explicit pings and fixes."""

    def __init__(self, mission: Mission, node: str) -> None:
        ranging = mission.ranging
        self.mission = mission
        self.node = node
        self.sound_speed = mission_sound_speed(mission)
        self.mode = ranging.sound_speed_mode
        self.peer_sound_speed: dict[str, SoundSpeed] = {}
        mac = mac_for(mission)
        cycle = mac.cycle_s()
        max_travel = mac.dlbl_travel_s(node)  # a reply must not match two of our transmissions
        self.ranger = DlblRanger(node, tuple(mission.nodes), tx_latency_s=ranging.tx_latency_s,
                                 rx_latency_s=ranging.rx_latency_s, max_travel_s=max_travel,
                                 cycle_s=cycle)
        self.anchors = tuple(a for a in mission_anchors(mission) if a != node)
        self.localises = node not in mission_anchors(mission) and len(self.anchors) >= 2
        self.anchor_positions: dict[str, tuple[float, float, float]] = {
            a: p for a in self.anchors if (p := initial_position(mission, a)) is not None
        }
        own = initial_position(mission, node)
        self.depth: float | None = own[2] if own else None
        self.start: tuple[float, float] | None = (own[0], own[1]) if own else None
        self.track = Track(accel_sigma=0.3)  # a vehicle that manoeuvres, not a ship
        self._refused_in_row = 0
        self.ping_peers = ping_plan(mission, node)
        self.ping_interval_s = ranging.ping.interval_s if ranging.ping is not None else math.inf
        self._next_ping = -math.inf
        self._ping_turn = 0
        default_age = cycle or 30.0
        if self.ping_peers:  # every peer's range must still count when its turn comes again
            default_age = max(default_age, 1.5 * self.ping_interval_s * len(self.ping_peers))
        self.fix_max_age_s = ranging.fix_max_age_s or default_age
        self.latest: dict[str, Range] = {}
        self.drops: Counter[str] = Counter()
        self.anchor_reports: dict[str, list[tuple[float, tuple[float, float, float]]]] = {}
        try:  # how old an anchor's acoustic position report is when it arrives
            airtime = simulated_preset(mission).airtime(mission.node_modem(node).frame_bytes)
        except (KeyError, ValueError):
            airtime = 0.0
        self.report_latency_s = airtime + ANCHOR_SAMPLE_AGE_S
        from bridge.ranging.tracker import RangeTracker, TrackerConfig

        config = TrackerConfig(range_sigma_m=RANGE_SIGMA_M, speed_sigma_mps=NAV_SPEED_SIGMA_MPS)
        if cycle is not None:  # a range per anchor per TDMA cycle: no news within one is normal
            config = replace(config, coast_after_s=max(config.coast_after_s, 1.5 * cycle),
                             init_window_s=max(config.init_window_s, cycle))
        self.tracker = RangeTracker(config, depth=self.depth) if self.localises else None
        self._reported_at = -math.inf
        self._clock_offset = 0.0  # the node's clock minus the modem's
        self._first_time: float | None = None  # when this node first sent or heard

    # -- transmissions (DLBL) ------------------------------------------------------------------

    def on_transmit(self, t_start: float) -> list[int | None]:
        if self._first_time is None:
            self._first_time = t_start
        return self.ranger.on_transmit(t_start)

    def forget_transmit(self, t_start: float) -> None:
        self.ranger.forget_transmit(t_start)

    # -- what the node learns ------------------------------------------------------------------

    def set_depth(self, depth: float) -> None:
        self.depth = depth
        if self.tracker is not None:
            self.tracker.set_depth(depth)

    def set_heading(self, heading_deg: float, speed_mps: float | None, now: float) -> None:
        """This node's compass heading (degrees from north) and, if known, speed at ``now``
        (with a speed they also dead-reckon the start position, the tracker's prior)."""
        if self.tracker is not None:
            self._set_prior(now)
            self.tracker.on_heading(now, heading_deg, speed_mps)

    def _set_prior(self, now: float) -> None:
        """Give the tracker where this node was put in (its mission position or first
        waypoint), as of when it started; it may have moved since."""
        if self._first_time is None:
            self._first_time = now
        if self.tracker is not None and self.tracker.prior is None and self.start is not None:
            from bridge.ranging.tracker import Prior

            self.tracker.prior = Prior(min(self._first_time, now), self.start[0],
                                       self.start[1], START_SIGMA_M)

    def set_anchor(self, anchor: str, position: tuple[float, float, float],
                   now: float | None = None) -> None:
        """A live position of ``anchor`` arriving at ``now``, if given (it may be moving): taken
        as where the anchor was :data:`ANCHOR_SAMPLE_AGE_S` before it sent the frame that
        brought it, if a range to it came with that frame, else :attr:`report_latency_s` ago."""
        self.anchor_positions[anchor] = position
        if now is not None:
            sent = now - self.report_latency_s + ANCHOR_SAMPLE_AGE_S
            rng = self.latest.get(anchor)
            if rng is not None and rng.method == "dlbl":
                arrived = rng.time + self._clock_offset  # that frame's start, on our clock
                if 0 <= now - arrived <= self.report_latency_s:
                    sent = arrived - rng.travel_time_s
            reports = self.anchor_reports.setdefault(anchor, [])
            reports.append((sent - ANCHOR_SAMPLE_AGE_S, position))
            del reports[:-2]

    def anchor_at(self, anchor: str, t: float) -> tuple[tuple[float, float, float], float, float]:
        """Where ``anchor`` was at ``t``: (position, 1-σ metres, age of the report in seconds),
        extrapolated from its last two live reports when it moves (back in time too: a DLBL
        range's first leg may predate the report its frame brought)."""
        reports = self.anchor_reports.get(anchor)
        position = self.anchor_positions[anchor]
        if not reports:  # the mission's: a moored anchor, or a live one not yet heard from
            if anchor not in self.mission.ranging.anchor_keys:
                return position, 0.0, 0.0
            since = max(t - (self._first_time if self._first_time is not None else t), 0.0)
            return position, START_SIGMA_M + ANCHOR_MAX_SPEED_MPS / 2 * since, 0.0
        t1, p1 = reports[-1]
        age = max(t - t1, 0.0)
        span = abs(t - t1)  # how far from the report, either way
        if len(reports) == 2 and 0 < t1 - reports[0][0] <= 60.0:
            t0, p0 = reports[0]
            rate = [(b - a) / (t1 - t0) for a, b in zip(p0, p1, strict=True)]
            position = (p1[0] + rate[0] * (t - t1), p1[1] + rate[1] * (t - t1), p1[2])
            speed = math.hypot(rate[0], rate[1])
            # a report's resolution, the sample's unknown age (up to a nav period or two), a
            # manoeuvre since
            return position, 0.05 + speed * 2 * ANCHOR_SAMPLE_AGE_S + 0.05 * span, age
        # one report: where it has gone since (or was before) is unknown
        return position, 0.05 + ANCHOR_MAX_SPEED_MPS / 2 * (span + 2 * ANCHOR_SAMPLE_AGE_S), age

    def set_water(self, temperature_c: float, salinity_psu: float, depth_m: float) -> None:
        """A CTD reading at this node (``ranging.ctd_key``); ``ValueError`` if implausible."""
        self.sound_speed = water_sound_speed(temperature_c, salinity_psu, depth_m, self.mission)

    def set_peer_water(self, peer: str, temperature_c: float, salinity_psu: float,
                       depth_m: float) -> SoundSpeed:
        """A CTD reading at ``peer`` (``ranging.peer_ctd_key``); ``ValueError`` if implausible
        or ``peer`` is not a node of the mission."""
        if peer not in self.mission.nodes or peer == self.node:
            raise ValueError(f"{peer!r} is not a peer of {self.node!r}")
        speed = water_sound_speed(temperature_c, salinity_psu, depth_m, self.mission)
        self.peer_sound_speed[peer] = speed
        return speed

    def peer_ctd_keys(self) -> dict[str, str]:
        """Each peer's CTD key at this node (``{src}`` = the peer, ``{node}``/``{dst}`` = us);
        empty unless ``mean_of_ends`` needs them."""
        template = self.mission.ranging.peer_ctd_key
        if template is None or self.mode != "mean_of_ends":
            return {}
        return {peer: template.replace("{src}", peer).replace("{node}", self.node)
                .replace("{dst}", self.node) for peer in self.mission.nodes if peer != self.node}

    def sound_speed_for(self, peer: str) -> SoundSpeed:
        """The sound speed of a range to ``peer``: ours, or the mean of both ends'."""
        theirs = self.peer_sound_speed.get(peer)
        if self.mode == "mean_of_ends" and theirs is not None:
            return SoundSpeed.mean_of(self.sound_speed, theirs)
        return self.sound_speed

    # -- measurements --------------------------------------------------------------------------

    def on_receive(self, src: str, t_rx_start: float, delays: Sequence[int | None],
                   now: float, host_now: float | None = None,
                   anchors: Mapping[str, tuple[float, float, float]] | None = None) -> Update:
        """A frame from ``src`` with its DLBL ``delays`` started arriving at ``t_rx_start``
        (``now``: the modem's clock; ``host_now``: the same instant on the clock of the node's
        other inputs, depth and heading, if it differs). ``anchors``: live anchor positions
        the same frame carried (``ranging.anchor_keys``), taken before its ranges are fused:
        a moving anchor's range is then measured against where it was when it sent them, not
        extrapolated from its reports in earlier frames (a cycle or more old)."""
        ranges = tuple(self.ranger.on_receive(src, t_rx_start, delays))
        for rng in ranges:
            self.latest[rng.peer] = rng
        offset = 0.0 if host_now is None else host_now - now
        if ranges:
            self._clock_offset = offset
        for anchor, position in (anchors or {}).items():
            if anchor in self.anchors:
                self.set_anchor(anchor, position, now + offset)
        if not (ranges and self.localises):
            return Update(ranges, None)
        for rng in ranges:
            self._track(rng, rng.time + offset, rng.reply_s + 2 * rng.travel_time_s)
        return Update(ranges, self.locate(now), self.estimate(now + offset))

    def on_modem_range(self, peer: str, travel_time_s: float, method: str,
                       now: float) -> Update:
        """The modem measured a one-way ``travel_time_s`` to ``peer`` (``method`` ``ping`` or
        ``propagation``) at ``now``. Implausible values are counted in :attr:`drops`."""
        if peer == self.node or peer not in self.mission.nodes:
            self.drops["unknown peer"] += 1
            return Update((), None)
        if method not in MODEM_METHODS:
            raise ValueError(f"unknown modem ranging method {method!r} (ping, propagation)")
        if not (math.isfinite(travel_time_s) and 0.0 <= travel_time_s <= MAX_MODEM_TRAVEL_S):
            self.drops["bad travel time"] += 1
            return Update((), None)
        rng = Range(peer, travel_time_s, method, now)
        self.latest[peer] = rng
        if not self.localises:
            return Update((rng,), None)
        self._track(rng, now, 2 * travel_time_s)
        return Update((rng,), self.locate(now), self.estimate(now))

    def _track(self, rng: Range, t: float, span_s: float) -> None:
        """Hand a range to an anchor with a known position to the tracker."""
        if self.tracker is None or rng.peer not in self.anchor_positions:
            return
        self._set_prior(t)
        now_at, sigma, age = self.anchor_at(rng.peer, t)
        before, _, _ = self.anchor_at(rng.peer, t - span_s)
        from bridge.ranging.tracker import RangeObs

        self.tracker.on_range(RangeObs(
            rng.peer, rng.range_m(self.sound_speed_for(rng.peer).mps), t, now_at,
            span_s=span_s, anchor_before=before, anchor_sigma_m=sigma, anchor_age_s=age))

    def estimate(self, now: float) -> Estimate | None:
        """The tracker's estimate at ``now`` (None if this node does not localise)."""
        if self.tracker is None:
            return None
        self.tracker.drop_if_lost(now)
        self._reported_at = now
        return self.tracker.estimate(now)

    def report(self, now: float) -> Estimate | None:
        """The estimate, if nothing was published for :data:`REPORT_EVERY_S` (so that coasting
        and lost tracks are seen without new ranges)."""
        self._set_prior(now)  # the node's first tick: it started (and may move) now
        if self.tracker is None or now - self._reported_at < REPORT_EVERY_S:
            return None
        return self.estimate(now)

    def locate(self, now: float) -> Fix | NoFix:
        """A fix from the fresh ranges to anchors with known positions, or why there is none."""
        names, anchors, ranges = [], [], []
        for anchor in self.anchors:
            rng, pos = self.latest.get(anchor), self.anchor_positions.get(anchor)
            if rng is None or pos is None or now - rng.time > self.fix_max_age_s:
                continue
            names.append(anchor)
            anchors.append(pos)
            ranges.append(rng.range_m(self.sound_speed_for(anchor).mps))
        if self.depth is None:
            return NoFix("no_depth", tuple(names))
        previous = self.track.predict(now) or self.start
        found = attempt(anchors, ranges, self.depth, previous, names=names)
        if isinstance(found, Fix):  # a refused (gated) fix does not steer the next one...
            self._refused_in_row = 0 if self.track.update(now, found) else \
                self._refused_in_row + 1
            if self._refused_in_row >= TRACK_RESTART_AFTER:  # ...unless the track is lost
                self.track.start(now, found.x, found.y, found.sigma_m)
                self._refused_in_row = 0
        return found

    # -- explicit ranging ----------------------------------------------------------------------

    def ping_due(self, now: float) -> str | None:
        """The peer to range to now, or None (not our turn yet, or we do not range)."""
        if not self.ping_peers or now < self._next_ping:
            return None
        return self.ping_peers[self._ping_turn % len(self.ping_peers)]

    def next_ping(self) -> float | None:
        """When the next range is due (``-inf``: now), or None if this node does not range."""
        return self._next_ping if self.ping_peers else None

    def pinged(self, peer: str, now: float) -> None:
        """A range to ``peer`` was asked for at ``now`` (answered or not): next peer's turn."""
        if peer in self.ping_peers:
            self._ping_turn = self.ping_peers.index(peer) + 1
        self._next_ping = now + self.ping_interval_s

    # -- payloads ------------------------------------------------------------------------------

    def range_payload(self, rng: Range) -> Mapping[str, Any]:
        """The map published on ``@zab/<mission>/<node>/range/<peer>``."""
        speed = self.sound_speed_for(rng.peer)
        return {**rng.payload(speed.mps), "sound_speed_source": speed.source}
