"""Progressive images: pixels to an embedded stream of a byte budget and back (pure).

:func:`encode` turns a grey (``h × w``) or colour (``h × w × 3``, RGB) ``uint8`` array into at
most ``budget`` bytes; :func:`decode` turns *any prefix* of them into the best image that
prefix holds, with its own estimate of the distortion. Colour goes as YCbCr with chroma at
half resolution and half weight; a decoded colour outside RGB's range comes back in
desaturated, its luma kept.

A region of interest (:class:`~bridge.image.geometry.Roi`) is coded as a picture of its own
(a *tile*), so its edges cost what a picture's edges cost and none of its bits go to
coefficients it shares with the rest (raising the ROI's coefficients in one transform of the
whole picture left ROI coding well short of the ROI coded alone: ``bench/image_bench.py``).
Its stream goes between two parts of the whole picture's: first a small share of the budget
(``2**-(shift + 1)``: a coarse picture of everything), then the tile, up to the budget or
until it is whole, then the rest of the whole picture's stream; the decoder puts the tile
over the ROI.

The stream, most significant bit first::

    version   2 bits, counted modulo 4 (1: the sixth, after 0; this decoder refuses the
              others, and the first 1, of the coder's second day, is long gone)
    colour    1 bit
    width-1   11 bits, height-1 11 bits
    top+1     5 bits: the highest bit plane (0: an empty image)
    roi       1 bit; when set x0, y0, x1, y1 (6 bits each, 64ths of the image), shift (3),
              the tile's top+1 (5), and how many bits the whole picture's first part and
              the tile's stream take (20 each)
    planes    the coefficients' bit planes (:mod:`bridge.image.bitplanes`), cut at the budget
              (with an ROI: the whole picture's first part, the tile's, the whole's rest)

Four bytes of header (13 with an ROI), against JPEG 2000's hundred and more.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from itertools import pairwise

import numpy as np
from numpy.typing import NDArray

from bridge.image.bitplanes import Planes, decode_planes, encode_planes
from bridge.image.geometry import Geometry, Roi, geometry
from bridge.image.wavelet import forward, inverse

__all__ = ["MAX_SIDE", "Decoded", "ImageStreamError", "decode", "encode", "header_bytes"]

VERSION = 1
MAX_SIDE = 2048
LENGTH_BITS = 20
"""Bits of the lengths in an ROI's header (a mission's budget is at most 64 kB)."""
FRACTION_BITS = 2  # quantiser step: a quarter of a (weighted) grey level
QUANTUM = float(1 << FRACTION_BITS)
MSE_CEILING = 128.0 ** 2
"""No picture is further off than every pixel by half the range (what the estimate of an
almost empty stream gives at most)."""
BODY = 0.3
"""Wavelet coefficients crowd nearer zero than the Laplacian their tail fits: the share of
its energy below threshold the distortion estimate keeps (``bench/image_bench.py`` checks the
estimate against the truth). 0.3: over eight scikit-image pictures and three seabeds, every
12th prefix up to 1.6 kB, the estimate is 0.13 dB above the truth on average, 1.30 dB off
in mean absolute value (0.25: +0.85 dB, 1.46; 0.4: -1.04 dB, 1.53)."""

U8 = NDArray[np.uint8]
F64 = NDArray[np.float64]


class ImageStreamError(ValueError):
    """Bytes that do not start a progressive image stream (too short, or another version)."""


@dataclass(frozen=True)
class Decoded:
    """An image decoded from a (possibly cut) stream."""

    pixels: U8
    stream_bytes: int
    complete: bool  # every bit plane arrived
    mse_estimate: float  # the stream's own estimate of the luma's mean squared error
    roi: Roi | None

    @property
    def psnr_estimate(self) -> float:
        """:attr:`mse_estimate` as PSNR (dB, peak 255)."""
        return 10 * math.log10(255 ** 2 / max(self.mse_estimate, 1e-3))


def header_bytes(roi: bool) -> int:
    """Bytes of the header (the planes start inside its last byte)."""
    return (_header_bits(roi) + 7) // 8


def _header_bits(roi: bool) -> int:
    return 2 + 1 + 11 + 11 + 5 + 1 + (24 + 3 + 5 + 2 * LENGTH_BITS if roi else 0)


def _components(pixels: U8) -> list[F64]:
    """Level-shifted planes: grey, or Y and half-size Cb, Cr."""
    if pixels.ndim == 2:
        grey = pixels.astype(np.float64)
        grey -= 128.0
        return [grey]
    r, g, b = (pixels[..., i].astype(np.float64) for i in range(3))  # (each one contiguous)
    t = np.empty_like(r)  # (the sums as written out, left to right, in fewer temporaries)
    y = r * 0.299
    y += np.multiply(g, 0.587, out=t)
    y += np.multiply(b, 0.114, out=t)
    y -= 128.0
    cb = r * -0.168736
    cb -= np.multiply(g, 0.331264, out=t)
    cb += np.multiply(b, 0.5, out=t)
    cr = r * 0.5
    cr -= np.multiply(g, 0.418688, out=t)
    cr -= np.multiply(b, 0.081312, out=t)
    return [y, _half(cb), _half(cr)]


def _half(c: F64) -> F64:
    h, w = c.shape
    if h % 2 or w % 2:
        c = np.pad(c, ((0, h % 2), (0, w % 2)), mode="edge")
    out = c[0::2, 0::2] + c[1::2, 0::2]
    out += c[0::2, 1::2]
    out += c[1::2, 1::2]
    out *= 0.25
    return out


@lru_cache(maxsize=8)
def _between(n: int, size: int) -> tuple[NDArray[np.intp], NDArray[np.intp], F64, F64]:
    """Where each of ``size`` samples falls between those of a half-size ``n``: the one
    before and after, and their weights."""
    at = np.clip((np.arange(size) + 0.5) / 2 - 0.5, 0, n - 1)
    before = np.floor(at).astype(np.intp)
    after = np.minimum(before + 1, n - 1)
    f = at - before
    return before, after, 1 - f, f


def _double(c: F64, h: int, w: int) -> F64:
    """Bilinear upsampling of a half-size chroma plane to ``h × w``."""
    ch, cw = c.shape
    y0, y1, gy, fy = _between(ch, h)
    x0, x1, gx, fx = _between(cw, w)

    def across(rows: F64) -> F64:
        out = rows.take(x0, axis=1) * gx
        out += rows.take(x1, axis=1) * fx
        return out

    out = across(c.take(y0, axis=0)) * gy[:, None]
    out += across(c.take(y1, axis=0)) * fy[:, None]
    return out


def _pixels(planes: list[F64]) -> U8:
    y = planes[0] + 128.0
    if len(planes) == 1:
        rgb = y
    else:
        h, w = y.shape
        cb, cr = _double(planes[1], h, w), _double(planes[2], h, w)
        g = y - 0.344136 * cb
        g -= 0.714136 * cr
        cr *= 1.402
        cb *= 1.772
        channels = (np.add(y, cr, out=cr), g, np.add(y, cb, out=cb))
        _into_gamut(channels, y)
        rgb = np.stack(channels, -1)
    np.rint(rgb, out=rgb)
    return np.clip(rgb, 0, 255, out=rgb).astype(np.uint8)


def _into_gamut(channels: tuple[F64, F64, F64], y: F64) -> None:
    """Bring the colours outside RGB's range back in, in place, by desaturating them: each
    keeps its luma ``y`` (clipped into range) and its hue, its chroma scaled down just
    enough. Clipping each channel instead changes their brightness (scikit-image colour
    320×240: +0.07 dB RGB PSNR at 800 B, +0.01 luma; underwater ones, never out of range,
    the same; ``bench/image_bench.py``)."""
    r, g, b = channels
    low = np.minimum(np.minimum(r, g), b)
    high = np.maximum(np.maximum(r, g), b)
    out = np.flatnonzero((low < 0) | (high > 255))  # (on whole planes: few are out)
    if not out.size:
        return
    luma, up, down = y.ravel()[out], high.ravel()[out], low.ravel()[out]
    inside = np.clip(luma, 0.0, 255.0)
    above = np.divide(255.0 - inside, up - luma, out=np.ones(out.size), where=up > luma)
    below = np.divide(inside, luma - down, out=np.ones(out.size), where=down < luma)
    scale = np.minimum(np.minimum(above, below, out=above), 1.0, out=above)
    for channel in channels:
        flat = channel.reshape(-1)
        flat[out] = inside + scale * (flat[out] - luma)


def encode(pixels: U8, budget: int, roi: Roi | None = None) -> bytes:
    """At most ``budget`` bytes of ``pixels`` (grey ``h × w`` or RGB ``h × w × 3``, uint8)."""
    array = np.asarray(pixels)
    if array.dtype != np.uint8 or array.ndim not in (2, 3) or (
            array.ndim == 3 and array.shape[2] != 3):
        raise ValueError(f"expected a uint8 h × w or h × w × 3 array, not {array.dtype} "
                         f"{array.shape}")
    height, width = array.shape[:2]
    if not (1 <= height <= MAX_SIDE and 1 <= width <= MAX_SIDE):
        raise ValueError(f"{width} × {height} is outside 1..{MAX_SIDE} pixels a side")
    if budget < header_bytes(roi is not None):
        raise ValueError(f"a budget of {budget} bytes cannot hold the header")
    if budget * 8 >= 1 << LENGTH_BITS:
        raise ValueError(f"a budget of {budget} bytes is over {(1 << LENGTH_BITS) // 8 - 1}")
    room = budget * 8 - _header_bits(roi is not None)
    top, whole = _planes(array if roi is None else _filled(array, *roi.box(height, width)),
                         room)
    head = [f"{VERSION:02b}", "1" if array.ndim == 3 else "0", f"{width - 1:011b}",
            f"{height - 1:011b}", f"{top + 1:05b}"]
    if roi is None:
        head.append("0")
        body = whole
    else:
        first = whole[:min((budget >> (roi.shift + 1)) * 8, room)]
        tile_top, tile = _planes(np.ascontiguousarray(array[roi.box(height, width)]),
                                 room - len(first))
        tile = tile[:room - len(first)]
        head += ["1", *(f"{v:06b}" for v in (roi.x0, roi.y0, roi.x1 - 1, roi.y1 - 1)),
                 f"{roi.shift:03b}", f"{tile_top + 1:05b}",
                 f"{len(first):0{LENGTH_BITS}b}", f"{len(tile):0{LENGTH_BITS}b}"]
        body = first + tile + whole[len(first):]
    bits = ("".join(head) + body)[:budget * 8]
    bits += "0" * (-len(bits) % 8)
    return int(bits, 2).to_bytes(len(bits) // 8, "big")


def _filled(array: U8, rows: slice, cols: slice) -> U8:
    """``array`` with the box ``rows`` × ``cols`` (the ROI, whose tile the decoder puts over
    it) smoothed over from its edges (the mean of the row-wise and the column-wise straight
    lines between the pixels just outside), so that the whole picture spends nothing there."""
    x = array.astype(np.float64)
    h, w = x.shape[:2]
    r0, r1, c0, c1 = rows.start, rows.stop, cols.start, cols.stop

    def line(a: F64, b: F64, n: int, axis: int) -> F64:
        t = (np.arange(n) + 1.0) / (n + 1)
        shape = [1] * a.ndim
        shape[axis] = n
        t = t.reshape(shape)
        return a * (1 - t) + b * t

    left = x[r0:r1, c0 - 1 if c0 else c1 % w][:, None]
    right = x[r0:r1, c1 if c1 < w else max(c0 - 1, 0)][:, None]
    top = x[r0 - 1 if r0 else r1 % h, c0:c1][None]
    bottom = x[r1 if r1 < h else max(r0 - 1, 0), c0:c1][None]
    x[rows, cols] = (line(left, right, c1 - c0, 1) + line(top, bottom, r1 - r0, 0)) / 2
    return np.clip(np.rint(x), 0, 255).astype(np.uint8)


def _planes(array: U8, budget_bits: int) -> tuple[int, str]:
    """A picture's top bit plane and its planes' bits (at least ``budget_bits`` of them, or
    all)."""
    height, width = array.shape[:2]
    geo = geometry(height, width, array.ndim == 3)
    canvases = np.concatenate([forward(c, lv).ravel() for c, lv in zip(
        _components(array), geo.levels, strict=True)])
    coefs = canvases[geo.order]
    scaled = np.abs(coefs)
    scaled *= geo.weight
    scaled *= QUANTUM
    q = np.floor(scaled, out=scaled).astype(np.int64)
    top = int(q.max()).bit_length() - 1 if q.size else -1
    if top < 0 or budget_bits <= 0:
        return top, ""
    return top, encode_planes(geo, q, coefs < 0, top, budget_bits)


@dataclass(frozen=True)
class _Header:
    colour: bool
    width: int
    height: int
    top: int
    roi: Roi | None
    at: int  # where the planes start
    tile_top: int = -1
    first: int = 0  # bits of the whole picture's first part (with an ROI)
    tile: int = 0  # bits of the tile's stream


def _read_header(bits: str) -> _Header:
    if len(bits) < _header_bits(False):
        raise ImageStreamError(f"{len(bits) // 8} bytes cannot hold an image header")
    version = int(bits[0:2], 2)
    if version != VERSION:
        raise ImageStreamError(f"stream version {version}, this decoder reads {VERSION}")
    colour = bits[2] == "1"
    width, height = int(bits[3:14], 2) + 1, int(bits[14:25], 2) + 1
    top = int(bits[25:30], 2) - 1
    if bits[30] != "1":
        return _Header(colour, width, height, top, None, 31)
    at = _header_bits(True)
    if len(bits) < at:  # a prefix that ends inside the ROI's header: no planes yet
        return _Header(colour, width, height, top, None, len(bits))
    x0, y0, x1, y1, shift, tile_top, first, tile = (
        int(bits[a:b], 2) for a, b in pairwise((31, 37, 43, 49, 55, 58, 63,
                                                63 + LENGTH_BITS, at)))
    try:
        roi = Roi(x0, y0, x1 + 1, y1 + 1, shift)
    except ValueError as exc:
        raise ImageStreamError(str(exc)) from None
    return _Header(colour, width, height, top, roi, at, tile_top - 1, first, tile)


@dataclass(frozen=True)
class _Picture:
    """One picture decoded from its planes' bits, before it becomes pixels."""

    planes: list[F64]
    complete: bool
    mse_estimate: float


def _picture(bits: str, height: int, width: int, colour: bool, top: int) -> _Picture:
    geo = geometry(height, width, colour)
    state = decode_planes(geo, bits, top) if top >= 0 else None
    canvases = np.zeros(geo.size)
    if state is not None:
        at, values = state.values()
        canvases[geo.order[at]] = values / (geo.weight[at] * QUANTUM)
    offsets = geo.offsets
    planes = [inverse(canvases[offsets[i]:offsets[i + 1]].reshape(shape), lv)
              for i, (shape, lv) in enumerate(zip(geo.shapes, geo.levels, strict=True))]
    return _Picture(planes, state is None or state.complete,
                    _mse_estimate(geo, state, height * width))


def decode(stream: bytes) -> Decoded:
    """The image any prefix of an :func:`encode` stream holds, from its first
    :func:`header_bytes` (``header_bytes(False)``, even with an ROI: one cut inside the
    ROI's header is a picture with nothing in it yet); a corrupt stream gives some image of
    the header's size; :class:`ImageStreamError` if there is no header."""
    bits = bin(int.from_bytes(b"\x01" + bytes(stream), "big"))[3:]
    head = _read_header(bits)
    body = bits[head.at:]
    roi = head.roi
    if roi is None:
        whole = _picture(body, head.height, head.width, head.colour, head.top)
        return Decoded(_pixels(whole.planes), len(stream), whole.complete,
                       whole.mse_estimate, None)
    ends = head.first + head.tile
    whole = _picture(body[:head.first] + body[ends:], head.height, head.width, head.colour,
                     head.top)
    rows, cols = roi.box(head.height, head.width)
    tile_h, tile_w = rows.stop - rows.start, cols.stop - cols.start
    tile = _picture(body[head.first:ends], tile_h, tile_w, head.colour, head.tile_top)
    pixels = _pixels(whole.planes)
    if len(body) > head.first:  # (until the tile starts, the whole's coarse fill stands)
        pixels[rows, cols] = _pixels(tile.planes)
    share = tile_h * tile_w / (head.height * head.width)
    mse = (1 - share) * whole.mse_estimate + share * tile.mse_estimate
    return Decoded(pixels, len(stream), whole.complete and tile.complete, mse, roi)


def _mse_estimate(geo: Geometry, state: Planes | None, pixels: int) -> float:
    """The luma's mean squared error as the stream knows it. A significant coefficient is
    off by a uniform error over its last interval; those still below their threshold ``t``
    are taken, band by band, as Laplacian with the scale that makes the share of the band
    above the last threshold all were tested against (at least half a coefficient) exceed
    it; in a band with none above it yet, at most half the level above's typical scale (their
    geometric mean: the largest made a picture's early estimates swing by dB as one band or
    another of a level woke, ``tests/image/test_codec.py``)."""
    if state is None:
        return 0.0
    units = QUANTUM ** 2  # squared quantiser units per squared grey level
    known = state.significant & geo.luma
    total = float(np.exp2(2 * state.plane[known]).sum()) / 12 / units
    if state.complete:
        return min(total / pixels, MSE_CEILING)
    bands = len(geo.bands)
    # Each band's scale is fitted at the last threshold every coefficient was tested against
    # (the plane before the one the stream stopped in): a pass tests the likeliest
    # coefficients first, so the share found so far in the current plane would overstate it.
    fit = state.threshold + 1
    sig, above, below = state.significant, state.magnitude >= 1 << fit, state.below
    # the coefficients of one band below one threshold share their expected square: count
    # them by (band, threshold) and weigh each group once (a threshold is at most 62: see
    # Planes.below)
    counts = np.zeros((bands, 64), dtype=np.int64)
    scales = np.ones(bands)
    scales_at: dict[int, list[float]] = {}  # each level's bands' scales (logs)
    for i, band in enumerate(geo.bands):  # (luma's bands: one slice of coding order each)
        if band.component:
            continue
        at = slice(band.start, band.start + band.size)
        unknown = ~sig[at]
        if not unknown.any():
            continue
        counts[i] = np.bincount(below[at][unknown], minlength=64)
        n_sig = int(np.count_nonzero(sig[at] & above[at]))
        found = max(float(n_sig), 0.5)
        b = 2.0 ** fit / np.log(band.size / found) if found < band.size else 1.0
        coarser = scales_at.get(band.level + 1)
        if not n_sig and coarser:  # nothing heard of this band yet: half the level above's
            b = min(b, math.exp(sum(coarser) / len(coarser)) / 2)  # (typical, not largest)
        scales_at.setdefault(band.level, []).append(math.log(b))
        scales[i] = b
    weights = counts.ravel() / units
    used = np.flatnonzero(weights)
    b = scales[used // 64]
    t = np.exp2((used % 64).astype(np.float64))
    r = np.exp(-t / b)
    # E[x² | x < t] for a Laplacian of scale b
    mean_sq = 2 * b * b - (t * t + 2 * b * t) * r / np.maximum(1 - r, 1e-12)
    total += BODY * float((np.maximum(mean_sq, 0.0) * weights[used]).sum())
    return min(total / pixels, MSE_CEILING)
