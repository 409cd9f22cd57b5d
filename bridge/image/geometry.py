"""Where every wavelet coefficient of an image sits, in the order the coder sends it (pure).

The coder sees one flat array of coefficients in *coding order*: bands from the coarsest to the
finest scale, and at each scale luma before chroma (colour images carry Cb and Cr at half
resolution, so their bands join one scale later); inside a band, along its edges: the band
of vertical edges (high-pass across the rows) column by column, the others row by row, so
that the coefficients of one edge follow one another in the significance passes' runs. A
:class:`Geometry` maps that order to each component's Mallat-layout canvas (where a
coefficient's neighbours are those around it on the canvas, in its band), gives each coefficient its
parent (the same place one scale coarser) and the weight that makes a coefficient's squared
error the pixels' (its own synthesis norm, edges and all, times a chroma weight). Both ends
build the same geometry from the stream's header. A region of interest (:class:`Roi`) is a rectangle
of the picture, coded as a picture of its own (:mod:`bridge.image.codec`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property, lru_cache

import numpy as np
from numpy.typing import NDArray

from bridge.image.wavelet import band_shapes, levels_for, synthesis_norms

__all__ = ["CHROMA_WEIGHT", "Geometry", "Roi", "geometry"]

CHROMA_WEIGHT = 0.5
"""Chroma coefficients count this much of luma's: colour sharpens after brightness."""

Ints = NDArray[np.int64]
IntArray = Ints
F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Roi:
    """A region of interest: a rectangle in 64ths of the image's width and height
    (``x0 < x1 <= 64``, ``y0 < y1 <= 64``); the rest of the picture gets a ``2**-(shift +
    1)`` share of the bytes before it, and whatever the ROI leaves over after it."""

    x0: int
    y0: int
    x1: int
    y1: int
    shift: int = 5

    def __post_init__(self) -> None:
        if not (0 <= self.x0 < self.x1 <= 64 and 0 <= self.y0 < self.y1 <= 64):
            raise ValueError(f"ROI {self.x0},{self.y0}-{self.x1},{self.y1} is not inside "
                             "0..64 with x0 < x1 and y0 < y1")
        if not 0 <= self.shift <= 7:
            raise ValueError(f"ROI shift {self.shift} is not 0..7")

    @classmethod
    def from_fractions(cls, x0: float, y0: float, x1: float, y1: float,
                       shift: int = 5) -> Roi:
        """The rectangle ``(x0, y0)``–``(x1, y1)`` given in fractions of the image (0..1),
        widened to whole 64ths."""
        lo = [min(63, max(0, int(np.floor(v * 64)))) for v in (x0, y0)]
        hi = [max(lo[i] + 1, min(64, int(np.ceil(v * 64)))) for i, v in enumerate((x1, y1))]
        return cls(lo[0], lo[1], hi[0], hi[1], shift)

    def fractions(self) -> tuple[float, float, float, float]:
        return self.x0 / 64, self.y0 / 64, self.x1 / 64, self.y1 / 64

    def box(self, height: int, width: int) -> tuple[slice, slice]:
        """Its rows and columns on a ``height`` × ``width`` picture (at least one pixel)."""
        def span(lo: int, hi: int, n: int) -> slice:
            start = min(lo * n // 64, n - 1)
            return slice(start, max(start + 1, -(-hi * n // 64)))
        return span(self.y0, self.y1, height), span(self.x0, self.x1, width)


@dataclass(frozen=True)
class Band:
    """One band of one component: its place on the canvas and in coding order."""

    component: int
    level: int  # 1 finest .. levels; the low band has the component's levels
    rows: tuple[int, int]
    cols: tuple[int, int]
    start: int  # first position in coding order

    @property
    def shape(self) -> tuple[int, int]:
        return self.rows[1] - self.rows[0], self.cols[1] - self.cols[0]

    @property
    def size(self) -> int:
        return self.shape[0] * self.shape[1]

    @property
    def scale(self) -> int:
        """Its scale on the picture: its level, one more for chroma (at half resolution)."""
        return self.level + (self.component > 0)


@dataclass(frozen=True)
class Geometry:
    """Coding order, canvases, parents, weights and the ROI mask of one image shape."""

    shapes: tuple[tuple[int, int], ...]  # each component's canvas
    levels: tuple[int, ...]
    bands: tuple[Band, ...]  # in coding order
    order: IntArray  # coding position -> index into the components' canvases, concatenated
    parent: IntArray  # coding position -> the parent's coding position (itself: none)
    weight: NDArray[np.float64]  # coding position -> weight
    band_start: IntArray  # each band's first coding position, then the total

    @property
    def size(self) -> int:
        return int(self.order.shape[0])

    @cached_property
    def luma(self) -> NDArray[np.bool_]:
        """Coding positions of the luma (or grey) coefficients."""
        mask = np.zeros(self.size, dtype=bool)
        for band in self.bands:
            if band.component == 0:
                mask[band.start:band.start + band.size] = True
        return mask

    @cached_property
    def neighbours(self) -> NDArray[np.int32]:
        """Each coding position's 8 neighbours in its band, as coding positions (``size``
        where the band ends: on the canvas the next band's coefficients are no neighbours,
        +0.02 dB at 800 B, grey and colour 320×240, ``bench/image_bench.py``)."""
        return self._neighbours()

    @cached_property
    def children(self) -> NDArray[np.int32]:
        """Each coding position's children (the coefficients it is the parent of), as
        coding positions in a row padded with ``size`` (one spare slot past the end)."""
        return self._children()

    @cached_property
    def marks(self) -> NDArray[np.int32]:
        """What a coding position becoming significant marks, in one table (one gather and
        one scatter a pass: half the time of two): its :attr:`neighbours`, then its
        :attr:`children` shifted by ``size + 1``, as places in one array of ``2 * (size +
        1)`` (the two ends' contexts: see :class:`bridge.image.bitplanes.Context`)."""
        return np.concatenate((self._neighbours(), self._children()[:-1] + (self.size + 1)),
                              axis=1)

    def _neighbours(self) -> NDArray[np.int32]:
        inverse = np.empty(self.size + 1, dtype=np.int32)
        inverse[self.order] = np.arange(self.size, dtype=np.int32)
        inverse[self.size] = self.size
        out = np.full((self.size, 8), self.size, dtype=np.int32)
        offsets = self.offsets
        for (h, w), start in zip(self.shapes, offsets, strict=False):
            rr, cc = np.divmod(np.arange(h * w), w)
            at = inverse[start + np.arange(h * w)]
            k = 0
            for dr in (-1, 0, 1):
                for dc in (-1, 0, 1):
                    if dr == dc == 0:
                        continue
                    r, c = rr + dr, cc + dc
                    ok = (r >= 0) & (r < h) & (c >= 0) & (c < w)
                    out[at[ok], k] = inverse[start + r[ok] * w + c[ok]]
                    k += 1
        band = np.append(self.band_of, -1)
        out[band[out] != band[:-1, None]] = self.size
        return out

    def _children(self) -> NDArray[np.int32]:
        has = np.flatnonzero(self.parent != np.arange(self.size))
        kids = has[np.argsort(self.parent[has], kind="stable")]
        parents = self.parent[kids]
        first = np.searchsorted(parents, parents)  # each kid's place among its siblings
        rank = np.arange(kids.size) - first
        out = np.full((self.size + 1, int(rank.max()) + 1 if rank.size else 1), self.size,
                      dtype=np.int32)
        out[parents, rank] = kids
        return out

    @cached_property
    def band_of(self) -> Ints:
        """Each coding position's band (its index in :attr:`bands`)."""
        return np.repeat(np.arange(len(self.bands)), [b.size for b in self.bands])

    @property
    def offsets(self) -> list[int]:
        """Where each component's canvas starts in the concatenated canvases."""
        out = [0]
        for h, w in self.shapes:
            out.append(out[-1] + h * w)
        return out


VERTICAL_EDGES = 1
"""The orientation (below: 0 the low band, then 1, 2, 3) of the band high-pass across the rows
and low-pass down the columns, whose coefficients line up down vertical edges: scanned
column by column (+0.06 dB at 800 B, grey and colour 320×240, against row by row;
``bench/image_bench.py``; the other two bands lose by it)."""


def _scan(shape: tuple[int, int], by_columns: bool) -> IntArray:
    """The place in the band's rows (raster order) of each coefficient of a band of ``shape``
    in coding order: row by row, or column by column."""
    h, w = shape
    at = np.arange(h * w, dtype=np.int64)
    return at.reshape(h, w).T.ravel() if by_columns else at


@lru_cache(maxsize=8)
def geometry(height: int, width: int, colour: bool) -> Geometry:
    """The geometry of a ``height`` × ``width`` image (grey, or colour with half-size
    chroma)."""
    levels = levels_for(height, width)
    comps = [(height, width, levels)]
    if colour:
        ch, cw = (height + 1) // 2, (width + 1) // 2
        comps += [(ch, cw, max(1, levels - 1))] * 2
    # every band, keyed by (scale, component, orientation): coarsest scale first
    found: list[tuple[tuple[int, int, int], int, int, tuple[int, int], tuple[int, int],
                      F64]] = []
    for comp, (h, w, lv) in enumerate(comps):
        shapes = band_shapes(h, w, lv)
        shift = 1 if comp else 0  # chroma's level l is luma's scale l + 1
        cw_ = CHROMA_WEIGHT if comp else 1.0
        down, across = synthesis_norms(h, lv), synthesis_norms(w, lv)

        def weight(level: int, rows: tuple[int, int], cols: tuple[int, int],
                   down: tuple[F64, ...] = down, across: tuple[F64, ...] = across,
                   cw_: float = cw_) -> F64:
            """A band's weights, raster order: its rows' norms times its columns'."""
            return np.outer(down[level - 1][rows[0]:rows[1]],
                            across[level - 1][cols[0]:cols[1]]).ravel() * cw_

        lh, lw = shapes[lv]
        found.append(((-(lv + shift) - 1, comp, 0), comp, lv, (0, lh), (0, lw),
                      weight(lv, (0, lh), (0, lw))))
        for level in range(lv, 0, -1):
            (h0, w0), (h1, w1) = shapes[level - 1], shapes[level]
            key = -(level + shift)
            for orient, rows, cols in ((1, (0, h1), (w1, w0)), (2, (h1, h0), (0, w1)),
                                       (3, (h1, h0), (w1, w0))):
                found.append(((key, comp, orient), comp, level, rows, cols,
                              weight(level, rows, cols)))
    found.sort(key=lambda b: b[0])
    offsets = [0]
    for h, w, _ in comps:
        offsets.append(offsets[-1] + h * w)
    bands: list[Band] = []
    orders, weights = [], []
    start = 0
    where: dict[tuple[int, int, int], Band] = {}  # (component, level, orientation)
    for (_, _, orient), comp, level, rows, cols, wt in found:
        band = Band(comp, level, rows, cols, start)
        bands.append(band)
        where[(comp, level, orient)] = band
        w = comps[comp][1]
        scan = _scan(band.shape, orient == VERTICAL_EDGES)
        rr, cc = np.divmod(scan, band.shape[1])
        orders.append(offsets[comp] + (rows[0] + rr) * w + cols[0] + cc)
        weights.append(wt[scan])
        start += band.size
    order = np.concatenate(orders).astype(np.int64)
    parent = np.arange(start, dtype=np.int64)
    for (comp, level, orient), band in where.items():
        lv = comps[comp][2]
        if orient == 0:
            continue
        up = where[(comp, lv, 0)] if level == lv else where[(comp, level + 1, orient)]
        bw = band.shape[1]
        ph, pw = up.shape
        step = 2 if level < lv else 1
        rr, cc = np.divmod(_scan(band.shape, orient == VERTICAL_EDGES), bw)
        up_at = np.empty(ph * pw, dtype=np.int64)  # the parent band's raster -> coding order
        up_at[_scan(up.shape, level < lv and orient == VERTICAL_EDGES)] = np.arange(ph * pw)
        parent[band.start:band.start + band.size] = up.start + up_at[
            np.minimum(rr // step, ph - 1) * pw + np.minimum(cc // step, pw - 1)]
    starts = np.array([b.start for b in bands] + [start], dtype=np.int64)
    return Geometry(tuple((h, w) for h, w, _ in comps), tuple(c[2] for c in comps),
                    tuple(bands), order, parent, np.concatenate(weights), starts)
