"""Image files in and out: types by encoding or signature, refusals before decoding."""

from __future__ import annotations

import io
import struct
import warnings
import zlib

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from PIL import Image

from bridge.image.formats import (
    ImageInputError,
    fit,
    kind_of,
    open_image,
    read_image,
    read_raw,
    write_image,
)
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


@pytest.mark.parametrize("data, encoding, said, was", [
    (PNG, "image/jpeg", "image/jpeg", "PNG"), (JPEG, "image/png", "image/png", "JPEG"),
    (PNG, "image/jpg", "image/jpg", "PNG")], ids=["png-as-jpeg", "jpeg-as-png", "png-as-jpg"])
def test_an_encoding_that_names_the_other_type_is_refused_saying_so(
        data: bytes, encoding: str, said: str, was: str) -> None:
    """A PNG put as image/jpeg is not a picture the sample says it is: refused, naming both."""
    with pytest.raises(ImageInputError) as refused:
        open_image(data, encoding, {"jpeg", "png"}, 10**6, colour=False)
    assert str(refused.value) == f"the encoding says {said} but the bytes are a {was} image"
    assert refused.value.cause == "unfit"


def test_a_type_not_enabled_is_refused() -> None:
    with pytest.raises(ImageInputError, match="png images are not enabled"):
        read_image(PNG, "image/png", {"jpeg"}, 10_000, colour=False)


def test_too_many_pixels_are_refused_before_decoding() -> None:
    with pytest.raises(ImageInputError, match="more than the channel's 4000"):
        read_image(PNG, "image/png", {"png"}, 4000, colour=False)


def png_declaring(width: int, height: int) -> bytes:
    """A tiny PNG whose header declares ``width × height`` pixels (a decompression bomb's
    header: its few bytes of data would inflate to the declared size)."""
    data = write_image(np.zeros((8, 8), np.uint8), "png")
    at = data.index(b"IHDR")
    body = struct.pack(">II", width, height) + data[at + 12:at + 17]
    return data[:at + 4] + body + struct.pack(">I", zlib.crc32(b"IHDR" + body)) + \
        data[at + 21:]


def jpeg_declaring(width: int, height: int) -> bytes:
    """A small JPEG whose frame header (SOF0) declares ``width × height`` pixels."""
    data = bytearray(write_image(np.zeros((8, 8), np.uint8), "jpeg"))
    at = data.index(b"\xff\xc0")
    data[at + 5:at + 9] = struct.pack(">HH", height, width)
    return bytes(data)


@pytest.mark.parametrize("bomb, kind", [
    (png_declaring(20000, 20000), "png"),  # over Pillow's error limit (2 × 89 M pixels)
    (png_declaring(10000, 10000), "png"),  # over its warning limit only
    (jpeg_declaring(20000, 20000), "jpeg"),
], ids=["png-error", "png-warning", "jpeg"])
def test_a_decompression_bomb_is_too_large_whatever_the_channel_s_limit(
        bomb: bytes, kind: str) -> None:
    """A header declaring more pixels than Pillow decodes is refused as too large (with the
    pixels it declares), not as undecodable bytes, and no warning escapes; even where the
    channel's own limit would take that many."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ImageInputError, match="pixels") as refused:
            open_image(bomb, f"image/{kind}", {kind}, 10**9, colour=False)
    assert refused.value.cause == "too_large"
    assert "decompression bomb" in str(refused.value)


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


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(["PNG", "JPEG"]), st.integers(1, 8), st.binary(max_size=8),
       st.lists(st.tuples(st.integers(0, 60), st.integers(0, 255)), max_size=6),
       st.integers(0, 60))
def test_a_picture_with_an_exif_block_it_cannot_read_shows_upright(
        kind: str, orientation: int, junk: bytes, flips: list[tuple[int, int]], cut: int
        ) -> None:
    """Cameras write EXIF blocks that are cut or garbled: the picture's pixels are fine, so
    it is taken (upright where the block cannot be read), never a crash; its layout, which
    says whether a ROS 2 viewer may show the file as it is, never ignores a turn."""
    pixels = np.zeros((6, 10), dtype=np.uint8)
    pixels[:, :5] = 255
    tags = Image.Exif()
    tags[0x0112] = orientation
    block = bytearray(tags.tobytes())
    for at, value in flips:
        if at < len(block):
            block[at] = value
    block = block[:len(block) - cut] + junk if cut else block + junk
    out = io.BytesIO()
    Image.fromarray(pixels).save(out, kind, exif=bytes(block))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # (Pillow warns of the corrupt block)
        image = open_image(out.getvalue(), "", {"jpeg", "png"}, 10_000, colour=False)
        shown = image.pixels()
    assert shown.shape in ((6, 10), (10, 6))
    if image.layout is not None:  # (as it is: upright)
        assert shown.shape == (6, 10) and shown[:, :5].mean() > 200 > 50 > shown[:, 5:].mean()


def _raw(pixels: np.ndarray, encoding: str, big: bool = False, pad: int = 0) -> dict:
    """A sensor_msgs/Image as plain data, each row padded by ``pad`` bytes."""
    h, w = pixels.shape[:2]
    data = pixels.astype(pixels.dtype.newbyteorder(">" if big else "<")).tobytes()
    row = len(data) // h
    rows = b"".join(data[r * row:(r + 1) * row] + b"\0" * pad for r in range(h))
    return {"height": h, "width": w, "encoding": encoding, "is_bigendian": big,
            "step": row + pad, "data": rows}


def test_raw_pictures_read_in_every_encoding_taken() -> None:
    rgb = PIXELS
    assert np.array_equal(read_raw(_raw(rgb, "rgb8", pad=3), 10_000, colour=True), rgb)
    assert np.array_equal(read_raw(_raw(rgb[..., ::-1], "bgr8"), 10_000, colour=True), rgb)
    wide = rgb.astype(np.uint16) * 256 + 7  # each channel's high byte is the 8-bit value
    for big in (False, True):
        assert np.array_equal(read_raw(_raw(wide, "rgb16", big), 10_000, colour=True), rgb)
        mono = read_raw(_raw(wide[..., 0], "mono16", big, pad=2), 10_000, colour=False)
        assert np.array_equal(mono, rgb[..., 0])
    alpha = np.concatenate([wide[..., ::-1], wide[..., :1]], axis=2)
    assert np.array_equal(read_raw(_raw(alpha, "bgra16"), 10_000, colour=True), rgb)
    grey = read_raw(_raw(rgb, "rgb8"), 10_000, colour=False)
    assert np.abs(grey.astype(int) - rgb @ np.array([0.299, 0.587, 0.114])).max() <= 0.5


def test_raw_pictures_that_do_not_fit_are_refused() -> None:
    with pytest.raises(ImageInputError, match="'yuv422' is not one zab reads") as refused:
        read_raw(_raw(PIXELS, "yuv422"), 10_000, colour=True)
    assert refused.value.cause == "unfit"
    short = _raw(PIXELS, "rgb8") | {"step": 100}
    with pytest.raises(ImageInputError, match="does not fit"):
        read_raw(short, 10_000, colour=True)
    with pytest.raises(ImageInputError, match="more than the channel's 100"):
        read_raw(_raw(PIXELS, "rgb8"), 100, colour=True)
    with pytest.raises(ImageInputError, match="not a sensor_msgs/Image"):
        read_raw({"height": 2}, 10_000, colour=True)
