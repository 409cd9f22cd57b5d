"""The CDF 9/7 wavelet (JPEG 2000's irreversible filter) by lifting, in numpy (pure).

Non-expansive on any size (odd ones too): a signal of ``n`` samples gives ``ceil(n/2)`` low
and ``floor(n/2)`` high coefficients, with whole-sample symmetric extension at both ends. A
2-D level transforms the rows, then the columns; :func:`forward` repeats it on the low band
and lays the result out as one array (Mallat's layout: the low band top left, each level's
details beside and below it), :func:`inverse` undoes it exactly (to rounding).

Our own lifting rather than PyWavelets: PyWavelets' ``bior4.4`` is the same filter but its
non-expansive mode (periodization) wraps the image's edges around, and its symmetric modes
give more coefficients than pixels; ``bench/image_bench.py`` measures this one's time.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

__all__ = ["band_shapes", "forward", "inverse", "levels_for", "synthesis_norms"]

ALPHA = -1.586134342059924
BETA = -0.052980118572961
GAMMA = 0.882911075530934
DELTA = 0.443506852043971
K = 1.230174104914001

Array = NDArray[np.float64]


def levels_for(height: int, width: int, smallest: int = 2) -> int:
    """How many levels a ``height`` × ``width`` image takes: until the low band would be
    smaller than ``smallest`` samples on its shorter side (at least one level, at most 8).
    Two rather than four: a level more leaves fewer low-band coefficients to code from the
    top plane (colour 320×240 at 400 B +0.06 dB, at 800 B +0.02; grey the same or better:
    ``bench/image_bench.py``)."""
    levels, side = 0, min(height, width)
    while side >= 2 * smallest and levels < 8:
        side = (side + 1) // 2
        levels += 1
    return max(levels, 1)


def band_shapes(height: int, width: int, levels: int) -> list[tuple[int, int]]:
    """The low band's shape after each level: ``[(h, w) of the image, level 1's low, …]``."""
    shapes = [(height, width)]
    for _ in range(levels):
        h, w = shapes[-1]
        shapes.append(((h + 1) // 2, (w + 1) // 2))
    return shapes


def _scaled_sum(a: Array, b: Array, c: float) -> Array:
    """``c * (a + b)`` in one new array (the same values: one temporary fewer)."""
    out = np.add(a, b)
    out *= c
    return out


def _lift_odd(d: Array, s: Array, c: float) -> None:
    """``d[i] += c (s[i] + s[i+1])``, ``s[n]`` mirrored to ``s[n-1]`` where it is missing."""
    n = d.shape[0]
    if s.shape[0] > n:
        d += _scaled_sum(s[:n], s[1:n + 1], c)
        return
    d[:n - 1] += _scaled_sum(s[:n - 1], s[1:n], c)
    d[n - 1] += c * (s[n - 1] + s[n - 1])


def _lift_even(s: Array, d: Array, c: float) -> None:
    """``s[i] += c (d[i-1] + d[i])``, ``d[-1]`` mirrored to ``d[0]``, ``d[m]`` to ``d[m-1]``."""
    m, n = s.shape[0], d.shape[0]
    if n == 0:
        return
    s[0] += c * (d[0] + d[0])
    s[1:n] += _scaled_sum(d[:n - 1], d[1:n], c)
    if n < m:
        s[n] += c * (d[n - 1] + d[n - 1])


def _analyse(x: Array) -> tuple[Array, Array]:
    """One level along axis 0: (low, high)."""
    s = x[0::2].copy()
    d = x[1::2].copy()
    if d.shape[0] == 0:
        return s, d
    _lift_odd(d, s, ALPHA)
    _lift_even(s, d, BETA)
    _lift_odd(d, s, GAMMA)
    _lift_even(s, d, DELTA)
    s *= 1 / K
    d *= K / 2
    return s, d


def _synthesise(s: Array, d: Array, out: Array | None = None) -> Array:
    """Inverse of :func:`_analyse` along axis 0, into ``out`` if given."""
    if out is None:
        out = np.empty((s.shape[0] + d.shape[0], *s.shape[1:]))
    if d.shape[0] == 0:
        out[...] = s
        return out
    s = s * K
    d = d * (2 / K)
    _lift_even(s, d, -DELTA)
    _lift_odd(d, s, -GAMMA)
    _lift_even(s, d, -BETA)
    _lift_odd(d, s, -ALPHA)
    out[0::2] = s
    out[1::2] = d
    return out


def forward(image: Array, levels: int) -> Array:
    """The ``levels``-level transform of a 2-D array, in Mallat's layout."""
    out = np.array(image, dtype=np.float64)
    h, w = out.shape
    band = np.empty_like(out)
    for _ in range(levels):
        low, high = _analyse(out[:h, :w].T)  # rows (as columns of the transpose)
        lw = low.shape[0]
        band[:h, :lw] = low.T
        band[:h, lw:w] = high.T
        low, high = _analyse(band[:h, :w])
        lh = low.shape[0]
        out[:lh, :w] = low
        out[lh:h, :w] = high
        h, w = lh, lw
    return out


def inverse(coefficients: Array, levels: int) -> Array:
    """Undo :func:`forward`."""
    out = np.array(coefficients, dtype=np.float64)
    height, width = out.shape
    shapes = band_shapes(height, width, levels)
    band = np.empty_like(out)
    for level in range(levels, 0, -1):
        h, w = shapes[level - 1]
        lh, lw = shapes[level]
        _synthesise(out[:lh, :w], out[lh:h, :w], band[:h, :w])
        _synthesise(band[:h, :lw].T, band[:h, lw:w].T, out[:h, :w].T)
    return out


@lru_cache(maxsize=16)
def synthesis_norms(n: int, levels: int) -> tuple[Array, ...]:
    """The synthesis norm of every coefficient of a 1-D signal of ``n`` samples, level by
    level: item ``l - 1`` holds, for each place of level ``l``'s layout (its low band, then
    its high band), the L2 norm of that coefficient's unit impulse synthesised back to ``n``
    samples. Near an edge the symmetric extension folds a coefficient's impulse onto itself:
    there it weighs up to about 30 % more or less than inside."""
    shapes = band_shapes(n, 1, levels)
    out = []
    for level in range(1, levels + 1):
        size = shapes[level - 1][0]
        norms = np.empty(size)
        for a in range(0, size, 256):  # (256 impulses at a time: memory)
            b = min(a + 256, size)
            c = np.zeros((n, b - a))
            c[np.arange(a, b), np.arange(b - a)] = 1.0
            for lv in range(level, 0, -1):
                low, top = shapes[lv][0], shapes[lv - 1][0]
                c[:top] = _synthesise(c[:low], c[low:top])
            norms[a:b] = np.sqrt((c * c).sum(axis=0))
        out.append(norms)
    return tuple(out)
