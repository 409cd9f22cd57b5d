"""A range-domain tracker for one moving node: an EKF bank over ranges, depth and heading (#16).

Every range is fused as it arrives, at its own time, against the anchor's position at that time
(a moving anchor included); the node's own depth is known (a pressure sensor), so the state is
horizontal only: ``[x, y, vx, vy]`` with white-noise acceleration ``accel_sigma`` (m/s²;
``accel_sigma_steered`` while a heading is coming in, which turns the velocity itself; a
heading without a speed steers only across the velocity: along it, still ``accel_sigma``, as
a compass tells turns, not the speed, which the vehicle holds with or without one).

- Manoeuvres. A small vehicle holds its course and speed, then turns within a second or two:
  next to a range cycle of seconds that is a jump of velocity, which white-noise acceleration
  either lags (small) or pays for on every straight (large). So the acceleration noise is small
  and, without a compass, a range far out asks a generalised likelihood-ratio test whether the
  vehicle turned between recent ranges (:meth:`RangeTracker._jumped`): the turn it likes best
  (at its old speed, any new heading) is taken if it explains those ranges better than none.
  Ranges from one anchor cannot show a turn at all (any turn fits its circle), so beside that
  track components that turned in the gap before each range (a ring of headings, at its speed:
  :mod:`bridge.ranging.turns`, ``turn_every_s``) keep the share a turn not yet seen deserves;
  each filters the ranges itself, the likeliest becomes the track, and the published estimate
  is the mixture. (``turn_every_s = 0``: a second, manoeuvring mode instead,
  ``wide_accel_sigma``, as an interacting-multiple-model filter has it.)

- Range model. A DLBL range (:mod:`bridge.ranging.dlbl`) is half a two-way travel time: leg 1
  left this node ``span_s`` before the reception that completed it, leg 2 arrived at that
  reception. So ``h = ½(|p(t − span) − a₁| + |p(t) − a₂|)`` with slant (3-D) distances from the
  node's depth to the anchor's: the depth difference is in the model, not subtracted first.
  With ``span_s = 0`` it is a plain range. While the position is so wide (a start, a long
  gap) that the range's circle curves off its tangent by more than the range's noise
  across that width, the update is iterated (Gauss-Newton) to the posterior's
  linearisation.
- Heading (and speed), when the node's navigation gives them, are the direction (and length) of
  the velocity; a change of heading also turns the velocity state by the same angle (the
  vehicle turned), so a corner does not need the ranges to discover it. When it turned since
  the last heading, the ranges taken meanwhile (and for ``turn_settle_s`` after) tell: each
  gap between them is a candidate, kept apart and weighted by its length and the ranges'
  likelihood (:meth:`RangeTracker._turned_since`). Heading is taken as course over ground (no
  current is modelled).
- Ambiguity. Ranges alone cannot tell a position from its mirror image across a line of
  anchors. Initialisation takes a least-squares / circle fix (:func:`~bridge.ranging.localise.
  attempt`) and its mirror alternative as hypotheses, weighted by the prior and then by the
  likelihood of every measurement; the state is ``lost`` (``ambiguous``) until one holds
  :data:`RESOLVED_SHARE` of the weight (or, when nothing tells them apart, ``commit_share``
  after ``commit_after_s``; the rest is published as ``mirror_doubt``), and from then on only
  that one is kept: the estimate cannot flip. Until then, whenever no hypothesis is left on
  the other side of the anchors' line (two that met, a first fix whose circles did not meet),
  the best one's image is put back: only weights rule a side out. The prior (e.g. the start
  position) is dead-reckoned with the node's own heading and speed (1-σ growing by
  ``reckon_drift_mps``; without them by ``prior_speed_mps`` per second): in a formation that
  moves with a moving anchor the ranges' motion hardly tells the sides apart, the vehicle's
  own navigation does. Without a compass, ranges to anchors on one line cannot show the
  vehicle crossing it (a trajectory and its image fit alike): a committed track that slides
  over the line is reflected back to the side it committed to (:meth:`RangeTracker._hold_side`).
- Starting. While the node dead-reckons and its prior alone tells the side of the anchors'
  line (``prior_side_sigmas``), the track starts from the prior and takes the recent ranges
  (up to two ``init_window_s`` old) into it, each with its anchor's uncertainty in its noise:
  a moving anchor not yet heard from takes part, weakly. Otherwise from a fix: ranges taken
  earlier are moved to the start time with the node's known velocity (half of each DLBL span
  included); an anchor whose position is uncertain by more than ``init_anchor_sigma_m`` (a
  moving one not yet heard from, or extrapolated from one old report) does not take part
  while the node dead-reckons; without dead reckoning the track starts wide with it and
  starts again once every anchor's position is known.
- Gating. A range whose normalised innovation squared exceeds ``gate_nis`` (χ², one degree of
  freedom) is refused and counted by reason in :attr:`RangeTracker.rejected`: ``long`` (later
  than predicted: multipath, a surface reflection), ``short`` (earlier than possible: a wrong
  clock), plus ``stale_anchor``, ``out_of_order`` and ``not_finite`` before the filter sees it.
  After ``diverged_after`` refusals from two or more anchors within ``2·coast_after_s``,
  outnumbering the ranges accepted meanwhile, the track restarts
  (``lost``, ``diverged``) from a fresh fix, with the old estimate as a broad prior.
- States: ``tracking`` (a range accepted within ``coast_after_s``), ``coasting`` (predicting;
  ``age_s`` says since when), ``lost`` with a reason (:data:`LOST_REASONS`). A lost track has
  no position; nothing published is ever infinite or NaN.

Pure and clock-free: every time is an argument, in seconds on one clock.
"""

from __future__ import annotations

import itertools
import math
from collections import Counter, deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bridge.ranging import kalman
from bridge.ranging.coast import coast_widened
from bridge.ranging.kalman import Matrix, Vector
from bridge.ranging.localise import Fix, attempt
from bridge.ranging.turns import TurnMixture

Anchor = tuple[float, float, float]  # x, y, depth

JUMP_SPEED_SHARE = 0.15
"""1-σ change of speed through a turn, as a share of the speed held before it."""
RESOLVED_SHARE = 0.999
"""Share of the hypotheses' weight the best must hold before the track commits to it."""

ITERATIONS = 5
"""Most Gauss-Newton steps of an iterated range update (:meth:`RangeTracker._range_update`)."""
MERGE_M = 1.0
"""Hypotheses nearer than this are one (the likelier is kept)."""
FRESH_HEADING_S = 0.5
"""A heading younger than this has seen any turn the ranges could suggest (no test then)."""
GATE_NIS_1DOF = 10.83
"""χ² with one degree of freedom at 99.9 %: a range this far out is 1 in 1000 if all is well."""

LOST_REASONS = {
    "no_depth": "this node's depth is unknown",
    "too_few_anchors": "fewer than two anchors with a recent range and a known position",
    "degenerate_geometry": "the anchors' geometry gives no position",
    "ambiguous": "two positions (mirror images) still fit the ranges and the prior",
    "diverged": "ranges kept contradicting the track; restarting from a fresh fix",
    "no_ranges": "no range accepted for too long; the prediction is no longer worth publishing",
}
"""Why a track is ``lost`` (``reason`` of :class:`Estimate`)."""


@dataclass(frozen=True)
class RangeObs:
    """One measured slant range to ``anchor``, completed at ``time``.

    ``span_s``: time from this node's emission of leg 1 to ``time`` (DLBL: the peer's delay
    plus the two-way travel time; 0 for a one-way range). ``anchor_at`` is the anchor's position
    at ``time``, ``anchor_before`` at the start of the span if it moved (default: the same);
    ``anchor_sigma_m`` the uncertainty of those positions; ``anchor_age_s`` how old the
    anchor's position report is.
    """

    anchor: str
    range_m: float
    time: float
    anchor_at: Anchor
    span_s: float = 0.0
    anchor_before: Anchor | None = None
    anchor_sigma_m: float = 0.0
    anchor_age_s: float = 0.0


def profile_at(points: tuple[tuple[float, float], ...], x: float) -> float:
    """A profile of (x, value) points at rising x, at ``x``: linear between points, held
    beyond the first and the last."""
    if x <= points[0][0]:
        return points[0][1]
    for (x0, v0), (x1, v1) in itertools.pairwise(points):
        if x <= x1:
            return v0 + (v1 - v0) * (x - x0) / (x1 - x0)
    return points[-1][1]


@dataclass(frozen=True)
class TrackerConfig:
    """Noise figures and limits; defaults suit a small AUV at 0.5–2 m/s and DLBL ranges."""

    range_sigma_m: float = 0.1
    range_sigma_at: tuple[tuple[float, float], ...] = ()  # (distance m, 1-σ m), rising
    # distances, linear between and held beyond: a measured noise profile (seed 001 fig. 8);
    # empty: ``range_sigma_m`` at every distance
    accel_sigma: float = 0.03
    accel_sigma_steered: float = 0.08  # while a heading steers the velocity (without a
    # speed: only across it, ``accel_sigma`` along it)
    heading_sigma_deg: float = 3.0
    speed_sigma_mps: float = 0.1
    max_speed_mps: float = 2.5
    jump_window_s: float = 2.5  # how far back a manoeuvre (a jump of velocity) is looked for
    jump_steps: int = 6  # ... and at least so many ranges back
    jump_test_nis: float = 2.0  # a range this far out asks whether the vehicle manoeuvred
    jump_min_llr: float = 2.0  # log-likelihood a manoeuvre must gain over none to be taken
    jump_even_llr: float = 1.0  # ... and one not taken is as likely as none in the estimate
    # (prior odds e⁻¹: a turn within a test's window, every ~10 s of sailing)
    jump_steered_even_llr: float = 4.0  # with a compass (a turn since its last heading, ~2 %)
    jump_ring_deg: float = 45.0  # the turns a manoeuvre test tries: a ring, every so many °
    gate_nis: float = GATE_NIS_1DOF
    coast_after_s: float = 6.0
    lost_after_s: float = 120.0
    max_sigma_m: float = 30.0
    init_window_s: float = 6.0
    anchor_max_age_s: float = 60.0
    max_lag_s: float = 10.0
    diverged_after: int = 6
    manoeuvre_window_s: float = 2.5
    prune_share: float = 1e-6
    min_heading_speed_mps: float = 0.2
    prior_speed_mps: float = 1.0
    commit_after_s: float = 20.0
    commit_share: float = 0.95
    init_anchor_sigma_m: float = 3.0  # anchors less certain than this do not start a track
    collinear_m: float = 1.0  # anchors this near one line leave a mirror image
    reckon_drift_mps: float = 0.1  # dead reckoning's 1-σ growth (current, log error)
    prior_side_sigmas: float = 3.0  # a dead-reckoned prior this far from the anchors' line
    # (in its and the anchors' 1-σ) tells the side by itself: the track starts from it
    wide_accel_sigma: float = 2.0  # without a compass, a second mode's (manoeuvring; 0: none)
    wide_enter_s: float = 100.0  # ... entered once in so many seconds
    wide_leave_s: float = 2.0  # ... and left after about so long
    turn_every_s: float = 10.0  # without a compass, a turn's prior: once in so long (0: no
    # turned components, :mod:`bridge.ranging.turns`; the manoeuvring mode instead)
    turn_ring_deg: float = 45.0  # ... the turns each gap may hide: a ring, every so many °
    turn_prune_share: float = 1e-2  # ... a turned component less likely than this is dropped
    turn_settle_s: float = 1.5  # a turn the compass shows: when it came is open so long
    # (a DLBL range that follows spans it); 0: merged at the heading
    coast_turn_every_s: float = 10.0  # without a compass, coasting past ``coast_after_s``
    # widens the track by the turns it may have made meanwhile (:mod:`bridge.ranging.coast`;
    # 0: not)


@dataclass(frozen=True)
class Prior:
    """Where the node was believed to be at ``time`` (e.g. its last GNSS fix before diving)."""

    time: float
    x: float
    y: float
    sigma_m: float = 2.0


@dataclass
class _Reckoning:
    """The prior carried forward by this node's own heading and speed (dead reckoning)."""

    prior: Prior
    time: float
    x: float
    y: float
    sigma: float
    velocity: tuple[float, float] | None = None  # from the latest heading and speed

    def advanced(self, t: float, config: TrackerConfig) -> _Reckoning:
        """Carried to ``t``: along the last velocity for up to ``coast_after_s`` (1-σ growing
        by ``reckon_drift_mps``), beyond that as unknown motion (``prior_speed_mps``)."""
        dt = t - self.time
        if dt <= 0:
            return self
        if self.velocity is None or dt > config.coast_after_s:
            return _Reckoning(self.prior, t, self.x, self.y,
                              math.hypot(self.sigma, config.prior_speed_mps * dt), None)
        vx, vy = self.velocity
        return _Reckoning(self.prior, t, self.x + vx * dt, self.y + vy * dt,
                          self.sigma + config.reckon_drift_mps * dt, self.velocity)


@dataclass
class _Hypothesis:
    x: np.ndarray  # [x, y, vx, vy]
    p: np.ndarray  # 4×4
    time: float
    log_w: float = 0.0
    heading: float | None = None  # radians, compass convention, last one applied
    heading_time: float = 0.0
    turns: list[tuple[float, np.ndarray]] = field(default_factory=list)  # (when, v before)
    steps: list[_Step] = field(default_factory=list)  # recent ranges, for a manoeuvre test
    blend: tuple[float, float, np.ndarray, np.ndarray] | None = None  # time, share, x, p
    pending: list[tuple[float, _Hypothesis]] = field(default_factory=list)  # turn times
    pending_until: float = 0.0  # ... kept apart until then (:meth:`RangeTracker._turned_since`)


_Taken = tuple[RangeObs, Vector, Matrix, float, float, float, bool]
"""A range taken again: the observation, the state before it (a vector, a covariance, its
time), and the log-likelihood, NIS and acceptance it had."""


@dataclass
class _Step:
    """One range as a hypothesis took it: its state just before, and what the range did."""

    obs: RangeObs
    x: np.ndarray
    p: np.ndarray
    time: float
    turns: list[tuple[float, np.ndarray]]
    loglik: float
    nis: float
    accepted: bool


@dataclass(frozen=True)
class Estimate:
    """What the tracker says at ``time``: a state, and a position unless ``lost``."""

    state: str  # tracking | coasting | lost
    time: float
    x: float = 0.0
    y: float = 0.0
    depth: float = 0.0
    vx: float = 0.0
    vy: float = 0.0
    cov: tuple[tuple[float, float], tuple[float, float]] = ((0.0, 0.0), (0.0, 0.0))
    age_s: float = 0.0
    reason: str | None = None
    anchors: tuple[str, ...] = ()
    ranges: Mapping[str, float] = field(default_factory=dict)
    candidates: tuple[tuple[float, float], ...] = ()
    doubt: float = 0.0  # the weight the mirror image still had when the track committed

    @property
    def has_position(self) -> bool:
        return self.state != "lost"

    @property
    def sigma_m(self) -> float:
        """1-σ horizontal error radius, √(σx² + σy²)."""
        return math.sqrt(max(self.cov[0][0] + self.cov[1][1], 0.0))

    def ellipse(self) -> tuple[float, float, float]:
        """The 1-σ error ellipse: semi-axes (major, minor) in metres and the major axis's angle
        in degrees anticlockwise from east."""
        (a, b), (_, d) = self.cov
        mean, diff = (a + d) / 2, math.hypot((a - d) / 2, b)
        angle = 0.5 * math.degrees(math.atan2(2 * b, a - d))
        return math.sqrt(max(mean + diff, 0.0)), math.sqrt(max(mean - diff, 0.0)), angle

    def payload(self, time: float | None = None) -> dict[str, Any]:
        """The map published on ``@zab/<mission>/<node>/position``; every number finite."""
        when = self.time if time is None else time
        if not self.has_position:
            out: dict[str, Any] = {
                "fix": False, "state": "lost", "reason": self.reason,
                "detail": LOST_REASONS.get(self.reason or "", ""),
                "anchors": list(self.anchors), "time": when,
            }
            if self.candidates:
                out["candidates"] = [list(c) for c in self.candidates]
            return _finite(out)
        major, minor, angle = self.ellipse()
        return _finite({
            "fix": True, "state": self.state, "method": "ekf",
            "x": self.x, "y": self.y, "depth": self.depth, "vx": self.vx, "vy": self.vy,
            "cov": [list(row) for row in self.cov], "sigma_m": self.sigma_m,
            "ellipse": {"major_m": major, "minor_m": minor, "angle_deg": angle},
            "age_s": self.age_s, "anchors": list(self.anchors), "ranges": dict(self.ranges),
            "time": when, **({"mirror_doubt": self.doubt} if self.doubt >= 1e-3 else {}),
        })


def _finite(value: Any) -> Any:
    """``value`` with every float checked finite (a bug otherwise, never published)."""
    if isinstance(value, float) and not math.isfinite(value):
        raise ValueError("a tracker payload must not hold inf or NaN")
    if isinstance(value, dict):
        for v in value.values():
            _finite(v)
    elif isinstance(value, list):
        for v in value:
            _finite(v)
    return value


def _cross(u: np.ndarray, v: np.ndarray) -> float:
    """The z of the cross product of two horizontal vectors (positive: ``v`` left of ``u``)."""
    return float(u[0] * v[1] - u[1] * v[0])


def _line_through(points: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray] | None:
    """(a point, a unit direction) of the line through the two points furthest apart; None
    when fewer than two points are more than :data:`MERGE_M` apart."""
    if len(points) < 2:
        return None
    a, b = max(((p, q) for i, p in enumerate(points) for q in points[i + 1:]),
               key=lambda pq: float(np.linalg.norm(pq[1] - pq[0])))
    length = float(np.linalg.norm(b - a))
    return None if length < MERGE_M else (a, (b - a) / length)


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi


@dataclass(frozen=True)
class Outcome:
    """What one measurement did: ``accepted``, or refused with ``reason``; ``nis`` if tested."""

    accepted: bool
    reason: str | None = None
    nis: float | None = None


class RangeTracker:
    """Tracks one node from its ranges to anchors, its depth and (optionally) heading/speed."""

    def __init__(self, config: TrackerConfig | None = None, prior: Prior | None = None,
                 depth: float | None = None) -> None:
        self.config = config or TrackerConfig()
        self.prior = prior
        self.depth = depth
        self.hypotheses: list[_Hypothesis] = []
        self.resolved = False
        self.rejected: Counter[str] = Counter()
        self.accepted = 0
        self.restarts = 0
        self.last_range_time: float | None = None
        self.lost_reason = "too_few_anchors" if depth is not None else "no_depth"
        self._recent: dict[str, RangeObs] = {}  # latest range per anchor (initialisation)
        self._used: dict[str, float] = {}  # anchor -> last accepted range (m)
        self._used_at: dict[str, float] = {}  # ... and its time
        self._refusals: list[tuple[RangeObs, str]] = []  # recent refused ranges, and why
        self._heading: tuple[float, float, float | None] | None = None  # time, rad, speed
        self.manoeuvres = 0
        self._accepted_at: deque[float] = deque(maxlen=64)  # times of recent accepted ranges
        self._now = 0.0  # the latest measurement's time
        self._agreed_at: dict[str, float] = {}  # anchor -> its last accepted range's time
        self._ambiguous_since: float | None = None
        self.doubt = 0.0  # the share of weight the committed hypothesis's rivals held
        self._reckoning: _Reckoning | None = None
        self._provisional = False  # started on an anchor whose position was uncertain
        self.folds = 0  # times a committed track slid over the anchors' line, reflected back
        self._side: np.ndarray | None = None  # a point on the committed side of that line
        self._wide: _Hypothesis | None = None  # the manoeuvring mode (:meth:`_mode_update`)
        self._wide_share = 0.0  # ... its probability
        self._turns: TurnMixture | None = None  # turned components (:meth:`_turns_prepare`)
        self._line_memo: tuple[tuple[RangeObs, ...],
                               tuple[np.ndarray, np.ndarray] | None] | None = None

    # -- inputs --------------------------------------------------------------------------------

    def set_depth(self, depth: float) -> None:
        """This node's depth (m, positive down), from its own sensor."""
        if math.isfinite(depth):
            self.depth = depth
            if self.lost_reason == "no_depth":
                self.lost_reason = "too_few_anchors"

    def on_heading(self, t: float, heading_deg: float, speed_mps: float | None = None) -> Outcome:
        """The node's compass heading (degrees clockwise from north) and, if known, its speed
        through the water at ``t``."""
        if not math.isfinite(heading_deg) or (speed_mps is not None
                                              and not math.isfinite(speed_mps)):
            self.rejected["not_finite"] += 1
            return Outcome(False, "not_finite")
        theta = math.radians(heading_deg)
        self._heading = (t, theta, speed_mps)
        self._now = max(self._now, t)
        self._reckon(t, theta, speed_mps)
        if not self.hypotheses:
            return Outcome(False, "not_started")
        cfg = self.config
        worst = 0.0
        for hyp in self.hypotheses:
            if t < hyp.time - cfg.max_lag_s:
                continue
            self._settle(hyp)
            self._predict(hyp, max(t, hyp.time))
            turned = _wrap(theta - hyp.heading) if hyp.heading is not None else 0.0
            noise = math.radians(cfg.heading_sigma_deg)
            if hyp.heading is None or abs(turned) > 3 * noise:
                if turned:  # the vehicle turned, so did its velocity; compass noise does not
                    self._turned_since(hyp, turned, t)
                hyp.heading = theta
            hyp.heading_time = t
            if speed_mps is not None:
                nis = self._speed_update(hyp, speed_mps)
                worst = max(worst, nis)
            speed = math.hypot(hyp.x[2], hyp.x[3])
            if speed >= cfg.min_heading_speed_mps:
                worst = max(worst, self._heading_update(hyp, theta, speed))
        self._normalise()
        return Outcome(True, None, worst)

    def on_range(self, obs: RangeObs) -> Outcome:
        """Fuse one range; refused ranges are counted in :attr:`rejected` by reason."""
        cfg = self.config
        if not (math.isfinite(obs.range_m) and obs.range_m >= 0 and math.isfinite(obs.time)
                and all(map(math.isfinite, obs.anchor_at)) and math.isfinite(obs.span_s)):
            return self._refuse("not_finite")
        if obs.anchor_age_s > cfg.anchor_max_age_s:
            return self._refuse("stale_anchor")
        if self.last_range_time is not None and obs.time < self.last_range_time - cfg.max_lag_s:
            return self._refuse("out_of_order")
        self._recent[obs.anchor] = obs
        self._now = max(self._now, obs.time)
        if self.depth is None:
            self.lost_reason = "no_depth"
            return Outcome(False, "no_depth")
        if not self.hypotheses:
            return self._start(obs.time)
        if self._provisional and obs.anchor_sigma_m <= cfg.init_anchor_sigma_m and sum(
                obs.time - o.time <= cfg.init_window_s
                and o.anchor_sigma_m <= cfg.init_anchor_sigma_m
                for o in self._recent.values()) >= 2:
            self._drop()  # started on an anchor whose position was a guess: start again
            return self._start(obs.time)
        worst_nis, refused = math.inf, True
        self._after_coast(obs.time)
        wide = self._mode_prepare(obs)
        turns = self._turns_prepare(obs)
        for hyp in self.hypotheses:
            log_w = hyp.log_w
            nis, ok = self._take_range(hyp, obs)
            if wide is not None and hyp is self.hypotheses[0]:
                self._mode_update(wide, hyp, obs)
            if turns is not None and hyp is self.hypotheses[0]:
                took = self._turns_update(turns, hyp, obs, hyp.log_w - log_w)
                ok = ok if took is None else took
            worst_nis = min(worst_nis, nis)
            refused = refused and not ok
        self._normalise()
        self._refusals = [(o, r) for o, r in self._refusals
                          if obs.time - o.time <= 2 * cfg.coast_after_s]
        if refused and self._manoeuvred(obs):
            refused = False
            self._normalise()  # the side held (:meth:`_hold_side`) after this update too
        if refused:  # refused by every hypothesis: a bad range (or a diverged track)
            reason = "long" if self._innovation_sign(obs) > 0 else "short"
            self._refusals.append((obs, reason))
            outcome = self._refuse(reason, worst_nis)
            window = 2 * cfg.coast_after_s
            taken = sum(obs.time - t <= window for t in self._accepted_at)
            if (len(self._refusals) >= cfg.diverged_after and len(self._refusals) > taken
                    and len({o.anchor for o, _ in self._refusals}) >= 2):
                self._restart(obs.time)
            return outcome
        self.accepted += 1
        self._accepted_at.append(obs.time)
        self._agreed_at[obs.anchor] = obs.time
        self.last_range_time = max(self.last_range_time or obs.time, obs.time)
        self._used[obs.anchor] = obs.range_m
        self._used_at[obs.anchor] = obs.time
        return Outcome(True, None, worst_nis)

    # -- output --------------------------------------------------------------------------------

    def estimate(self, t: float) -> Estimate:
        """The state at ``t``: position predicted to ``t`` unless the track is lost."""
        cfg = self.config
        anchors, ranges = self._listed()
        if not self.hypotheses:
            return Estimate("lost", t, reason=self.lost_reason, anchors=anchors)
        if not self.resolved:
            cands = tuple((float(h.x[0]), float(h.x[1])) for h in self.hypotheses)
            return Estimate("lost", t, reason="ambiguous", anchors=anchors, candidates=cands)
        hyp = self.hypotheses[0]
        age = t - (self.last_range_time if self.last_range_time is not None else hyp.time)
        x, p = hyp.x, hyp.p
        if hyp.blend is not None and hyp.blend[0] == hyp.time:  # a manoeuvre, perhaps
            _, share, jx, jp = hyp.blend
            mean = (1 - share) * x + share * jx
            p = (1 - share) * (p + np.outer(x - mean, x - mean)) + share * (
                jp + np.outer(jx - mean, jx - mean))
            x = mean
        x, p = _predicted(x, p, max(t - hyp.time, 0.0), *self._accel(t))
        if self._turns is not None and not self._steered(t):
            x, p = self._turns.moments(x, p, t, lambda cx, cp, dt: _predicted(
                cx, cp, dt, cfg.accel_sigma))
        wide = self._wide
        if wide is not None and not self._steered(t):
            mu = self._wide_share
            wx, wp = _predicted(wide.x, wide.p, max(t - wide.time, 0.0), cfg.wide_accel_sigma)
            mean = (1 - mu) * x + mu * wx
            p = (1 - mu) * (p + np.outer(x - mean, x - mean)) + mu * (
                wp + np.outer(wx - mean, wx - mean))
            x = mean
        p = self._coasted(x, p, t, age)
        sigma = math.sqrt(max(p[0, 0] + p[1, 1], 0.0))
        if age > cfg.lost_after_s or not math.isfinite(sigma) or sigma > cfg.max_sigma_m:
            return Estimate("lost", t, reason="no_ranges", anchors=anchors)
        state = "tracking" if age <= cfg.coast_after_s else "coasting"
        cov = ((float(p[0, 0]), float(p[0, 1])), (float(p[1, 0]), float(p[1, 1])))
        return Estimate(state, t, float(x[0]), float(x[1]), float(self.depth or 0.0),
                        float(x[2]), float(x[3]), cov, max(age, 0.0), None, anchors,
                        ranges, doubt=self.doubt)

    def _listed(self) -> tuple[tuple[str, ...], dict[str, float]]:
        """The anchors an estimate names, with their latest ranges: those the track used
        within ``coast_after_s`` of its latest range (an anchor gone silent drops out); without
        a track, those heard within ``init_window_s`` (the ones a start could take)."""
        cfg = self.config
        if not self.hypotheses:
            heard = sorted(a for a, o in self._recent.items()
                           if self._now - o.time <= cfg.init_window_s)
            return tuple(heard), {}
        latest = max(self._used_at.values(), default=0.0)
        used = sorted(a for a in self._used
                      if latest - self._used_at.get(a, latest) <= cfg.coast_after_s)
        return tuple(used), {a: self._used[a] for a in used}

    def drop_if_lost(self, t: float) -> None:
        """Forget a track whose estimate at ``t`` is ``lost`` (``no_ranges``): the next ranges
        start afresh, with its last estimate as a broad prior."""
        if self.resolved and self.estimate(t).reason == "no_ranges":
            self._restart(t, reason="no_ranges")

    # -- internals -----------------------------------------------------------------------------

    def _coasted(self, x: np.ndarray, p: np.ndarray, t: float, age: float) -> np.ndarray:
        """``p`` widened by the turns a track without a compass may have made in the
        ``age - coast_after_s`` seconds it coasted beyond its range cycle (:mod:`.coast`)."""
        cfg = self.config
        gap = age - cfg.coast_after_s
        if gap <= 0 or self._steered(t):
            return p
        return np.array(coast_widened(x.tolist(), p.tolist(), gap, cfg.coast_turn_every_s))

    def _after_coast(self, t: float) -> None:
        """A range after the track coasted past ``coast_after_s``: the hypotheses take it as
        wide as the turns they may have missed make them (:meth:`_coasted`), the turned
        components and the manoeuvring mode start again from them."""
        if self.last_range_time is None or not self.resolved:
            return
        age = t - self.last_range_time
        if age <= self.config.coast_after_s or self._steered(t):
            return
        for hyp in self.hypotheses:
            self._settle(hyp)
            self._predict(hyp, t)
            hyp.p = self._coasted(hyp.x, hyp.p, t, age)
        self._turns = None
        self._wide = None

    def _refuse(self, reason: str, nis: float | None = None) -> Outcome:
        self.rejected[reason] += 1
        return Outcome(False, reason, nis)

    def _manoeuvred(self, obs: RangeObs) -> bool:
        """Ranges refused in a row within ``manoeuvre_window_s`` (three; two without a compass):
        the vehicle may have turned or changed speed. Allow the velocity change such a manoeuvre
        could make since those anchors last agreed with the track, and take the ranges if all
        then fit one motion (each within 2 σ after the update, which unrelated outliers rarely
        do); else leave the track as it was."""
        cfg = self.config
        recent = [(o, r) for o, r in self._refusals
                  if obs.time - o.time <= cfg.manoeuvre_window_s]
        anchors = {o.anchor for o, _ in recent} | {obs.anchor}
        steered = self._steered(obs.time)
        # with a compass, turns are known: it takes three refusals; without, turns are the
        # usual reason and two (one anchor's in a row) are enough
        if not self.resolved or len(recent) < (2 if steered else 1):
            return False
        hyp = self.hypotheses[0]
        saved = (hyp.x.copy(), hyp.p.copy(), hyp.time, hyp.log_w)
        # since when the track may have been off: the last range accepted (without a compass:
        # the last these anchors agreed with, others' ranges may not see the turn)
        agreed = [self._agreed_at.get(a, obs.time - cfg.manoeuvre_window_s) for a in anchors]
        since = max(obs.time - (self.last_range_time or obs.time) if steered
                    else obs.time - min(agreed), 0.0)
        dv = max(math.hypot(hyp.x[2], hyp.x[3]), 0.5) * math.sqrt(2)  # up to a right angle
        hyp.p[2, 2] += dv * dv
        hyp.p[3, 3] += dv * dv
        hyp.p[0, 0] += (dv * since) ** 2 / 3
        hyp.p[1, 1] += (dv * since) ** 2 / 3
        tried = [o for o, _ in recent] + [obs]
        if all(self._range_update(hyp, o)[1] for o in tried) and all(
                (o.range_m - self._range_model(hyp, o)[0]) ** 2
                <= 4 * self._range_sigma(o.range_m) ** 2 + o.anchor_sigma_m**2 for o in tried):
            for _, reason in recent:  # it was the track that was wrong, not those ranges
                self.rejected[reason] -= 1
                if self.rejected[reason] <= 0:
                    del self.rejected[reason]
            self._refusals.clear()
            self.manoeuvres += 1
            return True
        hyp.x, hyp.p, hyp.time, hyp.log_w = saved
        return False

    def _innovation_sign(self, obs: RangeObs) -> float:
        hyp = max(self.hypotheses, key=lambda h: h.log_w)
        predicted, _ = self._range_model(hyp, obs)
        return obs.range_m - predicted

    def _start(self, t: float) -> Outcome:
        """Try to initialise from the latest range to each anchor (within the window)."""
        cfg = self.config
        assert self.depth is not None
        # an anchor whose position is uncertain (a moving one not yet heard from, or heard once
        # long ago) can put both candidates elsewhere, mirror pair included: while this node
        # dead-reckons (its prior stays good) it waits for that anchor's position; without, it
        # starts wide and starts again once every anchor's position is known
        recent = [o for o in self._recent.values() if t - o.time <= cfg.init_window_s]
        # dead reckoning carries older ranges too: one lost frame need not cost a cycle
        reckoned = [o for o in self._recent.values() if t - o.time <= 2 * cfg.init_window_s]
        if self._reckoned(t) and len(reckoned) >= 2 and self._start_from_prior(t, reckoned):
            return Outcome(True, "started")
        known = [o for o in recent if o.anchor_sigma_m <= cfg.init_anchor_sigma_m]
        fresh = known if len(known) >= 2 or self._reckoned(t) else recent
        self._provisional = len(fresh) > len(known)
        if len(fresh) < 2:
            self.lost_reason = "too_few_anchors"
            return Outcome(False, "too_few_anchors")
        reference = self._prior_at(t)
        # a range is from where the node was halfway through its span, to the anchor then:
        # with the velocity known (heading and speed), that is a range from where it is now to
        # the anchor moved along by the same; without, the spread of times is in the sigma
        velocity, v_sigma = self._known_velocity(t)
        anchors: list[Anchor] = []
        for o in fresh:
            before = o.anchor_before or o.anchor_at
            back = t - o.time + o.span_s / 2 if v_sigma < cfg.max_speed_mps else 0.0
            anchors.append(((before[0] + o.anchor_at[0]) / 2 + velocity[0] * back,
                            (before[1] + o.anchor_at[1]) / 2 + velocity[1] * back,
                            (before[2] + o.anchor_at[2]) / 2))
        ranges = [o.range_m for o in fresh]
        guess = (reference[0], reference[1]) if reference is not None else \
            (sum(a[0] for a in anchors) / len(anchors) + 1.0,
             sum(a[1] for a in anchors) / len(anchors) + 1.0)
        spread = max(o.time for o in fresh) - min(o.time for o in fresh)
        if v_sigma < cfg.max_speed_mps:
            spread = 2 * max(t - o.time + o.span_s / 2 for o in fresh)
        # ranges taken at other times (the node moved meanwhile) and anchors' uncertainty are
        # errors of the ranges: the geometry magnifies them as it does the ranges' own noise
        # (far from a short baseline, circles nearly tangent: tens of metres)
        moved = math.hypot(v_sigma * spread / 2, max(o.anchor_sigma_m for o in fresh))
        wide = math.hypot(cfg.range_sigma_m, moved)
        found = attempt(anchors, ranges, self.depth, guess, names=[o.anchor for o in fresh],
                        range_sigma_m=wide)
        if not isinstance(found, Fix):
            self.lost_reason = found.reason
            return Outcome(False, found.reason)
        if not math.isfinite(found.sigma_m) or found.sigma_m > cfg.max_sigma_m:
            # e.g. on the anchors' line, or far away with ranges of different times: no
            # telling yet (fresher ranges will)
            self.lost_reason = "degenerate_geometry"
            return Outcome(False, "degenerate_geometry")
        # without a compass the track's velocity is the ranges' alone: the start is as wide as
        # the geometry makes the motion; with one, the heading pulls it in (as before: the
        # geometry's on the range noise alone)
        magnified = found.sigma_m if not self._steered(t) else found.sigma_m / wide * \
            cfg.range_sigma_m
        sigma = math.hypot(magnified, moved, cfg.range_sigma_m)
        points = [(found.x, found.y)]
        if found.alternative is not None and math.dist(found.alternative, points[0]) > 1.0:
            points.append(found.alternative)  # the mirror image: motion and prior decide
        self.hypotheses = [self._hypothesis(pt, sigma, t, reference) for pt in points]
        self._normalise()
        self.last_range_time = t
        self._used = {o.anchor: o.range_m for o in fresh}
        self._used_at = {o.anchor: o.time for o in fresh}
        self._refusals.clear()
        return Outcome(True, "started")

    def _start_from_prior(self, t: float, recent: list[RangeObs]) -> bool:
        """Start from the dead-reckoned prior and fuse the recent ranges into it, each with its
        anchor's uncertainty in its noise (a moving anchor not yet heard from included), when
        the prior alone tells the side of the anchors' line: it lies further from that line
        than ``prior_side_sigmas`` times its and the anchors' 1-σ (else the mirror image is
        not ruled out, and a fix with both candidates starts the track). False if not started
        (or the ranges disagree with the prior)."""
        cfg = self.config
        reference = self._prior_at(t)
        if reference is None:
            return False
        x, y, sigma = reference
        spread = math.hypot(sigma, max(o.anchor_sigma_m for o in recent))
        points = [np.array(o.anchor_at[:2], dtype=float) for o in recent]
        line = _line_through(points)
        if line is None:
            return False
        a, u = line
        here = np.array([x, y])
        if all(abs(_cross(u, p - a)) <= cfg.collinear_m + spread for p in points) and abs(
                _cross(u, here - a)) < cfg.prior_side_sigmas * spread:
            return False
        hyp = self._hypothesis((x, y), sigma, t, None)
        taken = sum(self._range_update(hyp, o)[1] for o in sorted(recent, key=lambda o: o.time))
        if 2 * taken <= len(recent):
            return False  # the prior and the ranges disagree: start from a fix instead
        hyp.log_w = 0.0
        self.hypotheses = [hyp]
        self.resolved = True
        self._commit_side()
        self._provisional = False
        self._ambiguous_since = None
        self.last_range_time = t
        self._used = {o.anchor: o.range_m for o in recent}
        self._used_at = {o.anchor: o.time for o in recent}
        self._refusals.clear()
        return True

    def _prior_at(self, t: float) -> tuple[float, float, float] | None:
        """The prior position and its 1-σ (m) at ``t``: dead-reckoned from the prior's time
        with this node's heading and speed where they came, else grown by how far the node may
        have gone since."""
        if self.prior is None:
            return None
        r = self._reckoning
        if r is not None and r.prior is self.prior:
            r = r.advanced(t, self.config)
            return (r.x, r.y, r.sigma)
        grown = self.config.prior_speed_mps * max(t - self.prior.time, 0.0)
        return (self.prior.x, self.prior.y, math.hypot(self.prior.sigma_m, grown))

    def _reckoned(self, t: float) -> bool:
        """Whether the prior is being dead-reckoned with a heading and speed, recently."""
        r = self._reckoning
        return r is not None and r.prior is self.prior and r.velocity is not None \
            and t - r.time <= self.config.coast_after_s

    def _reckon(self, t: float, theta: float, speed: float | None) -> None:
        """Carry the prior forward to ``t`` with the heading and speed that held until now;
        from now on with ``theta`` and ``speed`` (none: unknown motion)."""
        prior = self.prior
        if prior is None or t < prior.time:
            return
        r = self._reckoning
        if r is None or r.prior is not prior:
            r = _Reckoning(prior, prior.time, prior.x, prior.y, prior.sigma_m)
        if t < r.time:
            return
        r = r.advanced(t, self.config)
        r.velocity = None if speed is None else (speed * math.sin(theta),
                                                 speed * math.cos(theta))
        self._reckoning = r

    def _known_velocity(self, t: float) -> tuple[tuple[float, float], float]:
        """This node's velocity from a recent heading and speed, and its 1-σ per axis; without
        them none, give or take ``max_speed_mps``."""
        cfg = self.config
        if self._heading is not None and t - self._heading[0] <= cfg.init_window_s:
            _, heading, speed = self._heading
            if speed is not None:
                return ((speed * math.sin(heading), speed * math.cos(heading)),
                        max(cfg.speed_sigma_mps * 3, 0.3))
        return (0.0, 0.0), cfg.max_speed_mps

    def _hypothesis(self, point: tuple[float, float], sigma: float, t: float,
                    reference: tuple[float, float, float] | None) -> _Hypothesis:
        cfg = self.config
        v_sigma = cfg.max_speed_mps / 2
        v = np.zeros(2)
        heading = None
        if self._heading is not None and t - self._heading[0] <= cfg.init_window_s:
            heading = self._heading[1]
            known, spread = self._known_velocity(t)
            if spread < cfg.max_speed_mps:
                v, v_sigma = np.array(known), spread
        x = np.array([point[0], point[1], v[0], v[1]], dtype=float)
        p = np.diag([sigma**2, sigma**2, v_sigma**2, v_sigma**2])
        log_w = 0.0
        if reference is not None:
            s2 = reference[2] ** 2 + sigma**2
            d2 = (point[0] - reference[0]) ** 2 + (point[1] - reference[1]) ** 2
            log_w = -0.5 * d2 / s2
        return _Hypothesis(x, p, t, log_w, heading, t)

    def _restart(self, t: float, reason: str = "diverged") -> None:
        """Drop the track; the next ranges start a new one, the old estimate a broad prior."""
        if self.hypotheses:
            best = max(self.hypotheses, key=lambda h: h.log_w)
            sigma = math.sqrt(max(best.p[0, 0] + best.p[1, 1], 0.0)) + 5.0
            self.prior = Prior(best.time, float(best.x[0]), float(best.x[1]), sigma)
        self._drop()
        self.restarts += 1
        self.lost_reason = reason

    def _drop(self) -> None:
        """Forget the hypotheses (the prior stays)."""
        self.hypotheses = []
        self.resolved = False
        self._provisional = False
        self._ambiguous_since = None
        self.doubt = 0.0
        self._side = None
        self._wide = None
        self._turns = None
        self._refusals.clear()
        self._used.clear()
        self._used_at.clear()

    def _normalise(self) -> None:
        """Weights relative to the best; drop the unlikely; keep the best's mirror image in the
        bank until the weights decide; commit once one dominates."""
        if not self.hypotheses:
            return
        top = max(h.log_w for h in self.hypotheses)
        for h in self.hypotheses:
            h.log_w -= top
        cfg = self.config
        floor = math.log(cfg.prune_share)
        kept: list[_Hypothesis] = []
        for h in sorted(self.hypotheses, key=lambda h: -h.log_w):
            if h.log_w < floor:
                continue
            if all(math.dist(h.x[:2], k.x[:2]) > MERGE_M for k in kept):
                kept.append(h)  # two that met (e.g. near the anchors' line) are one
        self.hypotheses = kept
        # two that met, or a first fix without a second candidate (circles that did not meet),
        # have not ruled out the mirror image: only weights may, so it is put back
        on_line = not self.resolved and self._keep_mirror()
        share = 1.0 / sum(math.exp(h.log_w) for h in self.hypotheses)
        waited = self._now - (self._ambiguous_since if self._ambiguous_since is not None
                              else self._now)
        if len(self.hypotheses) > 1 and (share >= RESOLVED_SHARE or (
                waited >= cfg.commit_after_s and share >= cfg.commit_share)):
            # decided by the data, or (when nothing can tell mirror images apart, e.g. anchors
            # on one line and no heading) by the prior after a while: the doubt is published
            self.hypotheses = self.hypotheses[:1]
            self.doubt = 1.0 - share
        if len(self.hypotheses) == 1 and (not on_line or waited >= cfg.commit_after_s):
            if not self.resolved:
                self._commit_side()
            self.resolved = True
            self._ambiguous_since = None
        elif self._ambiguous_since is None:
            self._ambiguous_since = self._now
        if self.resolved and len(self.hypotheses) == 1:
            self._hold_side()  # committed just now on the line, its side the prior's: held too

    def _mirror_line(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(a point, a unit direction) of the line the anchors heard lie on, if they do (two
        anchors always do): ranges cannot tell a position from its image across it."""
        cfg = self.config
        heard = tuple(o for o in self._recent.values()
                      if self._now - o.time <= cfg.anchor_max_age_s)
        if self._line_memo is not None and self._line_memo[0] == heard:
            return self._line_memo[1]  # every trial of a manoeuvre test, every heading asks
        points = [np.array(o.anchor_at[:2], dtype=float) for o in heard]
        line = _line_through(points)
        if line is not None:
            a, u = line
            a.flags.writeable = u.flags.writeable = False  # shared by every caller
            if any(abs(_cross(u, p - a)) > cfg.collinear_m for p in points):
                line = None  # anchors off one line: no mirror image fits every range
        self._line_memo = (heard, line)
        return line

    def _keep_mirror(self) -> bool:
        """Put the best hypothesis's mirror image back in the bank if no hypothesis is on the
        other side of the anchors' line, weighted as the best but for the prior (the ranges fit
        both alike). True if the best lies on that line (its image is itself: which side it
        will go is unknown)."""
        line = self._mirror_line()
        if line is None or not self.hypotheses:
            return False
        best = self.hypotheses[0]
        a, u = line
        side = _cross(u, best.x[:2] - a)
        if abs(side) <= MERGE_M / 2:
            return True
        if any(_cross(u, h.x[:2] - a) * side < 0 for h in self.hypotheses[1:]):
            return False  # the other side is in the bank already
        reflect = 2 * np.outer(u, u) - np.eye(2)
        image = a + reflect @ (best.x[:2] - a)
        # with a compass the velocity is the vehicle's on either side; without one the image
        # of the whole trajectory fits the ranges as well, velocity reflected too
        steered = self._heading is not None and \
            self._now - self._heading[0] <= self.config.coast_after_s
        g = np.eye(4)
        g[:2, :2] = reflect
        if not steered:
            g[2:, 2:] = reflect
        x = g @ best.x
        x[:2] = image
        log_w = best.log_w
        reference = self._prior_at(self._now)
        if reference is not None:
            s2 = reference[2] ** 2 + best.p[0, 0] + best.p[1, 1]
            for point, sign in ((image, 1.0), (best.x[:2], -1.0)):
                d2 = (point[0] - reference[0]) ** 2 + (point[1] - reference[1]) ** 2
                log_w -= sign * 0.5 * d2 / s2
        turns = best.turns if steered else [(w, reflect @ v) for w, v in best.turns]
        self.hypotheses.append(_Hypothesis(x, g @ best.p @ g.T, best.time, log_w,
                                           best.heading, best.heading_time, list(turns)))
        self.hypotheses.sort(key=lambda h: -h.log_w)
        return False

    def _commit_side(self) -> None:
        """Remember which side of the anchors' line (if they are on one) the track committed
        to (:meth:`_hold_side`): the estimate's, or, if that is on the line, the prior's (after
        a restart, the old track's); neither off it, or anchors off one line: none yet."""
        line = self._mirror_line()
        self._side = None
        if line is not None and self.hypotheses:
            here = self.hypotheses[0].x[:2]
            reference = self._prior_at(self._now)
            for point in (here, None if reference is None else np.array(reference[:2])):
                if point is not None and abs(_cross(line[1], point - line[0])) > MERGE_M / 2:
                    self._side = point.copy()  # a point: the line's direction may turn round
                    return

    def _hold_side(self) -> None:
        """Without a compass, anchors on one line fit a trajectory and its mirror image alike,
        so no range can show the vehicle crossing that line: the side the track committed to
        (by its prior, :meth:`_normalise`) is the only evidence there is. An estimate that
        slides over the line (sparse ranges, a turn not yet seen: its Gaussian straddles the
        line and the EKF follows the ranges to either image) is reflected back, whole state and
        covariance, recent steps and turns too: it fits every range as well, and it is on the
        side the evidence says. (With a compass the image's motion does not fit: untouched.)
        A manoeuvre's blend is held on its own (:meth:`_fold`)."""
        hyp = self.hypotheses[0]
        line = self._mirror_line()
        if self._side is None and line is not None and \
                abs(_cross(line[1], hyp.x[:2] - line[0])) > MERGE_M / 2:
            self._side = hyp.x[:2].copy()  # committed on the line: the side it left to
        if hyp.blend is not None:
            when, share, bx, bp = hyp.blend
            bx, bp, _ = self._fold(bx, bp)
            hyp.blend = (when, share, bx, bp)
        if self._wide is not None:
            self._wide.x, self._wide.p, _ = self._fold(self._wide.x, self._wide.p)
        for comp in self._turns.components if self._turns is not None else []:
            comp.x, comp.p, folded = self._fold(comp.x, comp.p)
            if folded:
                _reflect_history(comp.turns, comp.steps, self._fold_line())
        hyp.x, hyp.p, folded = self._fold(hyp.x, hyp.p)
        if folded:
            _reflect_history(hyp.turns, hyp.steps, self._fold_line())
            self.folds += 1

    def _fold_line(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The anchors' line a committed track without a compass is held on one side of
        (:meth:`_hold_side`); None when there is none to hold."""
        line = self._mirror_line()
        if line is None or self._side is None or not self.resolved or \
                self._steered(self._now):
            return None
        return line

    def _fold(self, x: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
        """``(x, p)``, reflected over the anchors' line if it lies on the side the track did
        not commit to (:meth:`_hold_side`); and whether it was."""
        line = self._fold_line()
        if line is None:
            return x, p, False
        a, u = line
        assert self._side is not None
        if _cross(u, x[:2] - a) * _cross(u, self._side - a) >= 0:
            return x, p, False
        g = _reflection(u)
        return _image(x, line), g @ p @ g.T, True

    def _mode_prepare(self, obs: RangeObs) -> _Hypothesis | None:
        """Without a compass, a committed track has a second mode beside its own (constant
        velocity, manoeuvres by :meth:`_jumped`): one manoeuvring (``wide_accel_sigma``), as an
        interacting-multiple-model filter keeps it, entered and left at random (``wide_enter_s``,
        ``wide_leave_s``). Where the ranges cannot tell them apart (one anchor heard: any turn
        fits its circle) it keeps the share a turn not yet seen deserves, and the published
        estimate is the mixture of both. Mixed here into the manoeuvring mode, as the track
        stood before ``obs`` (the track's own mode is left as it is); None when there is none."""
        cfg = self.config
        if (cfg.wide_accel_sigma <= 0 or cfg.turn_every_s > 0 or not self.resolved
                or len(self.hypotheses) != 1
                or self._steered(obs.time)):
            self._wide = None
            return None
        main = self.hypotheses[0]
        wide = self._wide
        if wide is None:
            rate = 1 / cfg.wide_enter_s
            self._wide_share = rate / (rate + 1 / cfg.wide_leave_s)
            wide = _Hypothesis(main.x.copy(), main.p.copy(), main.time)
        if wide.time < main.time:
            wide.x, wide.p = _predicted(wide.x, wide.p, main.time - wide.time,
                                        cfg.wide_accel_sigma)
        dt = max(obs.time - wide.time, 0.0)
        enter, leave = 1 - math.exp(-dt / cfg.wide_enter_s), 1 - math.exp(-dt / cfg.wide_leave_s)
        mu = self._wide_share
        share = (1 - mu) * enter + mu * (1 - leave)
        if share > 0:
            w1 = (1 - mu) * enter / share
            x = w1 * main.x + (1 - w1) * wide.x
            p = w1 * (main.p + np.outer(main.x - x, main.x - x)) + (1 - w1) * (
                wide.p + np.outer(wide.x - x, wide.x - x))
            wide.x, wide.p = x, p
        wide.time, wide.turns = main.time, list(main.turns)
        self._wide, self._wide_share = wide, share
        return wide

    def _turns_prepare(self, obs: RangeObs) -> TurnMixture | None:
        """Without a compass, a committed track keeps turned components beside it
        (:mod:`bridge.ranging.turns`): the track may have turned since its last range, each
        way of the ring. None when there are none (a compass, or no committed track)."""
        cfg = self.config
        if (cfg.turn_every_s <= 0 or not self.resolved or len(self.hypotheses) != 1
                or self._steered(obs.time)):
            self._turns = None
            return None
        if self._turns is None:
            self._turns = TurnMixture(cfg.turn_every_s, cfg.turn_ring_deg,
                                      floor=cfg.turn_prune_share,
                                      min_speed_mps=cfg.min_heading_speed_mps)
        track = self.hypotheses[0]
        if obs.time > track.time:
            self._turns.spawn(track, obs.time, self._predict, lambda c, when, v: _remember_turn(
                c, when, v, cfg.max_lag_s))
        return self._turns

    def _turns_update(self, turns: TurnMixture, track: _Hypothesis, obs: RangeObs,
                      gain: float) -> bool | None:
        """The turned components take ``obs`` (the track gained ``gain`` from it); the
        alike merged, and the likeliest, if more likely than the track, becomes it. Returns
        whether the new track accepted ``obs`` (None: the track stayed); ranges the old one
        refused and the new one took are then no longer counted as refused."""
        def take(comp: _Hypothesis) -> float:
            step = _Step(obs, comp.x.copy(), comp.p.copy(), comp.time, list(comp.turns), 0.0,
                         0.0, False)
            log_w = comp.log_w
            step.nis, step.accepted = self._range_update(comp, obs)
            step.loglik, comp.log_w = comp.log_w - log_w, log_w
            comp.steps.append(step)
            self._trim_steps(comp, obs.time)
            return step.loglik

        turns.update(gain, take)
        turns.merge(track)
        best = turns.likeliest()
        if best is None:
            return None
        if len(self.hypotheses) == 1 and len(best.steps) > 1:
            self._unrefuse(track.steps[:-1], best.steps[:-1])
        turns.swap(track, best)
        return best.steps[-1].accepted if best.steps else None

    def _mode_update(self, wide: _Hypothesis, main: _Hypothesis, obs: RangeObs) -> None:
        """The manoeuvring mode takes ``obs`` too; both modes' shares, by how well each
        predicted it (the track's own: its latest step)."""
        if obs.time > wide.time:
            wide.x, wide.p = _predicted(wide.x, wide.p, obs.time - wide.time,
                                        self.config.wide_accel_sigma)
            wide.time = obs.time
        predicted, jac = self._range_model(wide, obs)
        r = self._range_sigma(obs.range_m) ** 2 + obs.anchor_sigma_m**2
        log_w = wide.log_w
        self._update(wide, obs.range_m - predicted, jac, r)
        gain = wide.log_w - log_w
        wide.log_w = 0.0
        own = main.steps[-1].loglik if main.steps else gain
        top = max(gain, own)
        a = self._wide_share * math.exp(gain - top)
        b = (1 - self._wide_share) * math.exp(own - top)
        self._wide_share = min(max(a / (a + b), 1e-9), 1 - 1e-9)

    def _steered(self, t: float) -> bool:
        """A recent heading steers the velocity through turns (within ``coast_after_s``)."""
        return self._heading is not None and t - self._heading[0] <= self.config.coast_after_s

    def _accel(self, t: float) -> tuple[float, float | None]:
        """Process noise, (across the velocity or every way, along it or None): while a
        heading steers the velocity, ``accel_sigma_steered``; if the heading came without a
        speed, only across the velocity (turns between headings) and ``accel_sigma`` along it:
        a compass says nothing of the speed, which the ranges alone then carry, and which the
        vehicle holds as it does without one (seed 001 reception, 5 Hz compass: p95 0.34 ->
        0.26 m). A speed log measures the speed itself, changes included (a formation
        starting from rest, a vehicle surfacing): then every way alike, as before."""
        cfg = self.config
        if self._steered(t):
            assert self._heading is not None
            along = cfg.accel_sigma if self._heading[2] is None else None
            return cfg.accel_sigma_steered, along
        return cfg.accel_sigma, None

    def _predict(self, hyp: _Hypothesis, t: float) -> None:
        dt = t - hyp.time
        if dt > 0:
            hyp.x, hyp.p = _predicted(hyp.x, hyp.p, dt, *self._accel(t))
            hyp.time = t

    def _range_model(self, hyp: _Hypothesis, obs: RangeObs) -> tuple[float, Vector]:
        """Predicted range and its Jacobian (1×4) for hypothesis ``hyp``."""
        return self._range_at(hyp.x.tolist(), hyp.time, hyp.turns, obs)

    def _range_at(self, x: Vector, time: float, turns: list[tuple[float, np.ndarray]],
                  obs: RangeObs) -> tuple[float, Vector]:
        """Predicted range and its Jacobian (1×4) for the state ``x`` at ``time`` whose
        velocity was the ``turns``' before each (plain floats, :mod:`bridge.ranging.kalman`)."""
        assert self.depth is not None
        x0, x1, x2, x3 = x
        legs = ((obs.time - obs.span_s, obs.anchor_before or obs.anchor_at),
                (obs.time, obs.anchor_at))
        h, j0, j1, j2, j3 = 0.0, 0.0, 0.0, 0.0, 0.0
        for t_leg, (ax, ay, az) in legs:
            m, ox, oy = _displacement(time, t_leg, turns)  # p(t_leg) = p + m·v + o
            px, py = x0 + m * x2 + ox, x1 + m * x3 + oy
            ex, ey, ez = px - ax, py - ay, self.depth - az
            dist = math.sqrt(ex * ex + ey * ey + ez * ez) or 1e-9
            h += dist / 2
            ux, uy = ex / dist / 2, ey / dist / 2
            j0, j1, j2, j3 = j0 + ux, j1 + uy, j2 + ux * m, j3 + uy * m
        return h, [j0, j1, j2, j3]

    def _range_update(self, hyp: _Hypothesis, obs: RangeObs) -> tuple[float, bool]:
        """EKF update with one range; (NIS, accepted). The weight takes the likelihood."""
        x, p, hyp.time, nis, ok = self._ranged(hyp, hyp.x.tolist(), hyp.p.tolist(), hyp.time,
                                               obs)
        hyp.x, hyp.p = np.array(x), np.array(p)
        return nis, ok

    def _ranged(self, hyp: _Hypothesis, x: Vector, p: Matrix, t: float,
                obs: RangeObs) -> tuple[Vector, Matrix, float, float, bool]:
        """:meth:`_range_update` of ``hyp``'s state ``(x, p)`` at ``t``, in plain floats from
        the prediction to the last iteration (every trial takes it): ``(x, p, t, NIS,
        accepted)``, ``hyp``'s weight taking the likelihood."""
        if obs.time > t:
            x, p = kalman.predicted(x, p, obs.time - t, *self._accel(obs.time))
            t = obs.time
        predicted, jac = self._range_at(x, t, hyp.turns, obs)
        r = self._range_sigma(obs.range_m) ** 2 + obs.anchor_sigma_m**2
        x0, p0 = x, p
        x, p, nis, ok = self._fused(hyp, x, p, obs.range_m - predicted, jac, r)
        if ok and 2 * (p0[0][0] + p0[1][1]) / max(obs.range_m, 1.0) > math.sqrt(r):
            # the position so wide (a start, a long gap) that the range's circle curves away
            # from its tangent by more than the range's noise across that width: a step along
            # the gradient at the prior lands off the circle, and the next range to the same
            # anchor, linearised elsewhere, then reads as another anchor's (a position σ well
            # under a metre that only one anchor was heard). Iterated (Gauss-Newton) to the
            # posterior's linearisation; the gate and the weight keep the prior's
            for _ in range(ITERATIONS):
                xi = x
                h_i, (j0, j1, j2, j3) = self._range_at(xi, t, hyp.turns, obs)
                lin = (j0 * (x0[0] - xi[0]) + j1 * (x0[1] - xi[1]) + j2 * (x0[2] - xi[2])
                       + j3 * (x0[3] - xi[3]))  # the model linearised at xi, taken at x0
                x, p, _ = kalman.updated(x0, p0, obs.range_m - h_i - lin, (j0, j1, j2, j3), r)
                if math.hypot(x[0] - xi[0], x[1] - xi[1]) < 1e-3:
                    break
        return x, p, t, nis, ok

    def _range_sigma(self, range_m: float) -> float:
        """The range noise expected at ``range_m``: the profile's (``range_sigma_at``) if it
        has one, else ``range_sigma_m``."""
        profile = self.config.range_sigma_at
        return profile_at(profile, range_m) if profile else self.config.range_sigma_m

    def _take_range(self, hyp: _Hypothesis, obs: RangeObs) -> tuple[float, bool]:
        """Fuse ``obs`` into ``hyp``, remembering the step; without a compass, a range far out
        (this one or one of the last few) asks whether the vehicle manoeuvred (:meth:`_jumped`)."""
        cfg = self.config
        hyp.blend = None
        if hyp.pending:
            if obs.time <= hyp.pending_until:
                return self._pending_range(hyp, obs)
            self._settle(hyp)
        before = _Step(obs, hyp.x.copy(), hyp.p.copy(), hyp.time, list(hyp.turns), 0.0, 0.0,
                       False)
        log_w = hyp.log_w
        nis, ok = self._range_update(hyp, obs)
        before.loglik, before.nis, before.accepted = hyp.log_w - log_w, nis, ok
        hyp.steps.append(before)
        self._trim_steps(hyp, obs.time)
        if max(s.nis for s in hyp.steps[-3:]) > cfg.jump_test_nis:
            # with a compass the next heading turns the track; until it comes, a turn the
            # ranges suggest is in the published covariance (never taken: it would turn twice)
            steered = self._steered(obs.time)
            fresh = steered and self._heading is not None and \
                obs.time - self._heading[0] < FRESH_HEADING_S
            jumped = None if fresh else self._jumped(hyp, take=not steered)
            if jumped is not None:
                return jumped
        return nis, ok

    def _trim_steps(self, hyp: _Hypothesis, t: float) -> None:
        """Keep the last few ranges, however sparse (seed 001 often heard one anchor a cycle),
        and all of ``jump_window_s``; never beyond ``max_lag_s``."""
        cfg = self.config
        n = len(hyp.steps)
        hyp.steps = [s for k, s in enumerate(hyp.steps) if t - s.obs.time <= cfg.max_lag_s
                     and (n - k <= cfg.jump_steps or t - s.obs.time <= cfg.jump_window_s)]

    def _jumped(self, hyp: _Hypothesis, take: bool = True) -> tuple[float, bool] | None:
        """A generalised likelihood-ratio test for a manoeuvre. For every gap between recent
        ranges, suppose the vehicle turned there, keeping its speed, to a heading it does not
        say (a ring every ``jump_ring_deg``, each 1 σ wide enough to join the next, and a
        broad change of speed besides), and refilter the ranges since under each. If the
        likeliest gap explains them better than no manoeuvre by ``jump_min_llr`` (the mixture's
        marginal likelihood, so a free velocity is not given for nothing), the hypothesis takes
        it: the turns' posteriors at every gap two anchors saw merged by their weights,
        covariance spread included (when it turned is as uncertain as where to).
        (A vehicle's turns are abrupt next to a range cycle: white-noise acceleration either
        lags them or is noisy on the straights.) With ``take`` false (a compass steers the
        track) none is taken: the estimate stays and only its published covariance spreads
        over the turns. Returns the latest range's (NIS, accepted) if one was taken."""
        cfg = self.config
        best: tuple[float, int, list[tuple[float, _Hypothesis, list[_Taken]]]] | None = None
        ring = cfg.jump_ring_deg
        turns = [ring * k for k in range(1, round(360 / ring))]
        pool: list[tuple[float, _Hypothesis]] = []  # every gap's turns, log-odds on none
        for j in range(len(hyp.steps)):
            # one anchor's ranges fit any turn (a circle): it takes two to see one (nor can
            # the ranges after a gap that one anchor alone saw: no trial there)
            if len({s.obs.anchor for s in hyp.steps[j:]}) < 2:
                break
            start = self._halfway(hyp, j)
            tried = [self._refilter(hyp, j, turn, start) for turn in (*turns, None)]
            top = max(t[0] for t in tried)
            mixture = top + math.log(sum(math.exp(t[0] - top) for t in tried) / len(tried))
            none = sum(s.loglik for s in hyp.steps[j:])
            llr = mixture - none
            pool += [(t[0] - none - math.log(len(tried)), t[1]) for t in tried
                     if math.hypot(t[1].x[2], t[1].x[3]) <= cfg.max_speed_mps]
            if best is None or llr > best[0]:
                best = (llr, j, tried)
        if best is None:
            return None
        llr, j, tried = best
        tried = [t for t in tried if math.hypot(t[1].x[2], t[1].x[3]) <= cfg.max_speed_mps]
        if not tried:
            return None
        top = max(t[0] for t in tried)
        weights = [math.exp(t[0] - top) for t in tried]
        _, trial, taken = tried[max(range(len(tried)), key=weights.__getitem__)]
        redone = _steps(taken, trial.turns)
        # the estimate: every gap's turns (and none), weighted by how well they explain the
        # ranges; the turn's time is as uncertain as its direction, and the spread says so
        # ... each on the side the track committed to (without a compass an image fits alike)
        top = max(lw for lw, _ in pool)
        weights = [math.exp(lw - top) for lw, _ in pool]
        states = [self._fold(h.x, h.p)[:2] for _, h in pool]
        total = sum(weights)
        mean = np.asarray(sum(w * x for w, (x, _) in zip(weights, states, strict=True)) / total)
        cov = np.asarray(sum(w * (p + np.outer(x - mean, x - mean))
                             for w, (x, p) in zip(weights, states, strict=True)) / total)
        if self._fold(trial.x, trial.p)[2]:  # the likeliest turn was the image: so its history
            _reflect_history(trial.turns, redone, self._fold_line())
        if not take:  # the estimate stays, its covariance spread over the turns too
            cov = cov + np.outer(mean - hyp.x, mean - hyp.x)
            mean = hyp.x
        if llr < cfg.jump_min_llr or not take:
            # not taken, not ruled out: until the next range the estimate is the mixture of
            # both, weighted by the odds (even at ``jump_even_llr``), so its covariance says so
            even = cfg.jump_even_llr if take else cfg.jump_steered_even_llr
            share = 1.0 / (1.0 + math.exp(min(even - llr, 50.0)))
            if share >= 0.01 and trial.time == hyp.time:
                hyp.blend = (hyp.time, share, mean, cov)
            return None
        if len(self.hypotheses) == 1:  # ranges refused for want of the manoeuvre: not bad
            self._unrefuse(hyp.steps[j:-1], redone[:-1])
        hyp.x, hyp.p, hyp.time, hyp.turns = mean, cov, trial.time, trial.turns
        hyp.log_w += llr
        hyp.steps = hyp.steps[:j] + redone
        self.manoeuvres += 1
        return redone[-1].nis, redone[-1].accepted

    def _halfway(self, hyp: _Hypothesis, j: int) -> _Hypothesis:
        """The state before ``hyp.steps[j]``, predicted halfway to that range (where
        :meth:`_refilter` turns it)."""
        step = hyp.steps[j]
        half = _Hypothesis(step.x, step.p, step.time, 0.0, hyp.heading, hyp.heading_time,
                           step.turns)
        self._predict(half, step.time + max(step.obs.time - step.time, 0.0) / 2)
        return half

    def _refilter(self, hyp: _Hypothesis, j: int, turn_deg: float | None,
                  half: _Hypothesis) -> tuple[float, _Hypothesis, list[_Taken]]:
        """The ranges from ``hyp.steps[j]`` on, refiltered as if the vehicle had turned by
        ``turn_deg`` (clockwise; None: changed its velocity by up to its speed, each axis)
        halfway between the range before and that one (``half``, :meth:`_halfway`):
        (log-likelihood, state, what each range did)."""
        cfg = self.config
        step = hyp.steps[j]
        gap = max(step.obs.time - step.time, 0.0)
        x, p = half.x.tolist(), half.p.tolist()
        vx, vy = x[2], x[3]
        speed = max(math.hypot(vx, vy), cfg.min_heading_speed_mps)
        if turn_deg is None:
            p[2][2] += speed**2
            p[3][3] += speed**2
            change = speed**2 * 2
        else:
            a = math.radians(turn_deg)
            c, s = math.cos(a), math.sin(a)
            x[2], x[3] = c * vx + s * vy, c * vy - s * vx  # clockwise, as headings go
            norm = math.hypot(x[2], x[3]) or 1.0
            ax, ay = x[2] / norm, x[3] / norm  # along the new velocity (none: no spread)
            along = (JUMP_SPEED_SHARE * speed) ** 2
            across = (speed * math.tan(math.radians(cfg.jump_ring_deg / 2))) ** 2
            p[0][2:] = p[1][2:] = p[2][:2] = p[3][:2] = p[2][2:] = p[3][2:] = [0.0, 0.0]
            kalman.spread(p, ax, ay, along, across)  # the velocity: the turn's alone
            change = (x[2] - vx) ** 2 + (x[3] - vy) ** 2 + p[2][2] + p[3][3]
        when = change / 2 * gap * gap / 12  # when in the gap it turned
        p[0][0] += when
        p[1][1] += when
        trial = _Hypothesis(np.array(x), np.array(p), half.time, 0.0, hyp.heading,
                            hyp.heading_time, list(step.turns))
        _remember_turn(trial, trial.time, np.array((vx, vy)), cfg.max_lag_s)
        taken = self._retake(trial, hyp.steps[j:])
        return trial.log_w, trial, taken

    def _redo(self, trial: _Hypothesis, steps: list[_Step]) -> list[_Step]:
        """``steps``' ranges taken again by ``trial`` (which moves on with them), each a new
        step."""
        return _steps(self._retake(trial, steps), trial.turns)

    def _retake(self, trial: _Hypothesis, steps: list[_Step]) -> list[_Taken]:
        """``steps``' ranges taken again by ``trial`` (which moves on with them), the state
        carried from one to the next in plain floats; each range's :data:`_Taken` (made
        into steps, :func:`_steps`, for the trial kept alone)."""
        x, p, t = trial.x.tolist(), trial.p.tolist(), trial.time
        taken: list[_Taken] = []
        for old in steps:
            log_w = trial.log_w
            after, p_after, t_after, nis, ok = self._ranged(trial, x, p, t, old.obs)
            taken.append((old.obs, x, p, t, trial.log_w - log_w, nis, ok))
            x, p, t = after, p_after, t_after
        trial.x, trial.p, trial.time = np.array(x), np.array(p), t
        return taken

    def _turned_since(self, hyp: _Hypothesis, angle: float, t: float) -> None:
        """The compass says the vehicle turned clockwise by ``angle`` since its last heading:
        when, the ranges taken meanwhile tell. Each gap between them (and the last, up to
        ``t``) is a candidate, its prior share its length; from the state before that gap
        the velocity turns halfway through it (the variance of not knowing when within it
        added) and the ranges since are refiltered. The candidates are merged by prior and
        likelihood (the spread between them included); the likeliest one's history is kept."""
        cfg = self.config
        since = hyp.heading_time
        window = [j for j, s in enumerate(hyp.steps) if s.obs.time > since]
        last = hyp.steps[window[-1]].obs.time if window else since
        # the last gap: after every range, as the state stands (the ranges fitted no turn)
        end = _Hypothesis(hyp.x.copy(), hyp.p.copy(), hyp.time, 0.0, hyp.heading,
                          hyp.heading_time, list(hyp.turns), list(hyp.steps))
        before = end.x[2:].copy()
        _turn(end, angle, t - last)
        _remember_turn(end, (t + last) / 2, before, cfg.max_lag_s)
        kept = sum(hyp.steps[j].loglik for j in window)
        tried = [(math.log(max(t - last, 1e-3)) + kept, end)]
        for j in window:
            step = hyp.steps[j]
            start = max(step.time, since)
            trial = _Hypothesis(step.x.copy(), step.p.copy(), step.time, 0.0, hyp.heading,
                                hyp.heading_time, list(step.turns))
            self._predict(trial, start)
            gap = max(step.obs.time - start, 1e-3)
            self._predict(trial, start + gap / 2)
            before = trial.x[2:].copy()
            _turn(trial, angle, 0.0)
            change = trial.x[2:] - before
            trial.p[:2, :2] += np.outer(change, change) * gap**2 / 12  # when in the gap
            _remember_turn(trial, trial.time, before, cfg.max_lag_s)
            redone = self._redo(trial, hyp.steps[j:])
            self._predict(trial, t)
            trial.steps = hyp.steps[:j] + redone
            earlier = sum(hyp.steps[k].loglik for k in window if k < j)
            tried.append((math.log(gap) + earlier + trial.log_w, trial))
        hyp.pending, hyp.pending_until = tried, t + cfg.turn_settle_s
        self._pending_mix(hyp)

    def _pending_mix(self, hyp: _Hypothesis) -> _Hypothesis:
        """``hyp``'s state: its pending turn times (:meth:`_turned_since`) merged by weight,
        the spread between them included; returns the likeliest."""
        top = max(lw for lw, _ in hyp.pending)
        weights = [math.exp(lw - top) for lw, _ in hyp.pending]
        total = sum(weights)
        mean = np.asarray(sum(w * h.x for w, (_, h) in zip(weights, hyp.pending, strict=True))
                          / total)
        hyp.p = np.asarray(sum(w * (h.p + np.outer(h.x - mean, h.x - mean))
                               for w, (_, h) in zip(weights, hyp.pending, strict=True)) / total)
        hyp.x, hyp.time = mean, max(h.time for _, h in hyp.pending)
        return hyp.pending[max(range(len(weights)), key=weights.__getitem__)][1]

    def _pending_range(self, hyp: _Hypothesis, obs: RangeObs) -> tuple[float, bool]:
        """A range while a turn's time is pending: every candidate takes it, and its
        likelihood; the hypothesis's weight takes the mixture's."""
        results, logliks = [], []
        for k, (lw, cand) in enumerate(hyp.pending):
            step = _Step(obs, cand.x.copy(), cand.p.copy(), cand.time, list(cand.turns), 0.0,
                         0.0, False)
            log_w = cand.log_w
            step.nis, step.accepted = self._range_update(cand, obs)
            step.loglik = cand.log_w - log_w
            cand.steps.append(step)
            hyp.pending[k] = (lw + step.loglik, cand)
            results.append((step.nis, step.accepted))
            logliks.append(lw)
        top = max(logliks)
        prior = math.log(sum(math.exp(lw - top) for lw in logliks))
        after = max(lw for lw, _ in hyp.pending)
        gain = after + math.log(sum(math.exp(lw - after) for lw, _ in hyp.pending)) - top - prior
        hyp.log_w += gain
        self._pending_mix(hyp)
        return min(n for n, _ in results), any(ok for _, ok in results)

    def _settle(self, hyp: _Hypothesis) -> None:
        """A pending turn's time is as known as it will be: the merged state stays, with the
        likeliest candidate's history (refused ranges it accepted no longer counted)."""
        if not hyp.pending:
            return
        best = self._pending_mix(hyp)
        if len(self.hypotheses) == 1:
            self._unrefuse(hyp.steps, best.steps[:len(hyp.steps)])
        hyp.turns, hyp.steps = best.turns, best.steps
        hyp.pending = []

    def _unrefuse(self, old: list[_Step], new: list[_Step]) -> None:
        """Ranges refused for want of a manoeuvre (``old``) but accepted with it (``new``,
        the same ranges refiltered): not bad ranges, so no longer counted as refused."""
        taken = {id(step.obs) for step in new if step.accepted}
        for was in old:
            if id(was.obs) in taken and not was.accepted:
                for k, (o, reason) in enumerate(self._refusals):
                    if o is was.obs:
                        self.rejected[reason] -= 1
                        if self.rejected[reason] <= 0:
                            del self.rejected[reason]
                        del self._refusals[k]
                        break

    def _heading_update(self, hyp: _Hypothesis, theta: float, speed: float) -> float:
        vx, vy = float(hyp.x[2]), float(hyp.x[3])
        innovation = _wrap(theta - math.atan2(vx, vy))
        s2 = speed * speed
        nis, _ = self._update(hyp, innovation, [0.0, 0.0, vy / s2, -vx / s2],
                              math.radians(self.config.heading_sigma_deg) ** 2)
        return nis

    def _speed_update(self, hyp: _Hypothesis, speed_mps: float) -> float:
        vx, vy = float(hyp.x[2]), float(hyp.x[3])
        speed = math.hypot(vx, vy)
        if speed < 1e-3:
            heading = hyp.heading if hyp.heading is not None else 0.0
            jac = [0.0, 0.0, math.sin(heading), math.cos(heading)]
        else:
            jac = [0.0, 0.0, vx / speed, vy / speed]
        nis, _ = self._update(hyp, speed_mps - speed, jac, self.config.speed_sigma_mps**2)
        return nis

    def _update(self, hyp: _Hypothesis, innovation: float, jac: Vector,
                r: float) -> tuple[float, bool]:
        """EKF update of ``hyp`` with one scalar measurement; (NIS, accepted)."""
        x, p, nis, ok = self._fused(hyp, hyp.x.tolist(), hyp.p.tolist(), innovation, jac, r)
        if ok:
            hyp.x, hyp.p = np.array(x), np.array(p)
        return nis, ok

    def _fused(self, hyp: _Hypothesis, x: Vector, p: Matrix, innovation: float, jac: Vector,
               r: float) -> tuple[Vector, Matrix, float, bool]:
        """``(x, p)`` after a scalar measurement, with its NIS and whether the gate let it in
        (if not, ``(x, p)`` as they were); ``hyp``'s weight takes its likelihood."""
        xn, pn, s = kalman.updated(x, p, innovation, jac, r)
        nis = innovation * innovation / s
        gate = self.config.gate_nis
        # the weight takes the likelihood, capped at the gate: one wild value cannot decide
        hyp.log_w += -0.5 * min(nis, gate) - 0.5 * math.log(2 * math.pi * s)
        if nis > gate:
            return x, p, nis, False
        return xn, pn, nis, True


def _reflection(u: np.ndarray) -> np.ndarray:
    """The 4×4 reflection of a state ``[x, y, vx, vy]``'s axes over a line along ``u``."""
    reflect = 2 * np.outer(u, u) - np.eye(2)
    g = np.eye(4)
    g[:2, :2] = g[2:, 2:] = reflect
    return g


def _image(x: np.ndarray, line: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """State ``x``'s mirror image over ``line`` (a point, a unit direction): position and
    velocity reflected."""
    a, u = line
    y = _reflection(u) @ x
    y[:2] = a + (2 * np.outer(u, u) - np.eye(2)) @ (x[:2] - a)
    return y


def _reflect_history(turns: list[tuple[float, np.ndarray]], steps: list[_Step],
                     line: tuple[np.ndarray, np.ndarray] | None) -> None:
    """Reflect recorded turns and steps over ``line`` in place (a folded track's history)."""
    if line is None:
        return
    g = _reflection(line[1])
    reflect = g[2:, 2:]
    turns[:] = [(w, reflect @ v) for w, v in turns]
    for step in steps:
        step.x, step.p = _image(step.x, line), g @ step.p @ g.T
        step.turns = [(w, reflect @ v) for w, v in step.turns]


def _predicted(x: np.ndarray, p: np.ndarray, dt: float, accel_sigma: float,
               along_sigma: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`bridge.ranging.kalman.predicted` on numpy's arrays."""
    fx, fp = kalman.predicted(x.tolist(), p.tolist(), dt, accel_sigma, along_sigma)
    return np.array(fx), np.array(fp)


def _displacement(t_state: float, t_leg: float,
                  turns: list[tuple[float, np.ndarray]]) -> tuple[float, float, float]:
    """``(m, ox, oy)`` with ``p(t_leg) = p(t_state) + m·v(t_state) + (ox, oy)``: straight
    lines, except that going back past a recorded turn the velocity is the one held before it.
    (``m`` multiplies the identity: a scalar, in plain floats, as every range takes this.)"""
    m, ox, oy, t = 0.0, 0.0, 0.0, t_state
    held: np.ndarray | None = None  # None: the state's own velocity
    for when, before in reversed(turns):
        if when >= t_state:
            continue
        if when <= t_leg:
            break
        if held is None:
            m = -(t - when)
        else:
            ox, oy = ox - (t - when) * float(held[0]), oy - (t - when) * float(held[1])
        held, t = before, when
    if held is None:
        return t_leg - t_state, ox, oy
    back = t - t_leg
    return m, ox - back * float(held[0]), oy - back * float(held[1])


def _steps(taken: list[_Taken], turns: list[tuple[float, np.ndarray]]) -> list[_Step]:
    """The steps of ranges taken (:meth:`RangeTracker._retake`) under ``turns``."""
    return [_Step(obs, np.array(x), np.array(p), t, list(turns), loglik, nis, ok)
            for obs, x, p, t, loglik, nis, ok in taken]


def _remember_turn(hyp: _Hypothesis, when: float, before: np.ndarray, keep_s: float) -> None:
    """Record that the velocity was ``before`` until ``when`` (for ranges reaching back)."""
    hyp.turns = [(w, v) for w, v in hyp.turns if when - w <= keep_s]
    hyp.turns.append((when, before))


def _turn(hyp: _Hypothesis, angle: float, since_s: float) -> None:
    """The vehicle turned clockwise by ``angle`` radians some time in the last ``since_s``
    seconds: turn the velocity (and its covariance), and move the position as if the turn
    came halfway, with the variance of not knowing when (uniform over the interval)."""
    if angle == 0.0:
        return
    vx, vy = float(hyp.x[2]), float(hyp.x[3])
    x, p = kalman.turned(hyp.x.tolist(), hyp.p.tolist(), angle)
    since = max(since_s, 0.0)
    cx, cy = x[2] - vx, x[3] - vy  # what the prediction since the turn missed, per second
    x[0] += cx * since / 2
    x[1] += cy * since / 2
    kalman.widen(p, cx, cy, since**2 / 12)
    hyp.x, hyp.p = np.array(x), np.array(p)


__all__ = ["LOST_REASONS", "Estimate", "Outcome", "Prior", "RangeObs", "RangeTracker",
           "TrackerConfig"]
