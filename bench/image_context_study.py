"""Issue #30, round 4, step 1: would context modelling with an arithmetic coder pay?

A measurement, not a coder: it walks the bit-plane coder's passes
(:mod:`bridge.image.bitplanes`, the same order, classes and run codes; the bits it counts are
checked against :func:`~bridge.image.bitplanes.encode_planes`) and, for the decisions the
stream holds at a budget, sets the bits the run-length codes spend beside the ideal code
length (``-log2 p``, no coder overhead) of an adaptive binary model per context:

* contexts from the significance state at the pass's start: significant horizontal, vertical
  and diagonal neighbours in the band (JPEG 2000's counts, 0-2, 0-2, 0-4), parent
  significant, luma or chroma, the class (near, under, neither), and for the idle class
  whether the band has anything significant yet;
* probabilities from the counts of each context (Krichevsky-Trofimov: +1/2 each), either
  frozen at the pass's start (*pass-start*: what a coder that codes a pass in one call can
  do) or updated after every decision (*sequential*: a per-decision loop, too slow for the
  time goals, shown as the most adaptivity can give);
* signs under their neighbours' signs (horizontal and vertical, each -1/0/+1, and the band's
  orientation), refinement bits under first-or-later refinement and significant neighbours;
* *oracle*: for the near and under classes, each picture's own best static probability per
  context, known for free (no model cost): a bound no adaptive model reaches.

The stream change is the saved bits over the stream's bits at the budget (header left out);
round 4's bar was 5 % at 800 B colour. Run:
``uv run --group bench python bench/image_context_study.py``.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

sys.path.insert(0, str(Path(__file__).resolve().parent))

from image_bench import pictures

from bridge.image import bitplanes as bp
from bridge.image.codec import QUANTUM, _components, _header_bits
from bridge.image.geometry import Geometry, geometry
from bridge.image.wavelet import forward

Ints = NDArray[np.int64]
Bools = NDArray[np.bool_]
CLASSES = (0, 1, 3)  # the significance passes' places in bp.PASSES (2: the refinement)


@dataclass
class Sig:
    """One run-coded segment of a significance pass and what was known at the pass's start."""

    cls: int
    ones: Bools
    bits: int  # its run codes (signs included)
    ctx: dict[str, Ints]


@dataclass
class Ref:
    """A refinement pass."""

    bits: Ints  # the refinement bits, in order
    first: Ints  # 1 where the coefficient's first refinement
    near: Ints  # significant neighbours (0-2)


@dataclass
class Trace:
    events: list[Sig | Ref] = field(default_factory=list)

    def bits(self) -> int:
        return sum(e.bits if isinstance(e, Sig) else e.bits.size for e in self.events)


def coefficients(pixels: NDArray[np.uint8]) -> tuple[Geometry, Ints, Bools]:
    """The quantised magnitudes and signs the codec codes (see ``codec._planes``)."""
    h, w = pixels.shape[:2]
    geo = geometry(h, w, pixels.ndim == 3)
    canvases = np.concatenate([forward(c, lv).ravel() for c, lv in zip(
        _components(pixels), geo.levels, strict=True)])
    coefs = canvases[geo.order]
    return geo, np.floor(np.abs(coefs) * geo.weight * QUANTUM).astype(np.int64), coefs < 0


def orientations(geo: Geometry) -> Ints:
    """Each band's orientation: 0 low, 1 right of the low band, 2 below it, 3 diagonal."""
    return np.array([0 if b.rows[0] == 0 and b.cols[0] == 0 else 1 if b.rows[0] == 0
                     else 2 if b.cols[0] == 0 else 3 for b in geo.bands])


def trace(geo: Geometry, q: Ints, negative: Bools, budget_bits: int) -> Trace:
    """The coder's passes (as :func:`bp.encode_planes`) until ``budget_bits``."""
    top = int(q.max()).bit_length() - 1
    size = geo.size
    sig = np.zeros(size, dtype=bool)
    starts, scales = geo.band_start, [b.scale for b in geo.bands]
    ks: dict[tuple[int, int], int] = {}
    context = bp.Context(geo)
    first = np.frexp(q)[1] - 1
    nb, parent = geo.neighbours, geo.parent
    has_parent = parent != np.arange(size)
    orient = orientations(geo)
    chroma = np.array([b.component > 0 for b in geo.bands], dtype=np.int64)
    out = Trace()
    total = 0
    for n in range(top, -1, -1):
        new = np.flatnonzero(first == n)
        classes = context.classes(sig)
        was = np.flatnonzero(sig)
        for cls, c in enumerate(bp.PASSES):
            if c is None:
                if was.size:  # (no more than the budget still takes, as the coder)
                    held = was[:budget_bits - total]
                    known = np.append(sig, False)[nb[held]].sum(1)
                    out.events.append(Ref((q[held] >> n) & 1, (first[held] == n + 1) * 1,
                                          np.minimum(known, 2)))
                    total += held.size
                    if total >= budget_bits:
                        return out
                continue
            cand = classes[c].array()
            if cand.size == 0:
                continue
            s1 = np.append(sig, False)
            near = s1[nb[cand]]
            signed = np.append(np.where(negative, -1, 1) * sig, 0)[nb[cand]]
            band = geo.band_of[cand]
            ctx = {"h": near[:, 3] * 1 + near[:, 4], "v": near[:, 1] * 1 + near[:, 6],
                   "d": near[:, [0, 2, 5, 7]].sum(1), "p": (sig[parent[cand]]
                                                           & has_parent[cand]) * 1,
                   "c": chroma[band], "o": orient[band], "busy": context.busy[band] * 1,
                   "hs": np.clip(signed[:, 3] + signed[:, 4], -1, 1),
                   "vs": np.clip(signed[:, 1] + signed[:, 6], -1, 1),
                   "neg": negative[cand] * 1}
            at = np.minimum(np.searchsorted(cand, new), cand.size - 1)
            ones_at = at[cand[at] == new]
            ones = np.zeros(cand.size, dtype=bool)
            ones[ones_at] = True
            cut_at = np.searchsorted(cand, starts)
            cut, cut_ones = cut_at.tolist(), np.searchsorted(ones_at, cut_at).tolist()
            neg, ones_list = negative[cand[ones_at]].tolist(), ones_at.tolist()
            segments = bp._segments(cut, context.busy.tolist(), scales)
            sig[cand[ones_at]] = True
            context.became(cand[ones_at])
            for key_band, bands in segments:
                pos, length, found, signs, picks = 0, 0, [], [], []
                if len(bands) == 1:
                    b = bands[0]
                    pos, length = cut[b], cut[b + 1]
                    found = ones_list[cut_ones[b]:cut_ones[b + 1]]
                    signs = neg[cut_ones[b]:cut_ones[b + 1]]
                    picks.append(np.arange(pos, length))
                else:
                    for b in bands:
                        oa, oz = cut_ones[b], cut_ones[b + 1]
                        found += [p - cut[b] + length for p in ones_list[oa:oz]]
                        signs += neg[oa:oz]
                        length += cut[b + 1] - cut[b]
                        picks.append(np.arange(cut[b], cut[b + 1]))
                key = (cls, key_band)
                codes: list[str] = []
                yes = [p << 1 | negative for p, negative in zip(found, signs, strict=True)]
                ks[key] = bp._run_encode(codes, yes, pos, length,
                                         bp._start_kp(ks, key, length - pos))
                bits = sum(map(len, codes))
                pick = np.concatenate(picks)
                out.events.append(Sig(cls, ones[pick], bits,
                                      {k: v[pick] for k, v in ctx.items()}))
                total += bits
                if total >= budget_bits:
                    return out
    return out


Context = Callable[[Sig], Ints]


def ebcot(e: Sig) -> Ints:
    """JPEG 2000's neighbour counts, parent, luma/chroma, the class; idle bands apart."""
    c = e.ctx
    return ((((np.minimum(c["h"], 2) * 3 + c["v"]) * 5 + c["d"]) * 2 + c["p"]) * 4
            + c["busy"] * 2 + c["c"]) * 4 + e.cls


def coarse(e: Sig) -> Ints:
    """Fewer contexts (less to learn): horizontal+vertical (0-2), diagonal (0-2), parent,
    luma/chroma, the class."""
    c = e.ctx
    return ((((np.minimum(c["h"] + c["v"], 2) * 3 + np.minimum(c["d"], 2)) * 2 + c["p"]) * 2
             + c["c"]) * 4 + e.cls)


class Model:
    """Adaptive counts per context (KT), read at the pass's start or after every decision."""

    def __init__(self, sequential: bool) -> None:
        self.sequential = sequential
        self.counts: dict[int, tuple[float, float]] = {}

    def cost(self, keys: Ints, ones: Bools) -> float:
        """Ideal bits of ``ones`` under contexts ``keys`` (in order); learns them."""
        if keys.size == 0:
            return 0.0
        uk, inv = np.unique(keys, return_inverse=True)
        known = [self.counts.get(k, (0.0, 0.0)) for k in uk.tolist()]
        c0 = np.array([k[0] for k in known])
        c1 = np.array([k[1] for k in known])
        o = ones.astype(np.float64)
        n1 = np.bincount(inv, weights=o, minlength=uk.size)
        nn = np.bincount(inv, minlength=uk.size).astype(np.float64)
        if self.sequential:  # counts of the context's earlier decisions in the pass too
            order = np.argsort(inv, kind="stable")
            so, si = o[order], inv[order]
            start = np.searchsorted(si, np.arange(uk.size))
            before = np.cumsum(so) - so
            seen1 = before - before[start][si]
            seen = np.arange(so.size) - start[si]
            p = (c1[si] + seen1 + 0.5) / (c0[si] + c1[si] + seen + 1)
            bits = -np.log2(np.where(so == 1, p, 1 - p)).sum()
        else:
            p = ((c1 + 0.5) / (c0 + c1 + 1))[inv]
            bits = -np.log2(np.where(o == 1, p, 1 - p)).sum()
        for k, a, t in zip(uk.tolist(), n1.tolist(), nn.tolist(), strict=True):
            z = self.counts.get(k, (0.0, 0.0))
            self.counts[k] = (z[0] + t - a, z[1] + a)
        return float(bits)


def oracle(events: list[Sig], context: Context) -> float:
    """Each context's empirical entropy over ``events`` (static best probabilities, free)."""
    if not events:
        return 0.0
    keys = np.concatenate([context(e) for e in events])
    ones = np.concatenate([e.ones for e in events]).astype(np.float64)
    _, inv = np.unique(keys, return_inverse=True)
    n1, nn = np.bincount(inv, weights=ones), np.bincount(inv).astype(np.float64)
    p = n1 / nn
    with np.errstate(divide="ignore", invalid="ignore"):
        h = -(n1 * np.log2(np.where(p > 0, p, 1)) + (nn - n1) * np.log2(np.where(p < 1, 1 - p, 1)))
    return float(h.sum())


def study(t: Trace, budget_bits: int, context: Context, coded: tuple[int, ...],
          sequential: bool) -> tuple[float, float]:
    """(bits of the stream at ``budget_bits``, ideal bits of the same decisions) where the
    classes ``coded`` (and signs, refinement) go by context and the others by run codes; the
    pass the budget cuts counts pro rata."""
    sig_model, sign_model, ref_model = Model(sequential), Model(sequential), Model(sequential)
    old = new = 0.0
    for e in t.events:
        if isinstance(e, Ref):
            ideal = ref_model.cost(e.first * 3 + e.near, e.bits.astype(bool))
            size = e.bits.size
        else:
            ns = int(e.ones.sum())
            c = e.ctx
            o = e.ones
            signs = sign_model.cost(((c["hs"][o] + 1) * 3 + c["vs"][o] + 1) * 4 + c["o"][o],
                                    c["neg"][o].astype(bool))
            runs = e.bits - ns
            ideal = (sig_model.cost(context(e), e.ones) if e.cls in coded else runs) + signs
            size = e.bits
        share = min(1.0, (budget_bits - old) / size) if size else 1.0
        old += size * share
        new += ideal * share
        if old >= budget_bits - 1e-9:
            break
    return old, new


def main() -> None:
    sets = pictures()
    for name in ("grey 320×240 (scikit-image)", "colour 320×240 (scikit-image, luma)"):
        images = sets[name]
        print(f"\n{name}: stream change (ideal code lengths against the run codes; "
              f"{len(images)} pictures)")
        print(f"{'bytes':>6} | {'all ctx':>8} {'seq.':>7} | {'near+under ctx, rest runs':>25} "
              f"{'seq.':>7} | {'oracle near+under':>17}")
        for budget in (200, 800, 1600):
            room = budget * 8 - _header_bits(False)
            sums = np.zeros((5, 2))
            for pixels in images:
                geo, q, negative = coefficients(pixels)
                t = trace(geo, q, negative, int(room * 1.5))
                assert t.bits() == len(bp.encode_planes(geo, q, negative,
                                                        int(q.max()).bit_length() - 1,
                                                        int(room * 1.5))), "trace drifted"
                sums[0] += study(t, room, ebcot, CLASSES, False)
                sums[1] += study(t, room, ebcot, CLASSES, True)
                sums[2] += study(t, room, coarse, (0, 1), False)
                sums[3] += study(t, room, coarse, (0, 1), True)
                held: list[Sig] = []
                spent = 0
                for e in t.events:  # the near and under decisions the budget holds
                    size = e.bits if isinstance(e, Sig) else e.bits.size
                    if spent + size > room:
                        break
                    spent += size
                    if isinstance(e, Sig) and e.cls in (0, 1):
                        held.append(e)
                runs = sum(e.bits - int(e.ones.sum()) for e in held)
                sums[4] += (spent, spent - runs + oracle(held, ebcot))
            cells = [f"{100 * (b / a - 1):+6.2f} %" for a, b in sums]
            print(f"{budget:>6} | {cells[0]:>8} {cells[1]:>7} | {cells[2]:>25} {cells[3]:>7} | "
                  f"{cells[4]:>17}")


if __name__ == "__main__":
    main()
