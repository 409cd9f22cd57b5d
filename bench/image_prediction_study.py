"""Issue #30: could the decoder guess the coefficients the stream has not reached?

A measurement, not a coder. The decoder puts every coefficient not yet significant at 0. Near
an edge a wavelet coefficient and its neighbours along the edge (and its parent) share a sign,
so one just below the threshold beside significant ones might be guessed better than 0, for
free (the stream is unchanged). This study fits, per orientation and scale (the finest three
levels, then the rest together), the least-squares linear guess of each luma coefficient not
yet significant from its 8 neighbours' and its parent's decoded values, kept inside the
interval the stream leaves it (``±`` its threshold), and decodes with it:

* *fitted in the set*: the weights fitted on every picture of the set, the pictures included
  (what a decoder with the set's own weights built in would get: a bound);
* *leave one out*: each picture decoded with weights fitted on the others (what a decoder
  with weights built in gets on a picture it has not seen).

Mean luma PSNR against bytes, the gains over the plain decode beside them. Measured at stop
47 (2026-11-27)::

                     400 B             800 B             1600 B
                     fitted  unseen    fitted  unseen    fitted  unseen
    colour 320×240   +0.057  +0.003    +0.051  +0.001    +0.060  -0.014
    grey 320×240     +0.061  +0.019    +0.033  +0.007    +0.048  +0.008

Nothing for a picture not fitted on: the 9/7 transform leaves the values (not the
magnitudes) of neighbouring coefficients all but uncorrelated. Run:
``uv run --group bench python bench/image_prediction_study.py`` (about 10 s).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

sys.path.insert(0, str(Path(__file__).resolve().parent))

from image_bench import pictures, psnr, stream_state

from bridge.image.codec import QUANTUM, _components, _pixels
from bridge.image.geometry import Geometry
from bridge.image.wavelet import forward, inverse

F64 = NDArray[np.float64]
BUDGETS = (400, 800, 1600)
GROUPS = [(orient, levels) for orient in (1, 2, 3) for levels in ((1,), (2,), (3,),
                                                                   tuple(range(4, 9)))]


@dataclass
class Decoded:
    """A picture's stream cut at a budget, as the decoder holds it (coding order, weighted
    quantiser units), and the truth beside it."""

    pixels: NDArray[np.uint8]
    geo: Geometry
    values: F64  # the decoder's values (0: not yet significant)
    truth: F64
    guessable: NDArray[np.bool_]  # luma detail coefficients not yet significant
    group: NDArray[np.int64]  # each one's index in GROUPS (-1: none)
    features: F64  # 8 neighbours' and the parent's decoded values
    bound: F64  # what the stream says of its magnitude: below this


def decoded(pixels: NDArray[np.uint8], budget: int) -> Decoded:
    geo, state = stream_state(pixels, budget)
    at, vals = state.values()
    values = np.zeros(geo.size + 1)  # (a spare slot: neighbours past a band's end)
    values[at] = vals
    canvases = np.concatenate([forward(c, lv).ravel() for c, lv in zip(
        _components(pixels), geo.levels, strict=True)])
    group = np.full(geo.size, -1)
    for band in geo.bands:
        orient = (0 if band.rows[0] == band.cols[0] == 0 else 1 if band.rows[0] == 0
                  else 2 if band.cols[0] == 0 else 3)
        for g, (o, levels) in enumerate(GROUPS):
            if band.component == 0 and orient == o and band.level in levels:
                group[band.start:band.start + band.size] = g
    parent = values[geo.parent]
    parent[geo.parent == np.arange(geo.size)] = 0.0
    return Decoded(pixels, geo, values[:-1], canvases[geo.order] * geo.weight * QUANTUM,
                   ~state.significant & (group >= 0), group,
                   np.concatenate([values[geo.neighbours], parent[:, None]], axis=1),
                   np.exp2(state.below.astype(np.float64)))


def fit(pictures_: list[Decoded]) -> dict[int, F64]:
    """Each group's least-squares weights, over its coefficients with something known near."""
    out = {}
    for g in range(len(GROUPS)):
        xs, ys = [], []
        for d in pictures_:
            m = d.guessable & (d.group == g)
            m[m] = np.abs(d.features[m]).sum(axis=1) > 0
            xs.append(d.features[m])
            ys.append(d.truth[m])
        x, y = np.concatenate(xs), np.concatenate(ys)
        if y.size >= 20:
            out[g] = np.linalg.lstsq(x, y, rcond=None)[0]
    return out


def guessed(d: Decoded, weights: dict[int, F64]) -> float:
    """Luma PSNR of the picture decoded with the guesses (none: the plain decode)."""
    values = d.values.copy()
    for g, w in weights.items():
        m = d.guessable & (d.group == g)
        limit = d.bound[m] * 0.999
        values[m] = np.clip(d.features[m] @ w, -limit, limit)
    geo = d.geo
    canvases = np.zeros(geo.size)
    canvases[geo.order] = values / (geo.weight * QUANTUM)
    offsets = geo.offsets
    planes = [inverse(canvases[offsets[i]:offsets[i + 1]].reshape(shape), lv)
              for i, (shape, lv) in enumerate(zip(geo.shapes, geo.levels, strict=True))]
    return psnr(d.pixels, _pixels(planes))


def main() -> None:
    sets = pictures()
    for name in ("colour 320×240 (scikit-image, luma)", "grey 320×240 (scikit-image)"):
        print(f"\n{name}: mean luma PSNR dB ({len(sets[name])} pictures)")
        print(" bytes |  plain | fitted in the set | leave one out")
        for budget in BUDGETS:
            group = [decoded(p, budget) for p in sets[name]]
            plain = np.mean([guessed(d, {}) for d in group])
            inside = np.mean([guessed(d, fit(group)) for d in group])
            unseen = np.mean([guessed(d, fit(group[:i] + group[i + 1:]))
                              for i, d in enumerate(group)])
            print(f" {budget:5d} | {plain:6.2f} | {inside:8.2f} ({inside - plain:+.3f}) | "
                  f"{unseen:6.2f} ({unseen - plain:+.3f})", flush=True)


if __name__ == "__main__":
    main()
