"""Issue #30: would significance found in a plane wake its neighbours in the same plane?

A measurement, not a coder. :mod:`bridge.image.bitplanes` decides each plane's classes
(near a significant neighbour, under a significant parent, neither) from the state at the
plane's start, so a coefficient next to one found in this plane's first pass still waits in
the sparse last class. EBCOT's passes see such neighbours at once. This study codes the same
run codes in passes that do, in waves a whole pass at a time (so numpy could still do it):

* *waves*: after the near pass (and after the under pass), the coefficients newly near one
  found in this plane are coded as a near pass of their own, again until none are left;
* *lattice*: the last class goes in two parts, the even rows and columns of each band first,
  with waves after it, so that what it finds wakes its neighbours before the rest.

Both ends would know every wave from what came before, so the stream stays decodable; the
study counts each yes only if its whole run code fits the budget, as the decoder does, and
its plain variant reproduces ``bridge.image.codec``'s pictures (the table shows both). Mean
luma PSNR against bytes, each variant's gain over the plain coder beside it. Run:
``uv run --group bench python bench/image_wave_study.py`` (about 10 s).

Measured at stop 46: waves +0.011 / +0.028 / +0.080 dB at 200 / 800 / 1600 B on colour
320×240, +0.004 / +0.018 / +0.064 on grey; the lattice adds nothing (-0.05 at 200 B). Far
from the +0.18 dB colour at 800 B still needs, and a better coder at 1.6 kB shrinks the
underwater ROI gain, whose margin is 0.05 dB: not taken into the coder.
"""

from __future__ import annotations

import sys
from bisect import bisect_left
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

sys.path.insert(0, str(Path(__file__).resolve().parent))

from image_bench import pictures, psnr

from bridge.image import bitplanes as bp
from bridge.image.codec import QUANTUM, _components, _header_bits, _pixels, decode, encode
from bridge.image.geometry import Geometry, geometry
from bridge.image.wavelet import forward, inverse

Bools = NDArray[np.bool_]
Ints = NDArray[np.int64]
BUDGETS = (200, 800, 1600)
MAX_WAVES = 8


@dataclass(frozen=True)
class Variant:
    waves: bool  # newly near coefficients coded in waves after the near and under passes
    lattice: bool  # the last class in two parts, waves between


VARIANTS = {"plain": Variant(False, False), "waves": Variant(True, False),
            "waves + lattice": Variant(True, True)}


def in_band_even(geo: Geometry) -> Bools:
    """Coding positions on an even row and column of their own band."""
    out = np.zeros(geo.size, dtype=bool)
    for band in geo.bands:
        at = slice(band.start, band.start + band.size)
        width = geo.shapes[band.component][1]
        canvas = geo.order[at] - geo.offsets[band.component]
        out[at] = ((canvas // width - band.rows[0]) % 2 == 0) & (
            (canvas % width - band.cols[0]) % 2 == 0)
    return out


class Coder:
    """The bit-plane coder's run codes over a variant's passes, cut at a budget."""

    def __init__(self, geo: Geometry, q: Ints, negative: Bools, budget: int,
                 variant: Variant) -> None:
        self.geo, self.q, self.negative, self.budget, self.variant = (
            geo, q, negative, budget, variant)
        self.first = np.frexp(q)[1] - 1
        self.sig = np.zeros(geo.size, dtype=bool)
        self.magnitude = np.zeros(geo.size, dtype=np.int64)
        self.plane = np.zeros(geo.size, dtype=np.int64)
        self.refined = np.zeros(geo.size, dtype=bool)
        self.coded = np.zeros(geo.size, dtype=bool)  # tested in this plane
        self.context = bp.Context(geo)
        self.scales = [band.scale for band in geo.bands]
        self.even = in_band_even(geo) if variant.lattice else None
        self.ks: dict[tuple[int, int], int] = {}
        self.used = 0

    def run(self, top: int) -> None:
        for n in range(top, -1, -1):
            if self.plane_(n):
                return

    def plane_(self, n: int) -> bool:
        """Code plane ``n``; True where the budget ends in it."""
        self.coded[:] = False
        was = np.flatnonzero(self.sig)
        near, under = self.context.near[:-1].copy(), self.context.under[:-1].copy()
        if self.code(near & ~self.sig, 0, n) or self.waves(n):
            return True
        if self.code(under & ~self.coded & ~self.sig, 1, n) or self.waves(n):
            return True
        m = min(was.size, self.budget - self.used)  # refinement
        self.magnitude[was[:m]] |= self.q[was[:m]] & (1 << n)
        self.plane[was[:m]] = n
        self.refined[was[:m]] = True
        self.used += m
        if m < was.size:
            return True
        if self.even is not None:
            if self.code(self.even & ~self.coded & ~self.sig, 2, n) or self.waves(n):
                return True
            return self.code(~self.coded & ~self.sig, 4, n)
        return self.code(~self.coded & ~self.sig, 2, n)

    def waves(self, n: int) -> bool:
        if not self.variant.waves:
            return False
        for _ in range(MAX_WAVES):
            mask = self.context.near[:-1] & ~self.coded & ~self.sig
            if not mask.any():
                return False
            if self.code(mask, 3, n):
                return True
        return False

    def code(self, mask: Bools, cls: int, n: int) -> bool:
        """The significance decisions of ``mask``'s positions in plane ``n`` as
        :func:`~bridge.image.bitplanes.encode_planes` codes a pass (its segments and run
        parameters, ``cls`` keying them); True where the budget ends in it."""
        self.coded |= mask
        cand = bp.Positions.of(mask)
        if cand.size == 0:
            return False
        members = cand.array()
        hit = members[self.first[members] == n]
        ones = cand.ranks(hit)
        cut = cand.ranks(self.geo.band_start).tolist()
        cut_ones = np.searchsorted(ones, cut).tolist()
        found: list[int] = []
        ended = False
        for key_band, bands in bp._segments(cut, self.context.busy.tolist(), self.scales):
            places: list[int] = []  # (counted from 0 over the segment's bands)
            starts: list[tuple[int, int]] = []
            length = 0
            for b in bands:
                starts.append((length, cut[b]))
                places += (ones[cut_ones[b]:cut_ones[b + 1]] - cut[b] + length).tolist()
                length += cut[b + 1] - cut[b]
            key = (cls, key_band)
            kp = bp._start_kp(self.ks, key, length)
            at = 0
            for place in places:
                code, kp, _ = bp._code(kp, place - at, 0, length - at)
                if self.used + len(code) > self.budget:
                    ended = True
                    break
                self.used += len(code)
                base, first = starts[bisect_left([s for s, _ in starts], place + 1) - 1]
                found.append(place - base + first)
                at = place + 1
            if ended:
                break
            if at < length:
                m = bisect_left(bp._COVER[kp], length - at)
                self.used += m
                kp = bp._AFTER[kp][m]
            self.ks[key] = kp
            if self.used >= self.budget:
                ended = True
                break
        if found:
            idx = cand.take(np.array(found, dtype=np.int64))
            self.sig[idx] = True
            self.context.became(idx)
            self.magnitude[idx] = 1 << n
            self.plane[idx] = n
        return ended

    def pixels(self) -> NDArray[np.uint8]:
        """The picture the decoder makes of what was coded."""
        geo, at = self.geo, np.flatnonzero(self.sig)
        offset = np.where(self.refined[at], 0.5, bp.FIRST_OFFSET)
        value = self.magnitude[at] + offset * np.exp2(self.plane[at].astype(np.float64))
        canvases = np.zeros(geo.size)
        canvases[geo.order[at]] = np.where(self.negative[at], -value, value) / (
            geo.weight[at] * QUANTUM)
        planes = [inverse(canvases[geo.offsets[i]:geo.offsets[i + 1]].reshape(shape), lv)
                  for i, (shape, lv) in enumerate(zip(geo.shapes, geo.levels, strict=True))]
        return _pixels(planes)


def coded(picture: NDArray[np.uint8], budget: int, variant: Variant) -> NDArray[np.uint8]:
    """``picture`` as a variant codes it in ``budget`` bytes (header counted)."""
    h, w = picture.shape[:2]
    geo = geometry(h, w, picture.ndim == 3)
    canvases = np.concatenate([forward(c, lv).ravel() for c, lv in zip(
        _components(picture), geo.levels, strict=True)])
    coefs = canvases[geo.order]
    q = np.floor(np.abs(coefs) * geo.weight * QUANTUM).astype(np.int64)
    coder = Coder(geo, q, coefs < 0, budget * 8 - _header_bits(False), variant)
    coder.run(int(q.max()).bit_length() - 1)
    return coder.pixels()


def main() -> None:
    sets = pictures()
    for name in ("colour 320×240 (scikit-image, luma)", "grey 320×240 (scikit-image)"):
        group = sets[name]
        print(f"\n{name}: mean luma PSNR dB ({len(group)} pictures)")
        print(" bytes | codec  | " + " | ".join(f"{v:>15}" for v in VARIANTS))
        for budget in BUDGETS:
            shipped = np.mean([psnr(p, decode(encode(p, budget)).pixels) for p in group])
            row = [np.mean([psnr(p, coded(p, budget, v)) for p in group])
                   for v in VARIANTS.values()]
            cells = " | ".join(f"{r:6.2f} ({r - row[0]:+.3f})" for r in row)
            print(f" {budget:5d} | {shipped:6.2f} | {cells}", flush=True)
    print("\n(codec: bridge.image.codec's own stream; 'plain' is the study's copy of it)")


if __name__ == "__main__":
    main()
