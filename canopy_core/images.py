"""Decoding and checking the image files of a capture: 16-bit depth PNGs and 8-bit RGB colour images.

Works on bytes or a file, so that the service checks an upload (streamed to a file) with exactly the checks
the offline loader makes. Pillow reads the header first, so an oversized image (a decompression bomb) is
refused before decoding.
"""

from __future__ import annotations

import io
from pathlib import Path, PurePosixPath

import numpy as np
from PIL import Image, UnidentifiedImageError

from canopy_core.errors import CaptureError

__all__ = ["DEFAULT_MAX_PIXELS", "ImageSource", "decode_color", "decode_depth", "open_color", "open_depth"]

DEFAULT_MAX_PIXELS = 40_000_000
"""Largest image accepted, in pixels: well above a 4K colour frame, far below a decompression bomb."""

# The pixel limit is this module's own (max_pixels, checked from the header): Pillow's global one would
# override it with its own numbers and warnings, whose filters are process-wide and not thread-safe.
Image.MAX_IMAGE_PIXELS = None

_DEPTH_MODES = {"I;16", "I;16L", "I;16B"}
_COLOR_MODES = {"RGB", "RGBA", "P"}


_FORMAT_OF_SUFFIX = {".png": "PNG", ".jpg": "JPEG", ".jpeg": "JPEG"}
"""The image format a file's name promises: bytes of another format under it (a PNG saved as color.jpg) are
refused, so what a capture's files are called is what they hold."""


ImageSource = bytes | Path
"""An image's bytes, or the file holding them (read as Pillow needs it: a large upload is never in memory
whole)."""


def _open(
    source: ImageSource, *, file: str, view: str | None, max_pixels: int, stored: bool = False
) -> Image.Image:
    """Open an image and check its size from the header, before any pixel is decoded, and its format
    against its name (unless ``stored``: accepted before that rule); then decode it, so a corrupt or
    truncated file is told here."""
    size = len(source) if isinstance(source, bytes) else source.stat().st_size
    if size == 0:
        raise CaptureError("the file is empty", file=file, view=view)
    try:
        image = Image.open(io.BytesIO(source) if isinstance(source, bytes) else source)
    except UnidentifiedImageError as exc:
        raise CaptureError("not a readable PNG or JPEG image", file=file, view=view) from exc
    except OSError as exc:
        raise CaptureError(f"not a readable PNG or JPEG image ({exc})", file=file, view=view) from exc
    if image.format not in {"PNG", "JPEG"}:
        raise CaptureError(f"is a {image.format} image; PNG or JPEG expected", file=file, view=view)
    suffix = PurePosixPath(file).suffix.lower()
    if not stored and _FORMAT_OF_SUFFIX.get(suffix, image.format) != image.format:
        raise CaptureError(
            f"holds a {image.format} image under a {suffix} name; save it as {_FORMAT_OF_SUFFIX[suffix]} or "
            "name it for what it holds",
            file=file,
            view=view,
        )
    if image.width * image.height > max_pixels:
        raise CaptureError(
            f"image of {image.width}x{image.height} pixels exceeds the limit of {max_pixels} pixels",
            file=file,
            view=view,
        )
    try:
        image.load()
    except (OSError, SyntaxError, ValueError) as exc:
        raise CaptureError(f"corrupt or truncated image ({exc})", file=file, view=view) from exc
    return image


def open_depth(
    source: ImageSource,
    *,
    file: str,
    view: str | None = None,
    expected_size: tuple[int, int] | None = None,
    max_pixels: int = DEFAULT_MAX_PIXELS,
) -> Image.Image:
    """Open and check a depth image: every rule of :func:`decode_depth`, without making an array of it.

    Raises
    ------
    CaptureError
        Not a PNG, corrupt, not 16-bit single channel, wrong size, or no valid depth pixel.
    """
    image = _open(source, file=file, view=view, max_pixels=max_pixels)
    if image.format != "PNG":
        raise CaptureError("depth must be a lossless PNG, not JPEG", file=file, view=view)
    if image.mode not in _DEPTH_MODES:
        raise CaptureError(
            f"depth must be 16-bit single-channel; this PNG is mode {image.mode} "
            f"({len(image.getbands())} channel(s))",
            file=file,
            view=view,
        )
    _check_size(image, expected_size, file=file, view=view, what="depth_intrinsics")
    if image.getextrema()[1] == 0:
        raise CaptureError("the depth image has no valid pixel (all zero)", file=file, view=view)
    return image


def decode_depth(
    source: ImageSource,
    *,
    file: str,
    view: str | None = None,
    expected_size: tuple[int, int] | None = None,
    max_pixels: int = DEFAULT_MAX_PIXELS,
) -> np.ndarray:
    """Decode a depth PNG into a ``(height, width)`` uint16 array (0 = no reading).

    Parameters
    ----------
    source
        The file's bytes, or its path.
    file, view
        Where the bytes came from, for error messages.
    expected_size
        ``(width, height)`` from camera.json's depth_intrinsics; a different size is an error.
    max_pixels
        Images with more pixels are refused from their header alone.

    Raises
    ------
    CaptureError
        As :func:`open_depth`.
    """
    image = open_depth(source, file=file, view=view, expected_size=expected_size, max_pixels=max_pixels)
    return np.asarray(image, dtype=np.uint16)


def open_color(
    source: ImageSource,
    *,
    file: str,
    view: str | None = None,
    expected_size: tuple[int, int] | None = None,
    max_pixels: int = DEFAULT_MAX_PIXELS,
    stored: bool = False,
) -> Image.Image:
    """Open and check a colour image: every rule of :func:`decode_color`, without making an array of it."""
    image = _open(source, file=file, view=view, max_pixels=max_pixels, stored=stored)
    if image.mode not in _COLOR_MODES:
        raise CaptureError(f"colour must be 8-bit RGB; this image is mode {image.mode}", file=file, view=view)
    _check_size(image, expected_size, file=file, view=view, what="intrinsics")
    return image


def decode_color(
    source: ImageSource,
    *,
    file: str,
    view: str | None = None,
    expected_size: tuple[int, int] | None = None,
    max_pixels: int = DEFAULT_MAX_PIXELS,
    stored: bool = False,
) -> np.ndarray:
    """Decode a colour PNG or JPEG (bytes or path) into a ``(height, width, 3)`` uint8 RGB array.

    ``expected_size`` is ``(width, height)`` from camera.json (colour intrinsics, or the depth size when the
    colour is registered to the depth image). Alpha is dropped; palette images are expanded; 48-bit RGB
    PNGs are reduced to 8 bits by Pillow; grey images are refused because ball detection needs colour.
    ``stored``: accepted earlier, when a PNG under a .jpg name still passed.
    """
    image = open_color(
        source, file=file, view=view, expected_size=expected_size, max_pixels=max_pixels, stored=stored
    )
    return np.asarray(image.convert("RGB") if image.mode != "RGB" else image, dtype=np.uint8)


def _check_size(
    image: Image.Image, expected_size: tuple[int, int] | None, *, file: str, view: str | None, what: str
) -> None:
    if expected_size is None:
        return
    width, height = expected_size
    if image.size != (width, height):
        raise CaptureError(
            f"image is {image.width}x{image.height} but camera.json {what} says {width}x{height}",
            file=file,
            view=view,
        )
