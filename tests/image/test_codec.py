"""The progressive image stream: budgets, prefixes, regions of interest, colour, and corrupt
streams (never a crash)."""

from __future__ import annotations

from itertools import pairwise

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bridge.image.codec import ImageStreamError, _pixels, decode, encode, header_bytes
from bridge.image.formats import fit, read_image, write_image
from bridge.image.geometry import CHROMA_WEIGHT, Roi, geometry
from bridge.image.synthetic import seabed
from bridge.image.wavelet import forward, inverse, levels_for

GREY = seabed(120, 160, seed=3, colour=False)
COLOUR = seabed(120, 160, seed=4)


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(float) - b.astype(float)) ** 2))
    return 10 * np.log10(255 ** 2 / max(mse, 1e-9))


@pytest.mark.parametrize("shape", [(240, 320), (121, 161), (7, 5), (1, 9), (2, 2)])
def test_the_wavelet_inverts_on_any_size(shape: tuple[int, int]) -> None:
    x = np.random.default_rng(1).normal(0, 50, shape)
    levels = levels_for(*shape)
    assert np.abs(inverse(forward(x, levels), levels) - x).max() < 1e-9


def luma_psnr(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR of the luma (what the stream's estimate is of)."""
    def luma(x: np.ndarray) -> np.ndarray:
        return x.astype(float) @ np.array([0.299, 0.587, 0.114]) if x.ndim == 3 else x
    return psnr(luma(a), luma(b))


@pytest.mark.parametrize(("shape", "colour"), [((24, 40), False), ((23, 37), True)])
def test_each_weight_is_its_coefficients_synthesis_norm(shape: tuple[int, int],
                                                          colour: bool) -> None:
    """A unit error in any coefficient (corners and edges too) costs its weight squared in
    squared error of the pixels (chroma: times the chroma weight squared)."""
    geo = geometry(*shape, colour)
    offsets = geo.offsets
    for at in range(0, geo.size, 7):
        spot = int(geo.order[at])
        comp = int(np.searchsorted(offsets, spot, side="right")) - 1
        canvas = np.zeros(geo.shapes[comp])
        canvas.flat[spot - offsets[comp]] = 1.0
        norm = float(np.sqrt((inverse(canvas, geo.levels[comp]) ** 2).sum()))
        assert geo.weight[at] == pytest.approx(norm * (CHROMA_WEIGHT if comp else 1.0))


def test_neighbours_are_those_around_a_coefficient_in_its_band() -> None:
    geo = geometry(23, 37, True)
    band_of, offsets = geo.band_of, geo.offsets

    def place(at: int) -> tuple[int, int]:
        band = geo.bands[band_of[at]]
        return divmod(int(geo.order[at]) - offsets[band.component],
                      geo.shapes[band.component][1])

    for at in range(geo.size):
        band = geo.bands[band_of[at]]
        r, c = place(at)
        around = {(r + dr, c + dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if dr or dc}
        inside = {(y, x) for y, x in around
                  if band.rows[0] <= y < band.rows[1] and band.cols[0] <= x < band.cols[1]}
        got = [int(n) for n in geo.neighbours[at] if n != geo.size]
        assert all(band_of[n] == band_of[at] for n in got)
        assert {place(n) for n in got} == inside and len(got) == len(inside)


@pytest.mark.parametrize("budget", [60, 200, 800, 1600])
def test_a_stream_fits_its_budget_exactly(budget: int) -> None:
    assert len(encode(GREY, budget)) == budget


def test_more_bytes_only_refine() -> None:
    stream = encode(GREY, 3200)
    scores = [psnr(GREY, decode(stream[:n]).pixels) for n in (8, 50, 200, 800, 3200)]
    assert scores == sorted(scores)
    assert scores[-1] > 38
    assert decode(stream[:200]).pixels.shape == GREY.shape


@pytest.mark.parametrize("roi", [None, Roi.from_fractions(0.25, 0.25, 0.75, 0.75)])
def test_every_prefix_decodes(roi: Roi | None) -> None:
    """From the first four bytes: a receiver whose fragments are shorter than an ROI's
    header shows a picture with nothing in it yet, not a malformed stream."""
    stream = encode(GREY, 400, roi)
    for n in range(header_bytes(False), len(stream) + 1):
        image = decode(stream[:n])
        assert image.pixels.shape == GREY.shape
        assert image.stream_bytes == n
        assert image.roi == (roi if n >= header_bytes(True) else None)


@pytest.mark.parametrize("roi", [None, Roi.from_fractions(0.25, 0.25, 0.75, 0.75)])
def test_a_large_budget_is_nearly_lossless_and_says_so(roi: Roi | None) -> None:
    image = decode(encode(GREY, 65536, roi))  # (the largest a mission allows)
    assert image.complete
    assert psnr(GREY, image.pixels) > 45


def test_the_distortion_estimate_follows_the_truth() -> None:
    stream = encode(GREY, 1600)
    for n in (200, 800, 1600):
        image = decode(stream[:n])
        assert abs(image.psnr_estimate - psnr(GREY, image.pixels)) < 4


@pytest.mark.parametrize("seed", [3, 11])
def test_the_distortion_estimate_does_not_fall_as_bytes_come(seed: int) -> None:
    """A viewer sees each refinement's estimate: more bytes never read as a worse picture,
    though a pass tests its likeliest coefficients first (within a tenth of a dB past the
    first 40 bytes; before, the bands' first coefficients may move it by half a dB)."""
    pixels = seabed(120, 160, seed=seed, colour=False)
    stream = encode(pixels, 800)
    estimates = [decode(stream[:n]).psnr_estimate for n in range(20, 801, 8)]
    falls = [(n, a, b) for n, (a, b) in zip(range(28, 801, 8), pairwise(estimates),
                                            strict=True) if b < a - (0.1 if n > 40 else 0.5)]
    assert not falls, falls


def test_the_first_refinements_estimate_no_better_picture_than_the_later_ones() -> None:
    """The tour's picture (a camera's JPEG of a seabed, made 160×120) in 19-byte fragments:
    its first refinement read 32.2 dB, the second 26.9 (the truth: 26.3, then 27.8), as
    though the picture got worse. And over seabeds as cameras give them, no refinement reads
    a dB worse than the one before, and the estimates are within about a dB of the truth."""
    def camera(seed: int, colour: bool) -> np.ndarray:
        jpeg = write_image(seabed(240, 320, seed=seed, colour=colour), "jpeg", quality=90)
        return fit(read_image(jpeg, "image/jpeg", ["jpeg"], 10**6, colour), 160, 120)

    tour = camera(11, False)
    stream = encode(tour, 95)
    pictures = [decode(stream[:n]) for n in range(19, 96, 19)]
    estimates = [p.psnr_estimate for p in pictures]
    assert estimates == sorted(estimates)
    assert abs(estimates[0] - luma_psnr(tour, pictures[0].pixels)) < 1.5
    errors = []
    for seed in range(4):
        for colour in (False, True):
            pixels = camera(seed, colour)
            stream = encode(pixels, 400)
            pictures = [decode(stream[:n]) for n in range(12, 401, 12)]
            estimates = [p.psnr_estimate for p in pictures]
            assert max(a - b for a, b in pairwise(estimates)) < 1.0, (seed, colour)
            errors += [p.psnr_estimate - luma_psnr(pixels, p.pixels) for p in pictures]
    assert np.mean(np.abs(errors)) < 1.1  # (0.90; 1.26 when a level's largest scale ruled)


def test_colour_goes_as_luma_and_half_size_chroma() -> None:
    image = decode(encode(COLOUR, 1600))
    assert image.pixels.shape == COLOUR.shape
    assert psnr(COLOUR, image.pixels) > 28


def test_a_colour_out_of_range_comes_back_desaturated_with_its_luma() -> None:
    to_rgb = np.array([[0.0, 1.402], [-0.344136, -0.714136], [1.772, 0.0]])  # (Cb, Cr)
    for y, cb, cr in np.random.default_rng(5).uniform(-150, 150, (200, 3)):
        rgb = _pixels([np.full((4, 4), y), np.full((2, 2), cb), np.full((2, 2), cr)])
        assert np.all(rgb == rgb[0, 0])
        got = rgb[0, 0].astype(float)
        luma = got @ np.array([0.299, 0.587, 0.114])
        assert abs(luma - np.clip(y + 128, 0, 255)) <= 0.5  # (channels rounded)
        chroma = to_rgb @ [cb, cr]
        scale = (got - luma) @ chroma / (chroma @ chroma)  # the same hue, less of it
        assert np.abs(got - luma - scale * chroma).max() <= 1.0
        assert -0.01 <= scale <= 1.01
        plain = y + 128 + chroma
        if np.all((plain >= 0) & (plain <= 255)):  # in range: as converted
            assert np.abs(got - plain).max() <= 0.5


def test_a_region_of_interest_sharpens_first() -> None:
    roi = Roi.from_fractions(0.25, 0.25, 0.75, 0.75)
    inside = (slice(30, 90), slice(40, 120))
    plain = decode(encode(GREY, 400)).pixels
    raised = decode(encode(GREY, 400, roi))
    assert raised.roi == roi
    assert psnr(GREY[inside], raised.pixels[inside]) > psnr(GREY[inside], plain[inside]) + 1


def test_an_roi_stream_brings_a_coarse_whole_first_then_the_roi() -> None:
    roi = Roi.from_fractions(0.25, 0.25, 0.75, 0.75)
    stream = encode(GREY, 800, roi)
    inside = roi.box(*GREY.shape)
    outside = np.ones(GREY.shape, dtype=bool)
    outside[inside] = False
    for n in range(header_bytes(True), len(stream) + 1):
        assert decode(stream[:n]).pixels.shape == GREY.shape
    coarse = decode(stream[:header_bytes(True) + (800 >> (roi.shift + 1))]).pixels
    whole = decode(stream).pixels
    flat = np.full(GREY.shape, 128, dtype=np.uint8)
    assert psnr(GREY[outside], coarse[outside]) > psnr(GREY[outside], flat[outside]) + 3
    assert psnr(GREY[inside], whole[inside]) > psnr(GREY[inside], coarse[inside]) + 10


def test_an_roi_outside_64ths_is_refused() -> None:
    with pytest.raises(ValueError, match="not inside"):
        Roi(10, 10, 5, 20)


def test_bad_pixels_and_budgets_are_refused() -> None:
    with pytest.raises(ValueError, match="uint8"):
        encode(GREY.astype(float), 100)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="header"):
        encode(GREY, 2)


def test_no_header_is_a_clear_error() -> None:
    with pytest.raises(ImageStreamError):
        decode(b"\x00\x01")
    with pytest.raises(ImageStreamError, match="version 2"):  # the stream before ROI tiles
        decode(b"\xbf" + b"\xff" * 7)
    stream = bytearray(encode(GREY, 200))
    stream[0] |= 0xC0  # version 3: the stream before the runs started lower each plane
    with pytest.raises(ImageStreamError, match="version 3"):
        decode(bytes(stream))
    stream[0] &= 0x3F  # version 0: the stream before each coefficient's own weight
    with pytest.raises(ImageStreamError, match="version 0"):
        decode(bytes(stream))


STREAMS = [encode(COLOUR, 600), encode(COLOUR, 600, Roi.from_fractions(0.1, 0.2, 0.6, 0.9))]


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_corrupt_streams_decode_to_some_image_or_a_clear_error(data: st.DataObject) -> None:
    whole = data.draw(st.sampled_from(STREAMS))
    stream = bytearray(whole[:data.draw(st.integers(0, len(whole)))])
    for _ in range(data.draw(st.integers(0, 8))):
        if stream:
            at = data.draw(st.integers(0, len(stream) - 1))
            stream[at] ^= 1 << data.draw(st.integers(0, 7))
    stream += data.draw(st.binary(max_size=64))
    try:
        image = decode(bytes(stream))
    except ImageStreamError:
        return
    assert image.pixels.dtype == np.uint8
    assert image.pixels.shape[:2] == (int.from_bytes(stream[:4], "big") >> 7 & 0x7FF) + 1 \
        or image.pixels.ndim in (2, 3)
