"""The stream's own distortion estimate (``Decoded.psnr_estimate``) against the truth, by picture
size and kind: why it is far off on camera-sized pictures. A measurement, not a fix.

Found from outside: a camera's 640×480 JPEG read 39 dB at 37 B, 33 dB at 555 B and 38 dB at
the end of a few kB while its true luma PSNR rose from 21.6 to 29.0 dB. This script encodes
pictures at 640×480, 320×240 and 160×120 (6400 B), decodes every prefix of 20 … 100 B (every
8th byte) and 24 more up to the end, and sets the estimate beside the true luma PSNR
(:func:`image_bench.psnr`), in three sets:

* *listed*: scikit-image's astronaut, chelsea, coffee (grey and colour) and camera (grey),
  centre-cropped to 4:3 and resized with Pillow (:func:`image_bench.prepare`: 640×480 is
  *up*-sampled from their 300 … 512 lines), and seabeds (:func:`bridge.image.synthetic.seabed`,
  seeds 0 and 1, grey and colour), each as it is and as a JPEG of quality 75;
* *camera-like*: 640×480, 320×240 and 160×120 windows cut 1:1 (no resampling: a camera's own
  detail at every scale) from the larger scikit-image pictures (retina, stereo_motorcycle,
  hubble_deep_field; grey and colour), as they are and as a noisy camera gives them (Gaussian
  noise σ 4, Pillow's unsharp mask, JPEG quality 75);
* *texture*: grass, gravel, brick (grey, resized).

Then, for the same prefixes, what makes up the estimate (:func:`parts`: the same arithmetic as
:func:`bridge.image.codec._mse_estimate`, checked against it), beside the same parts of the
true error: the coefficients the stream has found (their last interval), the unknown ones of
*busy* bands (something in them above the threshold fitted at: a Laplacian tail fit times
``BODY``) and of *idle* bands (nothing above it yet: half the level above's typical scale,
capped by the band's own bound).

Measured (``mean / mean |·| / worst`` of estimate − truth, dB)::

    set          size   20 … 100 B          101 B … 1.6 kB      1.6 … 6.4 kB
    listed        160   +1.1 / 1.2 /  +2.7  +1.0 / 1.3 /  +3.9  +1.7 / 1.7 /  +4.6
                  320   +0.2 / 0.9 /  -2.1  -0.3 / 1.5 /  -4.3  +0.6 / 1.4 /  +4.9
                  640   -1.0 / 1.4 /  -6.9  -1.4 / 1.8 /  -7.0  -0.9 / 1.8 /  -6.6
    camera-like   160   +1.9 / 3.2 / +11.6  +3.1 / 3.4 / +11.5  +2.9 / 3.1 /  -7.5
                  320   +2.9 / 3.4 /  +9.8  +2.6 / 3.0 /  +9.7  +3.2 / 3.2 /  +5.8
                  640   +2.4 / 3.0 /  +6.9  +2.1 / 2.4 /  +8.2  +2.3 / 2.4 /  +8.3
    texture       160  +10.9 / 10.9 / +14.0 +5.5 / 5.5 /  +9.4  +3.0 / 3.1 /  +5.9
                  640   +9.9 / 9.9 / +14.4  +4.2 / 4.3 / +13.7  +2.9 / 3.0 /  +4.8

    unknown coefficients' energy, truth / estimate     busy bands   idle bands
    listed (160, 320, 640)                             1.8 1.6 1.6  0.98 0.81 0.61
    camera-like (160, 320, 640)                        1.7 1.8 1.7  1.6  2.1  1.4
    texture (160, 320, 640)                            3.8 3.8 3.8  9.0  5.9  4.1

What that says:

* The estimate is right on the calibration pictures because two errors of opposite sign
  cancel: busy bands' unknown energy is underestimated 1.6 … 1.8× on every natural and
  camera-like picture (``BODY`` 0.3 alone would be ~0.5), idle bands' is overestimated on the
  smooth ones (the level-above chain at ½ keeps each unseen level's total energy at the level
  above's, where these pictures lose a third or more a level). Which error wins depends on the
  share of bands still idle, so on size and stage: small pictures late read optimistic, large
  smooth ones early pessimistic (the listed 640×480: worst -7 dB; the first 12 … 36 B, not in
  the table: -4 … -16 dB on the seabeds and camera, the top planes' bound).
* Camera-like pictures hold detail the listed ones do not (up-sampling empties 640×480's
  finest scale; a camera's frame fills it, and its noise sits there): the idle bands' error
  is then underestimated and the same prior reads them 2 … 3 dB optimistic at every size,
  textured or noisy ones far more. The camera's report (+17 dB early, +9 at the end) fits
  this, at the top of the range (grass, gravel, brick: +10 dB early at 160×120 as at 640×480).
* Until the planes reach a scale, the stream says of it only that nothing there is above the
  threshold: it cannot tell a smooth picture from a textured or noisy one there. Tried, on
  the decoder's side (stream unchanged), over these pictures and more (collages, noisy
  variants, held-out pictures): each band's tail shape over two planes; the levels' slope
  between busy levels; the chain at other ratios with other idle weights; a floor under an
  idle band's scale from its own bound; sibling bands of the same level; coefficients found
  so far in the current plane; the share of significant coefficients whose parent is
  significant (it does single out textures); a floor of camera noise. Each either does not
  separate the kinds, or makes the estimate fall as bytes come (what
  ``tests/image/test_codec.py`` forbids), or moves the bench's calibration pictures
  (downsampled scikit-image pictures and seabeds, smoother than a camera's frames): weights
  fitted to the camera-like pictures (busy 0.55, idle 0.7, chain 0.41) read them within about
  a dB on average at every size, but the bench's grey 320×240 at -1.6 dB (now +0.6), and three
  of those tests fail.

Run: ``uv run --group bench python bench/image_estimate_study.py [--quick]`` (about a
minute; ``--quick``: 640×480 only).
"""

from __future__ import annotations

import argparse
import io
import math
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
import skimage.data
from numpy.typing import NDArray
from PIL import Image, ImageFilter

sys.path.insert(0, str(Path(__file__).resolve().parent))

from image_bench import prepare, psnr

from bridge.image.bitplanes import Planes, decode_planes
from bridge.image.codec import (
    BODY,
    QUANTUM,
    _components,
    _mse_estimate,
    _read_header,
    decode,
    encode,
)
from bridge.image.geometry import Geometry, geometry
from bridge.image.synthetic import seabed
from bridge.image.wavelet import forward

U8 = NDArray[np.uint8]
SIZES = ((160, 120), (320, 240), (640, 480))
BUDGET = 6400


def jpeg(pixels: U8, quality: int = 75) -> U8:
    out = io.BytesIO()
    Image.fromarray(pixels).save(out, format="JPEG", quality=quality)
    return np.asarray(Image.open(io.BytesIO(out.getvalue())))


def noisy_camera(pixels: U8) -> U8:
    """``pixels`` as a small camera gives them: sensor noise, sharpened, JPEG."""
    noisy = pixels.astype(np.float64) + np.random.default_rng(0).normal(0, 4.0, pixels.shape)
    image = Image.fromarray(np.clip(np.rint(noisy), 0, 255).astype(np.uint8))
    image = image.filter(ImageFilter.UnsharpMask(radius=1.5, percent=80, threshold=2))
    return jpeg(np.asarray(image))


def window(name: str, width: int, height: int, colour: bool) -> U8:
    """A ``width`` × ``height`` window cut 1:1 from the middle of a scikit-image picture."""
    x = getattr(skimage.data, name)()
    if isinstance(x, tuple):  # (stereo_motorcycle: the left view, the right, the disparity)
        x = x[0]
    if not colour:
        x = np.asarray(Image.fromarray(x).convert("L"))
    h, w = x.shape[:2]
    y0, x0 = (h - height) // 2, (w - width) // 2
    return np.ascontiguousarray(x[y0:y0 + height, x0:x0 + width])


def picture_sets(width: int, height: int) -> dict[str, list[tuple[str, U8]]]:
    data = skimage.data
    listed: list[tuple[str, U8]] = []
    for name in ("astronaut", "chelsea", "coffee"):
        listed += [(f"{name} grey", prepare(getattr(data, name)(), width, height, grey=True)),
                   (f"{name} colour", prepare(getattr(data, name)(), width, height))]
    listed.append(("camera grey", prepare(data.camera(), width, height)))
    for seed in (0, 1):
        listed += [(f"seabed {seed} grey", seabed(height, width, seed, colour=False)),
                   (f"seabed {seed} colour", seabed(height, width, seed))]
    listed += [(f"{label}, JPEG 75", jpeg(p)) for label, p in listed]
    camera: list[tuple[str, U8]] = []
    for name in ("retina", "stereo_motorcycle", "hubble_deep_field"):
        for colour in (False, True):
            p = window(name, width, height, colour)
            label = f"{name} 1:1 {'colour' if colour else 'grey'}"
            camera += [(label, p), (f"{label}, noisy camera", noisy_camera(p))]
    texture = [(name, prepare(getattr(data, name)(), width, height))
               for name in ("grass", "gravel", "brick")]
    return {"listed": listed, "camera-like": camera, "texture": texture}


def prefixes(n: int) -> list[int]:
    return sorted({*range(20, 101, 8), *(round(float(x)) for x in np.geomspace(110, n, 24))})


def stage(n: int) -> str:
    return "≤100 B" if n <= 100 else "≤1.6 kB" if n <= 1600 else ">1.6 kB"


def magnitudes(pixels: U8, geo: Geometry) -> NDArray[np.float64]:
    """Every coefficient's magnitude in quantiser units, coding order (what the coder codes,
    before flooring)."""
    canvases = np.concatenate([forward(c, lv).ravel() for c, lv in zip(
        _components(pixels), geo.levels, strict=True)])
    return np.abs(canvases[geo.order]) * geo.weight * QUANTUM


def state(stream: bytes) -> tuple[Geometry, Planes]:
    bits = bin(int.from_bytes(b"\x01" + stream, "big"))[3:]
    head = _read_header(bits)
    geo = geometry(head.height, head.width, head.colour)
    return geo, decode_planes(geo, bits[head.at:], head.top)


def parts(geo: Geometry, st: Planes, q: NDArray[np.float64]) -> dict[str, tuple[float, float]]:
    """The estimate's parts and the truth's (squared quantiser units, summed): found
    coefficients, unknown ones of busy bands, of idle bands. The same arithmetic as
    :func:`bridge.image.codec._mse_estimate` (the sum is checked against it by the caller)."""
    units = QUANTUM ** 2
    out = {"found": [0.0, 0.0], "busy": [0.0, 0.0], "idle": [0.0, 0.0]}
    at, values = st.values()
    rec = np.zeros(geo.size)
    rec[at] = np.abs(values)
    known = st.significant & geo.luma
    out["found"] = [float(np.exp2(2 * st.plane[known]).sum()) / 12,
                    float(((q - rec)[known] ** 2).sum())]
    if st.complete:
        return {k: (e / units, t / units) for k, (e, t) in out.items()}
    fit = st.threshold + 1
    sig, above, below = st.significant, st.magnitude >= 1 << fit, st.below
    scales_at: dict[int, list[float]] = {}
    for band in geo.bands:
        if band.component:
            continue
        sl = slice(band.start, band.start + band.size)
        unknown = ~sig[sl]
        if not unknown.any():
            continue
        n_sig = int(np.count_nonzero(sig[sl] & above[sl]))
        found = max(float(n_sig), 0.5)
        b = 2.0 ** fit / np.log(band.size / found) if found < band.size else 1.0
        coarser = scales_at.get(band.level + 1)
        if not n_sig and coarser:
            b = min(b, math.exp(sum(coarser) / len(coarser)) / 2)
        scales_at.setdefault(band.level, []).append(math.log(b))
        t = np.exp2(below[sl][unknown].astype(np.float64))
        r = np.exp(-t / b)
        mean_sq = 2 * b * b - (t * t + 2 * b * t) * r / np.maximum(1 - r, 1e-12)
        key = "busy" if n_sig else "idle"
        out[key][0] += BODY * float(np.maximum(mean_sq, 0.0).sum())
        out[key][1] += float((q[sl][unknown] ** 2).sum())
    return {k: (e / units, t / units) for k, (e, t) in out.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="640×480 only")
    args = parser.parse_args()
    errors: dict[tuple[str, int, str], list[float]] = defaultdict(list)
    energy: dict[tuple[str, int, str], list[float]] = defaultdict(lambda: [0.0, 0.0])
    for width, height in SIZES[2:] if args.quick else SIZES:
        for name, pictures in picture_sets(width, height).items():
            for _, pixels in pictures:
                stream = encode(pixels, BUDGET)
                geo, _ = state(stream[:4])
                q = magnitudes(pixels, geo)
                for n in prefixes(len(stream)):
                    decoded = decode(stream[:n])
                    errors[(name, width, stage(n))].append(
                        decoded.psnr_estimate - psnr(pixels, decoded.pixels))
                    g, st = state(stream[:n])
                    got = parts(g, st, q)
                    estimate = sum(e for e, _ in got.values()) / (width * height)
                    assert math.isclose(min(estimate, 128.0 ** 2),
                                        _mse_estimate(g, st, width * height), rel_tol=1e-9)
                    for key in ("busy", "idle"):
                        energy[(name, width, key)][0] += got[key][0]
                        energy[(name, width, key)][1] += got[key][1]
    print("estimate − true luma PSNR, dB: mean / mean |·| / worst")
    print(f"{'set':>12} {'size':>5} | " + " | ".join(f"{s:^22}" for s in
                                                      ("≤100 B", "≤1.6 kB", ">1.6 kB")))
    for name in ("listed", "camera-like", "texture"):
        for width, _ in SIZES:
            cells = []
            for s in ("≤100 B", "≤1.6 kB", ">1.6 kB"):
                e = np.array(errors.get((name, width, s), [np.nan]))
                cells.append(f"{e.mean():+5.1f} / {np.abs(e).mean():4.1f} / "
                             f"{e[np.argmax(np.abs(e))]:+5.1f}")
            if not np.isnan(errors.get((name, width, "≤100 B"), [np.nan])[0]):
                print(f"{name:>12} {width:>5} | " + " | ".join(cells))
    print("\nunknown coefficients' energy, truth / estimate (all prefixes)")
    print(f"{'set':>12} {'size':>5} | {'busy bands':>10} | {'idle bands':>10}")
    for name in ("listed", "camera-like", "texture"):
        for width, _ in SIZES:
            if (name, width, "busy") not in energy:
                continue
            ratios = [energy[(name, width, k)][1] / max(energy[(name, width, k)][0], 1e-9)
                      for k in ("busy", "idle")]
            print(f"{name:>12} {width:>5} | {ratios[0]:10.2f} | {ratios[1]:10.2f}")


if __name__ == "__main__":
    main()
