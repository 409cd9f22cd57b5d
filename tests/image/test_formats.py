"""Image files in and out: types by encoding or signature, refusals before decoding."""

from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image

from bridge.image.formats import ImageInputError, fit, kind_of, read_image, write_image
from bridge.image.synthetic import seabed

PIXELS = seabed(60, 80, seed=1)
JPEG = write_image(PIXELS, "jpeg", quality=85)
PNG = write_image(PIXELS, "png", text={"seq": 3})


def test_the_encoding_or_the_signature_names_the_type() -> None:
    assert kind_of(JPEG, "image/jpeg") == "jpeg"
    assert kind_of(PNG, "image/png;charset=binary") == "png"
    assert kind_of(PNG, "zenoh/bytes") == "png"
    assert kind_of(JPEG, "application/octet-stream") == "jpeg"
    with pytest.raises(ImageInputError, match="image/gif"):
        kind_of(b"GIF89a", "image/gif")
    with pytest.raises(ImageInputError, match="not a JPEG or PNG"):
        kind_of(b"hello", "text/plain")


def test_images_read_grey_or_colour() -> None:
    grey = read_image(PNG, "image/png", {"png"}, 10_000, colour=False)
    assert grey.shape == (60, 80)
    rgb = read_image(JPEG, "image/jpeg", {"jpeg"}, 10_000, colour=True)
    assert rgb.shape == (60, 80, 3)
    assert np.abs(rgb.astype(int) - PIXELS).mean() < 6


def test_a_type_not_enabled_is_refused() -> None:
    with pytest.raises(ImageInputError, match="png images are not enabled"):
        read_image(PNG, "image/png", {"jpeg"}, 10_000, colour=False)


def test_too_many_pixels_are_refused_before_decoding() -> None:
    with pytest.raises(ImageInputError, match="more than the channel's 4000"):
        read_image(PNG, "image/png", {"png"}, 4000, colour=False)


def test_undecodable_bytes_are_refused() -> None:
    with pytest.raises(ImageInputError, match="cannot decode"):
        read_image(JPEG[:40], "image/jpeg", {"jpeg"}, 10_000, colour=False)


def test_fit_keeps_proportions_and_never_enlarges() -> None:
    assert fit(PIXELS, 40, 40).shape == (30, 40, 3)
    assert fit(PIXELS, 800, 600) is PIXELS


def test_png_metadata_is_readable() -> None:
    image = Image.open(io.BytesIO(PNG))
    assert image.text == {"seq": "3"}  # type: ignore[attr-defined]


def _png16(values: np.ndarray) -> bytes:
    """A 16-bit grey PNG of ``values`` (Pillow opens it as mode ``I;16``)."""
    out = io.BytesIO()
    Image.fromarray(values.astype(np.uint16)).save(out, "PNG")
    return out.getvalue()


def test_a_16_bit_grey_png_reads_as_its_high_bytes() -> None:
    ramp = np.linspace(0, 65535, 48 * 64).reshape(48, 64).astype(np.uint16)
    data = _png16(ramp)
    assert Image.open(io.BytesIO(data)).mode == "I;16"
    grey = read_image(data, "image/png", {"png"}, 10_000, colour=False)
    assert np.array_equal(grey, (ramp >> 8).astype(np.uint8))  # (Pillow's own clips at 255)
    rgb = read_image(data, "image/png", {"png"}, 10_000, colour=True)
    assert np.array_equal(rgb, np.repeat(grey[..., None], 3, axis=2))


def test_a_jpeg_is_turned_upright_by_its_exif_orientation() -> None:
    pixels = np.zeros((40, 80, 3), dtype=np.uint8)
    pixels[:, :40] = 255  # white on the left
    image = Image.fromarray(pixels)
    exif = image.getexif()
    exif[0x0112] = 6  # the camera was turned: show it rotated 90° clockwise
    out = io.BytesIO()
    image.save(out, "JPEG", exif=exif.tobytes(), quality=95)
    rgb = read_image(out.getvalue(), "image/jpeg", {"jpeg"}, 10_000, colour=True)
    assert rgb.shape == (80, 40, 3)
    assert rgb[:30].mean() > 200 > 50 > rgb[50:].mean()  # the left is now on top
