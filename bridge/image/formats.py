"""Standard image files in and out (Pillow): what applications publish, what viewers read.

:func:`open_image` takes the bytes of a JPEG or PNG sample (the Zenoh encoding says which, or
the bytes' signature when it says nothing), refusing a type not enabled and anything larger
than a pixel limit by its header (no decompression bombs), and decodes it when first asked
(upright, by its EXIF orientation);
:func:`fit` scales pixels to fit a size; :func:`write_image` makes a PNG (metadata in ``tEXt``
chunks) or a JPEG (metadata in a comment).
"""

from __future__ import annotations

import contextlib
import io
import json
import struct
import warnings
from collections.abc import Callable, Collection, Iterator, Mapping
from functools import partial
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["KINDS", "ImageInputError", "InputImage", "fit", "kind_of", "open_image",
           "open_raw", "orientation", "read_image", "read_raw", "read_text", "write_image"]

KINDS = {"jpeg": "image/jpeg", "png": "image/png"}
"""Image types an input may take, by name, with their Zenoh encodings."""

_SIGNATURES = {b"\xff\xd8\xff": "jpeg", b"\x89PNG\r\n\x1a\n": "png"}

U8 = NDArray[np.uint8]


class ImageInputError(ValueError):
    """An input sample that is not a usable image (the message says why; ``cause``:
    ``undecodable``, ``too_large`` or ``unfit``: a type not taken)."""

    def __init__(self, message: str, cause: str = "undecodable") -> None:
        super().__init__(message)
        self.cause = cause


def kind_of(data: bytes, encoding: str) -> str:
    """``jpeg`` or ``png``: from the encoding (``image/jpeg`` …) or, when it names no image
    type (``zenoh/bytes``, ``application/octet-stream``), from the bytes' signature. An
    encoding naming one type on the other's signature is refused (``unfit``): neither is
    trusted."""
    kind = encoding.partition(";")[0].strip().lower()
    for name, mime in KINDS.items():
        if kind == mime or (name == "jpeg" and kind == "image/jpg"):
            for signature, other in _SIGNATURES.items():
                if other != name and data.startswith(signature):
                    raise ImageInputError(f"the encoding says {kind} but the bytes are a "
                                          f"{other.upper()} image", "unfit")
            return name
    if kind.startswith("image/"):
        raise ImageInputError(f"image type {kind!r} is not one zab reads (jpeg, png)", "unfit")
    for signature, name in _SIGNATURES.items():
        if data.startswith(signature):
            return name
    raise ImageInputError(f"not a JPEG or PNG image (encoding {encoding or 'none'!r})")


class InputImage:
    """An input picture whose header has been read (type and size checked); its pixels are
    decoded when first asked for, then kept. A camera faster than the water has most of its
    pictures replaced before they are sent: those are never decoded (a 1080p JPEG is ~13 ms)."""

    __slots__ = ("_decode", "_pixels", "kind", "layout")

    def __init__(self, decode: Callable[[], U8], kind: str | None = None,
                 layout: str | None = None) -> None:
        self._decode: Callable[[], U8] | None = decode
        self._pixels: U8 | None = None
        self.kind = kind
        """``jpeg`` or ``png`` for a file (None: raw pixels)."""
        self.layout = layout
        """How the file's pixels are laid out, as Pillow names it (``L``, ``RGB``, ``RGBA``,
        ``I;16B`` …), where a viewer shows them upright as they are (None: an EXIF
        orientation turns them)."""

    def pixels(self) -> U8:
        """The pixels; raises :class:`ImageInputError` if the bytes past the header are bad."""
        if self._pixels is None:
            assert self._decode is not None
            self._pixels, self._decode = self._decode(), None
        return self._pixels


def open_image(data: bytes, encoding: str, accept: Collection[str], max_pixels: int,
               colour: bool) -> InputImage:
    """An image sample checked by its header, to be decoded when needed
    (``h × w`` grey, or ``h × w × 3`` RGB when ``colour``). Raises :class:`ImageInputError`
    for a type not in ``accept``, an image of more than ``max_pixels`` pixels, or bytes that
    are no image Pillow reads."""
    kind = kind_of(data, encoding)
    if kind not in accept:
        raise ImageInputError(f"{kind} images are not enabled on this channel "
                              f"(accept: {', '.join(sorted(accept)) or 'none'})", "unfit")
    with _pillow_errors(kind, data):
        image = _open(data, kind)
        width, height = image.size
        layout = _layout(image)
    if width * height > max_pixels:
        raise ImageInputError(f"{width} × {height} pixels is more than the channel's "
                              f"{max_pixels}", "too_large")
    return InputImage(partial(_decoded, data, kind, colour), kind, layout)


def _layout(image: Any) -> str | None:
    """The raw mode of an open Pillow image's pixels (``RGB;16B`` for a 16-bit colour PNG
    Pillow makes ``RGB``), None where its EXIF orientation turns it."""
    if not image.tile or orientation(image) != 1:
        return None
    args = image.tile[0][3]
    raw = args[0] if isinstance(args, tuple) else args
    return raw if isinstance(raw, str) else None


def orientation(image: Any) -> int:
    """The EXIF orientation of an open Pillow image, from its header (a PNG's ``getexif``
    would decode it): 1 where it has none, or a block that cannot be read (decoding shows
    such a picture upright too)."""
    from PIL import Image

    exif = image.info.get("exif")
    if not isinstance(exif, bytes):
        return 1
    tags = Image.Exif()
    try:
        tags.load(exif)
    except (struct.error, SyntaxError):
        return 1
    value = tags.get(_ORIENTATION, 1)
    return value if isinstance(value, int) else 1


_ORIENTATION = 0x0112


def read_image(data: bytes, encoding: str, accept: Collection[str], max_pixels: int,
               colour: bool) -> U8:
    """The pixels of an image sample: :func:`open_image`, decoded at once."""
    return open_image(data, encoding, accept, max_pixels, colour).pixels()


def _open(data: bytes, kind: str) -> Any:
    """Pillow's lazy image of ``data`` (the header read, no pixels yet)."""
    from PIL import Image  # (Pillow loads with the first picture)

    return Image.open(io.BytesIO(data), formats=[kind.upper()])


def _decoded(data: bytes, kind: str, colour: bool) -> U8:
    """The pixels as a viewer shows them: turned upright by the EXIF orientation a camera
    wrote, and 16-bit grey (PNG) by its high bytes, as a raw ``mono16`` (Pillow's own
    conversion clips it at 255: a white picture)."""
    from PIL import Image, ImageOps

    with _pillow_errors(kind, data):
        image = _open(data, kind)
        with contextlib.suppress(struct.error, SyntaxError):  # (EXIF it cannot read: upright)
            ImageOps.exif_transpose(image, in_place=True)
        if image.mode.startswith("I"):  # I;16 (or I): 16-bit grey
            high = np.clip(np.asarray(image), 0, 65535) >> 8
            image = Image.fromarray(high.astype(np.uint8))
        converted = image.convert("RGB" if colour else "L")
        return np.asarray(converted, dtype=np.uint8).copy()


@contextlib.contextmanager
def _pillow_errors(kind: str, data: bytes) -> Iterator[None]:
    """Pillow's complaints about ``data`` as :class:`ImageInputError` (a decompression bomb:
    ``too_large``)."""
    from PIL import Image, UnidentifiedImageError

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            yield
    except UnidentifiedImageError:
        raise ImageInputError(f"not a decodable {kind} image ({len(data)} bytes)") from None
    except (Image.DecompressionBombError, Image.DecompressionBombWarning) as exc:
        # (its header declares more pixels than Pillow decodes, whatever the channel takes)
        raise ImageInputError(f"the {kind} image's header declares more pixels than zab "
                              f"decodes, a decompression bomb? ({len(data)} bytes: {exc})",
                              "too_large") from None
    except (OSError, ValueError, SyntaxError, struct.error) as exc:
        raise ImageInputError(f"cannot decode the {kind} image: {exc}") from None


RAW = {"mono8": (1, 1), "mono16": (1, 2), "rgb8": (3, 1), "bgr8": (3, 1), "rgba8": (4, 1),
       "bgra8": (4, 1), "rgb16": (3, 2), "bgr16": (3, 2), "rgba16": (4, 2), "bgra16": (4, 2),
       "8UC1": (1, 1), "8UC3": (3, 1), "16UC1": (1, 2)}
"""Raw pixel encodings taken (sensor_msgs/Image, its ``image_encodings``): channels and bytes
per channel (16-bit ones by their high bytes)."""


def open_raw(message: Mapping[str, Any], max_pixels: int, colour: bool) -> InputImage:
    """A ``sensor_msgs/msg/Image`` as plain data (``height``, ``width``, ``encoding``,
    ``is_bigendian``, ``step``, ``data``), its fields checked now and its pixels laid out when
    first asked for (a 1080p rgb8 frame made grey is ~30 ms: at 30 frames a second, a core
    for pictures mostly replaced before they are sent). Raises :class:`ImageInputError`."""
    try:
        height, width = int(message["height"]), int(message["width"])
        encoding, step = str(message["encoding"]), int(message["step"])
        data = message["data"]
        size = len(data)
    except (KeyError, TypeError, ValueError) as exc:
        raise ImageInputError(f"not a sensor_msgs/Image: {exc}") from None
    if encoding not in RAW:
        raise ImageInputError(f"raw encoding {encoding!r} is not one zab reads "
                              f"({', '.join(RAW)})", "unfit")
    if height * width > max_pixels:
        raise ImageInputError(f"{width} × {height} pixels is more than the channel's "
                              f"{max_pixels}", "too_large")
    channels, depth = RAW[encoding]
    if height < 1 or width < 1 or step < width * channels * depth or size < height * step:
        raise ImageInputError(f"{width} × {height} {encoding} does not fit its {size} "
                              f"bytes (step {step})")
    return InputImage(partial(_raw_pixels, bytes(data), height, width, step, encoding,
                              bool(message.get("is_bigendian")), colour))


def read_raw(message: Mapping[str, Any], max_pixels: int, colour: bool) -> U8:
    """The pixels of a ``sensor_msgs/msg/Image``: :func:`open_raw`, laid out at once."""
    return open_raw(message, max_pixels, colour).pixels()


def _raw_pixels(data: bytes, height: int, width: int, step: int, encoding: str,
                big_endian: bool, colour: bool) -> U8:
    channels, depth = RAW[encoding]
    rows = np.frombuffer(data, dtype=np.uint8)[:height * step].reshape(height, step)
    flat = rows[:, :width * channels * depth]
    if depth == 2:  # 16 bits a channel: keep the high byte
        flat = flat[:, 0::2] if big_endian else flat[:, 1::2]
    pixels = flat.reshape(height, width, channels)
    if encoding.startswith("bgr"):
        pixels = pixels[..., 2::-1]
    pixels = pixels[..., :3]
    if channels == 1:
        pixels = np.repeat(pixels, 3, axis=2) if colour else pixels[..., 0]
    elif not colour:
        grey = pixels.astype(np.float64) @ np.array([0.299, 0.587, 0.114])
        pixels = np.clip(np.rint(grey), 0, 255)
    return np.ascontiguousarray(pixels, dtype=np.uint8)


def fit(pixels: U8, width: int, height: int) -> U8:
    """``pixels`` scaled to fit ``width × height``, keeping their shape's proportions
    (never enlarged)."""
    from PIL import Image

    h, w = pixels.shape[:2]
    ratio = min(width / w, height / h, 1.0)
    size = (max(1, round(w * ratio)), max(1, round(h * ratio)))
    if size == (w, h):
        return pixels
    resized = Image.fromarray(pixels).resize(size, Image.Resampling.LANCZOS)
    return np.asarray(resized, dtype=np.uint8).copy()


def write_image(pixels: U8, kind: str = "png", quality: int = 90,
                text: Mapping[str, Any] | None = None) -> bytes:
    """``pixels`` as a PNG (``text`` in ``tEXt`` chunks) or a JPEG at ``quality`` (``text``
    as JSON in its comment)."""
    from PIL import Image
    from PIL.PngImagePlugin import PngInfo

    image = Image.fromarray(pixels)
    out = io.BytesIO()
    if kind == "png":
        info = PngInfo()
        for key, value in (text or {}).items():
            info.add_text(key, str(value))
        image.save(out, format="PNG", pnginfo=info, compress_level=6)
    elif kind == "jpeg":
        comment = json.dumps(dict(text or {}), separators=(",", ":")).encode()
        image.save(out, format="JPEG", quality=quality, comment=comment)
    else:
        raise ValueError(f"cannot write {kind!r} images (png, jpeg)")
    return out.getvalue()


def read_text(image: Any) -> dict[str, Any]:
    """The ``text`` :func:`write_image` wrote in ``image`` (an open Pillow image): a PNG's
    text chunks, or the object a JPEG's JSON comment holds (a comment that is no JSON object
    comes back as ``comment``); each ``zab:`` value parsed from its JSON (text stays text)."""
    text = dict(getattr(image, "text", None) or {})
    comment = image.info.get("comment")
    if isinstance(comment, bytes):
        try:
            said = json.loads(comment)
        except ValueError:
            said = None
        if isinstance(said, dict):
            text.update(said)
        else:
            text["comment"] = comment.decode("utf-8", "replace")
    for key, value in text.items():
        if str(key).startswith("zab:") and isinstance(value, str):
            with contextlib.suppress(ValueError):
                text[key] = json.loads(value)
    return text
