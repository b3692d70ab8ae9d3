"""A corpus of bad captures, generated (never hand-edited binaries): one small valid one-view capture, and
from it one folder per kind of bad input a crew, a typo or a hostile client produces, each bad in exactly
one file. The tests send each over HTTP and give it to `canopy measure`; to look at them by hand:

    .venv/bin/python -m tests.bad_inputs OUT_FOLDER
"""

from __future__ import annotations

import io
import json
import struct
import sys
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

__all__ = ["BAD_INPUTS", "BadInput", "write_corpus", "write_valid_capture"]

WIDTH, HEIGHT = 64, 48
VIEW = "views/1"
_DEPTH_MM = 2000


def _manifest(**changes: Any) -> dict[str, Any]:
    return {
        "format": "canopy-capture/1",
        "orchard": "Corpus orchard",
        "row": "R1",
        "tree": "T1",
        "captured_at": "2026-11-20T08:31:00Z",
        "views": [VIEW],
        **changes,
    }


def _camera(**intrinsics: float) -> dict[str, Any]:
    return {
        "depth_intrinsics": {
            "width": WIDTH,
            "height": HEIGHT,
            "fx": 50.0,
            "fy": 50.0,
            "cx": 32.0,
            "cy": 24.0,
            **intrinsics,
        },
        "depth_scale": 1000.0,
    }


def _image(pixels: np.ndarray, image_format: str = "PNG") -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(pixels).save(buffer, image_format)
    return buffer.getvalue()


def _depth(value_mm: int = _DEPTH_MM, dtype: type = np.uint16) -> bytes:
    return _image(np.full((HEIGHT, WIDTH), value_mm, dtype=dtype))


def _color(image_format: str = "PNG") -> bytes:
    return _image(np.random.default_rng(7).integers(0, 256, (HEIGHT, WIDTH, 3), dtype=np.uint8), image_format)


def _nested(depth: int) -> bytes:
    return b"[" * depth + b"]" * depth


def _png_bomb(width: int, height: int) -> bytes:
    """A PNG whose header declares ``width`` x ``height`` 16-bit pixels and holds almost nothing."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", width, height, 16, 0, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", header)
        + chunk(b"IDAT", zlib.compress(b"\0" * 64))
        + chunk(b"IEND", b"")
    )


def _valid_files() -> dict[str, bytes]:
    return {
        "capture.json": json.dumps(_manifest()).encode(),
        f"{VIEW}/camera.json": json.dumps(_camera()).encode(),
        f"{VIEW}/depth.png": _depth(),
        f"{VIEW}/color.png": _color(),
    }


@dataclass(frozen=True)
class BadInput:
    """One kind of bad input: the file it spoils (``path`` in the capture), what it puts there (a file
    renamed by ``rename_to``, e.g. a PNG saved as color.jpg) and what the error must name."""

    kind: str
    path: str
    content: Callable[[], bytes]
    says: str
    """Words the error message holds, naming what is wrong."""
    rename_to: str | None = None


BAD_INPUTS: tuple[BadInput, ...] = (
    BadInput("capture_json_nested_5000_deep", "capture.json", lambda: _nested(5000), "nested too deeply"),
    BadInput(
        "camera_json_nested_5000_deep", f"{VIEW}/camera.json", lambda: _nested(5000), "nested too deeply"
    ),
    BadInput(
        "camera_json_utf16",
        f"{VIEW}/camera.json",
        lambda: json.dumps(_camera()).encode("utf-16"),
        "UTF-8",
    ),
    BadInput(
        "capture_json_latin1",
        "capture.json",
        lambda: json.dumps(_manifest(orchard="Vergers de l'Aube é"), ensure_ascii=False).encode("latin-1"),
        "UTF-8",
    ),
    BadInput(
        "principal_point_far_outside",
        f"{VIEW}/camera.json",
        lambda: json.dumps(_camera(cx=1e9)).encode(),
        "principal point",
    ),
    BadInput(
        "focal_length_in_millimetres",
        f"{VIEW}/camera.json",
        lambda: json.dumps(_camera(fx=3.6, fy=3.6)).encode(),
        "field of view",
    ),
    BadInput(
        "misspelt_depth_scale",
        f"{VIEW}/camera.json",
        lambda: json.dumps(
            {**{k: v for k, v in _camera().items() if k != "depth_scale"}, "depth_scael": 1000.0}
        ).encode(),
        "depth_scale",
    ),
    BadInput(
        "depth_scale_missing",
        f"{VIEW}/camera.json",
        lambda: json.dumps({k: v for k, v in _camera().items() if k != "depth_scale"}).encode(),
        "depth_scale",
    ),
    BadInput(
        "tree_name_with_nul",
        "capture.json",
        lambda: json.dumps(_manifest(tree="T1\u0000")).encode(),
        "control character",
    ),
    BadInput(
        "view_path_outside_the_capture",
        "capture.json",
        lambda: json.dumps(_manifest(views=["views/../../etc"])).encode(),
        "views/<name>",
    ),
    BadInput(
        "png_saved_as_jpg",
        f"{VIEW}/color.png",
        _color,
        "PNG image under a .jpg name",
        rename_to=f"{VIEW}/color.jpg",
    ),
    BadInput("depth_8_bit", f"{VIEW}/depth.png", lambda: _depth(200, np.uint8), "16-bit"),
    BadInput("depth_all_zero", f"{VIEW}/depth.png", lambda: _depth(0), "no valid pixel"),
    BadInput("depth_truncated", f"{VIEW}/depth.png", lambda: _depth()[:60], "truncated"),
    BadInput(
        "depth_decompression_bomb", f"{VIEW}/depth.png", lambda: _png_bomb(60000, 60000), "exceeds the limit"
    ),
    BadInput("color_not_an_image", f"{VIEW}/color.png", lambda: b"GIF89a? no: just text", "not a readable"),
)


def write_valid_capture(folder: Path) -> dict[str, bytes]:
    """Write the corpus's valid capture into ``folder``; its files by path."""
    files = _valid_files()
    for path, data in files.items():
        (folder / path).parent.mkdir(parents=True, exist_ok=True)
        (folder / path).write_bytes(data)
    return files


def write_corpus(root: Path) -> dict[str, Path]:
    """One capture folder per :data:`BAD_INPUTS` kind under ``root``; the folders by kind."""
    folders = {}
    for bad in BAD_INPUTS:
        folder = root / bad.kind
        write_valid_capture(folder)
        target = folder / (bad.rename_to or bad.path)
        if bad.rename_to:
            (folder / bad.path).unlink()
        target.write_bytes(bad.content())
        folders[bad.kind] = folder
    return folders


if __name__ == "__main__":
    written = write_corpus(Path(sys.argv[1]))
    print(f"{len(written)} bad captures in {sys.argv[1]}: {', '.join(written)}")
