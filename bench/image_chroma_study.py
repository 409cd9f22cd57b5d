"""Issue #30: where chroma's cost to colour luma goes, and whether chroma from luma gets it back.

A measurement, not a coder. Colour 320×240 luma at 800 B is 26.34 dB; the same luma coded alone
as grey gives 26.49. This study splits the difference, encoding each colour picture of the
bench's set with its chroma planes replaced before the transform (the luma decode depends on
nothing else, so luma PSNR needs no decoder for them):

* *chroma zero*: every chroma coefficient 0, its bands still in the stream: what chroma's
  idle bands cost;
* *chroma less a fit on luma*: each chroma plane less its least-squares line on the
  half-size luma (``a·Y + b``, per picture: two numbers a plane that a header could carry),
  the way AV1's chroma-from-luma takes out what luma predicts;
* *… per 16 × 16 block*: the same fitted in every block of the chroma planes (keeping each
  block's mean), at no cost: a bound no real side information reaches;
* *luma alone*: the luma as a grey picture.

Mean luma PSNR (dB) through the real codec against bytes. Measured at stop 51
(2026-11-28)::

                                    400 B    800 B   1600 B
    as coded                       24.548   26.335   28.426
    chroma zero                    24.671   26.455   28.566
    chroma less a fit on luma      24.590   26.361   28.444
    … per 16 × 16 block (bound)    24.562   26.361   28.466
    luma alone                     24.727   26.490   28.582

Of chroma's 0.15 dB at 800 B, its idle bands take about 0.035 and its coefficients 0.12;
chroma from luma gets back at most 0.03 (natural pictures' colours are regions, little of
them follows the luma). Run: ``uv run --group bench python bench/image_chroma_study.py``
(about 3 s).
"""

from __future__ import annotations

import statistics
import sys
from collections.abc import Callable
from functools import partial
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

sys.path.insert(0, str(Path(__file__).resolve().parent))

from image_bench import luma, ours, pictures, psnr

from bridge.image import codec

F64 = NDArray[np.float64]
BUDGETS = (400, 800, 1600)
Planes = Callable[[F64, F64], F64]
"""A chroma plane, given the half-size luma, as it is coded instead."""


def line_off(chroma: F64, y: F64) -> F64:
    """``chroma`` less its least-squares line on ``y``."""
    a = np.stack([y.ravel(), np.ones(y.size)], 1)
    fit, *_ = np.linalg.lstsq(a, chroma.ravel(), rcond=None)
    return chroma - (a @ fit).reshape(chroma.shape)


def blocks_off(chroma: F64, y: F64, side: int = 16) -> F64:
    """``chroma`` less its least-squares line on ``y`` in each ``side``-square block, each
    block's mean kept."""
    out = chroma.copy()
    for i in range(0, chroma.shape[0], side):
        for j in range(0, chroma.shape[1], side):
            block = (slice(i, i + side), slice(j, j + side))
            yy = y[block] - y[block].mean()
            slope = float((yy * chroma[block]).sum() / max(float((yy * yy).sum()), 1e-9))
            out[block] = chroma[block] - slope * yy
    return out


VARIANTS: dict[str, Planes | None] = {
    "as coded": None,
    "chroma zero": lambda c, y: np.zeros_like(c),
    "chroma less a fit on luma": line_off,
    "… per 16 × 16 block (bound)": blocks_off,
}


def coded_with(chroma: Planes | None, pixels: NDArray[np.uint8], budget: int) -> float:
    """Luma PSNR of ``pixels`` at ``budget`` with its chroma planes made by ``chroma``."""
    plain = codec._components
    if chroma is not None:
        def components(array: NDArray[np.uint8]) -> list[F64]:
            y, cb, cr = plain(array)
            half = codec._half(y)
            return [y, chroma(cb, half), chroma(cr, half)]
        codec._components = components  # type: ignore[assignment]
    try:
        return psnr(pixels, ours(pixels, budget))
    finally:
        codec._components = plain


def luma_alone(pixels: NDArray[np.uint8], budget: int) -> float:
    """Luma PSNR of ``pixels``' luma coded as a grey picture."""
    grey = np.clip(np.rint(luma(pixels)), 0, 255).astype(np.uint8)
    return psnr(pixels, ours(grey, budget))


def main() -> None:
    images = pictures()["colour 320×240 (scikit-image, luma)"]
    print(f"colour 320×240 (scikit-image, {len(images)} pictures): mean luma PSNR dB")
    print(f"{'':32}" + "".join(f"{b:>7} B" for b in BUDGETS))
    rows: dict[str, Callable[[NDArray[np.uint8], int], float]] = {
        name: partial(coded_with, variant) for name, variant in VARIANTS.items()}
    rows["luma alone"] = luma_alone
    for name, run in rows.items():
        means = [statistics.fmean(run(p, b) for p in images) for b in BUDGETS]
        print(f"{name:32}" + "".join(f"{m:9.3f}" for m in means), flush=True)


if __name__ == "__main__":
    main()
