"""Underwater-looking test pictures, made from a seed (numpy only).

A seabed scene — rocks and sand ripples under a sloping floor, a pipe crossing it — seen
through water: contrast falls with distance towards a blue-green veiling light, red fades
first, and *marine snow* (bright specks, some out of focus) hangs in front. Used by the tests,
the benchmark and the demo, so none of them needs an image file.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["seabed"]

VEIL = np.array([30.0, 110.0, 120.0])  # the water's own colour (RGB)
ATTENUATION = np.array([1.3, 0.4, 0.3])  # per channel, over the scene's depth


def _smooth_noise(rng: np.random.Generator, h: int, w: int, cells: int) -> NDArray[np.float64]:
    """Value noise: a coarse random grid, bilinearly interpolated to ``h × w``."""
    gh, gw = cells + 1, max(2, round(cells * w / h)) + 1
    grid = rng.random((gh, gw))
    ys, xs = np.linspace(0, gh - 1.001, h), np.linspace(0, gw - 1.001, w)
    y0, x0 = ys.astype(int), xs.astype(int)
    fy, fx = (ys - y0)[:, None], (xs - x0)[None, :]
    a, b = grid[y0][:, x0], grid[y0][:, x0 + 1]
    c, d = grid[y0 + 1][:, x0], grid[y0 + 1][:, x0 + 1]
    return (a * (1 - fx) + b * fx) * (1 - fy) + (c * (1 - fx) + d * fx) * fy  # type: ignore[no-any-return]


def seabed(height: int = 240, width: int = 320, seed: int = 0,
           colour: bool = True, snow: int = 60) -> NDArray[np.uint8]:
    """A ``height × width`` underwater scene (RGB, or its grey when not ``colour``)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:height, 0:width] / max(height, width)
    rocks = sum(_smooth_noise(rng, height, width, c) / i for i, c in ((1, 4), (2, 9), (4, 23)))
    ripples = 0.5 + 0.5 * np.sin(40 * (xx + 0.15 * yy) + 3 * _smooth_noise(rng, height, width, 5))
    albedo = 0.2 + 0.6 * (rocks / 1.75) ** 2 + 0.1 * ripples
    pipe = np.abs(yy - (0.55 + 0.25 * xx - 0.1)) < 0.035  # a pipe crossing the floor
    albedo = np.where(pipe, 0.75 - 3 * np.abs(yy - (0.45 + 0.25 * xx)), albedo)
    scene = albedo[..., None] * np.array([200.0, 180.0, 150.0])
    distance = 1.3 - yy[..., None]  # the floor slopes away: far at the top
    transmission = np.exp(-ATTENUATION * distance)
    image = scene * transmission + VEIL * (1 - transmission)
    for _ in range(snow):  # marine snow: specks, the nearer ones larger and blurred
        cy, cx = rng.random() * height, rng.random() * width
        radius = 0.6 + 2.5 * rng.random() ** 3
        glow = np.exp(-(((np.arange(height)[:, None] - cy) ** 2
                         + (np.arange(width)[None, :] - cx) ** 2) / (2 * radius ** 2)))
        image += (70 + 90 * rng.random()) * glow[..., None]
    image += rng.normal(0, 2.0, image.shape)  # sensor noise
    pixels = np.clip(np.rint(image), 0, 255).astype(np.uint8)
    if colour:
        return pixels  # type: ignore[no-any-return]
    grey = pixels.astype(np.float64) @ np.array([0.299, 0.587, 0.114])
    return np.clip(np.rint(grey), 0, 255).astype(np.uint8)  # type: ignore[no-any-return]
