"""A constant-velocity Kalman filter for a moving node's fixes, pure Python.

Each horizontal axis is filtered on its own (state: position, velocity) with white-noise
acceleration ``accel_sigma`` (m/s²); a fix's ``sigma_m`` (a radius) gives each axis a variance
``sigma_m² / 2``. Fixes whose innovation exceeds ``gate`` standard deviations are refused and
counted (a wrong mirror choice, an outlier range). :meth:`Track.predict` gives the previous
estimate :func:`~bridge.ranging.localise.locate` needs to resolve ambiguities.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from bridge.ranging.localise import Fix, Point


@dataclass
class _Axis:
    x: float
    v: float = 0.0
    pxx: float = 1.0
    pxv: float = 0.0
    pvv: float = 1.0

    def predicted(self, dt: float, q: float) -> _Axis:
        """The state ``dt`` seconds ahead; ``q`` is the acceleration variance."""
        pxx = self.pxx + 2 * dt * self.pxv + dt * dt * self.pvv + q * dt**4 / 4
        pxv = self.pxv + dt * self.pvv + q * dt**3 / 2
        pvv = self.pvv + q * dt * dt
        return _Axis(self.x + dt * self.v, self.v, pxx, pxv, pvv)

    def updated(self, z: float, r: float) -> _Axis:
        """The state after a position measurement ``z`` of variance ``r``."""
        s = self.pxx + r
        kx, kv = self.pxx / s, self.pxv / s
        y = z - self.x
        return _Axis(
            self.x + kx * y,
            self.v + kv * y,
            (1 - kx) * self.pxx,
            (1 - kx) * self.pxv,
            self.pvv - kv * self.pxv,
        )


@dataclass
class Track:
    """Smooths fixes of one moving node; times in seconds on any one clock."""

    accel_sigma: float = 0.05
    initial_speed_sigma: float = 1.0
    gate: float = 5.0
    time: float | None = None
    refused: int = 0
    _axes: tuple[_Axis, _Axis] | None = field(default=None, repr=False)

    @property
    def started(self) -> bool:
        """Whether a fix has been accepted yet."""
        return self._axes is not None

    def start(self, t: float, x: float, y: float, sigma_m: float = 1.0) -> None:
        """Start (or restart) at a known position, e.g. the last GNSS fix before diving."""
        var, vv = sigma_m**2 / 2, self.initial_speed_sigma**2
        self._axes = (_Axis(x, 0.0, var, 0.0, vv), _Axis(y, 0.0, var, 0.0, vv))
        self.time = t

    def predict(self, t: float) -> Point | None:
        """The position expected at ``t`` (None before the first fix)."""
        if self._axes is None or self.time is None:
            return None
        dt = t - self.time
        return (self._axes[0].x + dt * self._axes[0].v, self._axes[1].x + dt * self._axes[1].v)

    def update(self, t: float, fix: Fix) -> bool:
        """Fold in ``fix`` taken at ``t``; False if it was refused by the gate."""
        if self._axes is None or self.time is None:
            self.start(t, fix.x, fix.y, fix.sigma_m)
            return True
        dt, q = max(t - self.time, 0.0), self.accel_sigma**2
        r = max(fix.sigma_m, 1e-3) ** 2 / 2
        ax, ay = (a.predicted(dt, q) for a in self._axes)
        d2 = (fix.x - ax.x) ** 2 / (ax.pxx + r) + (fix.y - ay.x) ** 2 / (ay.pxx + r)
        if math.sqrt(d2) > self.gate:
            self.refused += 1
            return False
        self._axes = (ax.updated(fix.x, r), ay.updated(fix.y, r))
        self.time = t
        return True

    @property
    def position(self) -> Point | None:
        """The filtered position at the last accepted fix."""
        return None if self._axes is None else (self._axes[0].x, self._axes[1].x)

    @property
    def velocity(self) -> Point | None:
        """The filtered velocity (m/s) at the last accepted fix."""
        return None if self._axes is None else (self._axes[0].v, self._axes[1].v)

    @property
    def sigma_m(self) -> float:
        """1-σ position error radius of the filtered estimate."""
        return math.inf if self._axes is None else math.sqrt(self._axes[0].pxx + self._axes[1].pxx)
