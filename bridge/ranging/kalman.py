"""The range tracker's Kalman steps on its state ``[x, y, vx, vy]``, in plain floats.

Every range a tracker takes is fused many times over: by the track, by each turned component,
and by every trial of a manoeuvre test (eight turns at each recent gap). On a 4-vector and a
4×4 covariance numpy's cost is its per-call overhead, several times the arithmetic, so the
steps every range takes are written out here, term by term: a vector is four floats, a
covariance four rows of four. The forms are the exact ones, nothing approximated: the
prediction is ``F P Fᵀ + Q`` of constant velocity under continuous white-noise acceleration,
the update Joseph's form. A covariance is symmetric: the upper triangle is computed and
mirrored, so it stays exactly symmetric.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

Vector = list[float]
Matrix = list[list[float]]


def predicted(x: Sequence[float], p: Sequence[Sequence[float]], dt: float, accel_sigma: float,
              along_sigma: float | None = None) -> tuple[Vector, Matrix]:
    """``(x, p)`` ``dt`` ahead at constant velocity with continuous white-noise acceleration:
    1-σ ``accel_sigma`` every way, or, with ``along_sigma``, that along the velocity (a change
    of speed) and ``accel_sigma`` across it (a turn)."""
    a2 = accel_sigma**2
    qxx, qxy, qyy = a2, 0.0, a2
    x0, x1, vx, vy = x
    speed = math.hypot(vx, vy)
    if along_sigma is not None and speed > 1e-6:
        ux, uy, more = vx / speed, vy / speed, along_sigma**2 - a2
        qxx, qxy, qyy = qxx + ux * ux * more, qxy + ux * uy * more, qyy + uy * uy * more
    (p00, p01, p02, p03), (_, p11, p12, p13), (_, _, p22, p23), (_, _, _, p33) = p
    # Q integrates the acceleration's variance q: q·dt³/3, q·dt²/2 and q·dt by block
    c3, c2 = dt**3 / 3, dt**2 / 2
    e02, e03, e12, e13 = p02 + dt * p22, p03 + dt * p23, p12 + dt * p23, p13 + dt * p33
    m00 = p00 + dt * p02 + dt * e02 + qxx * c3
    m01 = p01 + dt * p12 + dt * e03 + qxy * c3
    m11 = p11 + dt * p13 + dt * e13 + qyy * c3
    m02, m03 = e02 + qxx * c2, e03 + qxy * c2
    m12, m13 = e12 + qxy * c2, e13 + qyy * c2
    m22, m23, m33 = p22 + qxx * dt, p23 + qxy * dt, p33 + qyy * dt
    return [x0 + dt * vx, x1 + dt * vy, vx, vy], [
        [m00, m01, m02, m03], [m01, m11, m12, m13], [m02, m12, m22, m23], [m03, m13, m23, m33]]


def updated(x: Sequence[float], p: Sequence[Sequence[float]], innovation: float,
            h: Sequence[float], r: float) -> tuple[Vector, Matrix, float]:
    """``(x, p)`` after a scalar measurement (its ``innovation``, Jacobian ``h`` and variance
    ``r``), and the innovation's variance ``s = hᵀ·P·h + r``. The covariance in Joseph form,
    ``(I − k·hᵀ) P (I − k·hᵀ)ᵀ + r·k·kᵀ`` with the gain ``k = P·h / s``, which is (for any
    gain) ``P − k·(P·h)ᵀ − (P·h)·kᵀ + s·k·kᵀ``: computed so."""
    h0, h1, h2, h3 = h
    (p00, p01, p02, p03), (_, p11, p12, p13), (_, _, p22, p23), (_, _, _, p33) = p
    a0 = p00 * h0 + p01 * h1 + p02 * h2 + p03 * h3  # P·h
    a1 = p01 * h0 + p11 * h1 + p12 * h2 + p13 * h3
    a2 = p02 * h0 + p12 * h1 + p22 * h2 + p23 * h3
    a3 = p03 * h0 + p13 * h1 + p23 * h2 + p33 * h3
    s = a0 * h0 + a1 * h1 + a2 * h2 + a3 * h3 + r
    k0, k1, k2, k3 = a0 / s, a1 / s, a2 / s, a3 / s
    m00 = p00 - 2 * k0 * a0 + s * k0 * k0
    m01 = p01 - k0 * a1 - a0 * k1 + s * k0 * k1
    m02 = p02 - k0 * a2 - a0 * k2 + s * k0 * k2
    m03 = p03 - k0 * a3 - a0 * k3 + s * k0 * k3
    m11 = p11 - 2 * k1 * a1 + s * k1 * k1
    m12 = p12 - k1 * a2 - a1 * k2 + s * k1 * k2
    m13 = p13 - k1 * a3 - a1 * k3 + s * k1 * k3
    m22 = p22 - 2 * k2 * a2 + s * k2 * k2
    m23 = p23 - k2 * a3 - a2 * k3 + s * k2 * k3
    m33 = p33 - 2 * k3 * a3 + s * k3 * k3
    x0, x1, x2, x3 = x
    return [x0 + k0 * innovation, x1 + k1 * innovation, x2 + k2 * innovation,
            x3 + k3 * innovation], [[m00, m01, m02, m03], [m01, m11, m12, m13],
                                    [m02, m12, m22, m23], [m03, m13, m23, m33]], s


def turned(x: Sequence[float], p: Sequence[Sequence[float]],
           angle: float) -> tuple[Vector, Matrix]:
    """``(x, p)`` with the velocity turned clockwise by ``angle`` radians (as headings go), its
    covariance with it: ``G·x``, ``G·P·Gᵀ`` with ``G`` the identity but for the rotation of
    the velocity."""
    c, s = math.cos(angle), math.sin(angle)
    x0, x1, vx, vy = x
    (p00, p01, p02, p03), (_, p11, p12, p13), (_, _, p22, p23), (_, _, _, p33) = p
    m02, m03 = c * p02 + s * p03, c * p03 - s * p02
    m12, m13 = c * p12 + s * p13, c * p13 - s * p12
    m22 = c * c * p22 + 2 * c * s * p23 + s * s * p33
    m23 = c * s * (p33 - p22) + (c * c - s * s) * p23
    m33 = s * s * p22 - 2 * c * s * p23 + c * c * p33
    return [x0, x1, c * vx + s * vy, c * vy - s * vx], [
        [p00, p01, m02, m03], [p01, p11, m12, m13], [m02, m12, m22, m23], [m03, m13, m23, m33]]


def spread(p: Matrix, ux: float, uy: float, along: float, across: float) -> None:
    """Add a turn's uncertainty to ``p``'s velocity block, in place: ``along`` (a variance)
    along the unit vector ``u`` (the speed) and ``across`` across it (the heading)."""
    p[2][2] += along * ux * ux + across * uy * uy
    p[2][3] += (along - across) * ux * uy
    p[3][2] += (along - across) * ux * uy
    p[3][3] += along * uy * uy + across * ux * ux


def widen(p: Matrix, cx: float, cy: float, when: float) -> None:
    """Add ``when·c·cᵀ`` to ``p``'s position block, in place: a change of velocity ``c``
    made at a time of variance ``when`` (s²) within a gap."""
    p[0][0] += cx * cx * when
    p[0][1] += cx * cy * when
    p[1][0] += cx * cy * when
    p[1][1] += cy * cy * when
