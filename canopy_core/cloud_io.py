"""Reading and writing coloured point clouds as binary PLY (metres, RGB as 8-bit), with plyfile."""

from __future__ import annotations

import io
from pathlib import Path
from typing import BinaryIO

import numpy as np
from plyfile import PlyData, PlyElement

__all__ = ["ply_bytes", "read_ply", "write_ply"]


def write_ply(path: str | Path, points_m: np.ndarray, colors_rgb: np.ndarray | None = None) -> Path:
    """Write ``(N, 3)`` points (float64 x, y, z) and ``(N, 3)`` uint8 colours as binary little-endian PLY."""
    target = Path(path)
    with target.open("wb") as stream:
        _write(stream, points_m, colors_rgb)
    return target


def ply_bytes(points_m: np.ndarray, colors_rgb: np.ndarray | None = None) -> bytes:
    """The bytes :func:`write_ply` would write, for storing a cloud somewhere other than a file."""
    stream = io.BytesIO()
    _write(stream, points_m, colors_rgb)
    return stream.getvalue()


def _write(stream: BinaryIO, points_m: np.ndarray, colors_rgb: np.ndarray | None) -> None:
    fields = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
    if colors_rgb is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    vertices = np.empty(points_m.shape[0], dtype=fields)
    for axis, name in enumerate("xyz"):
        vertices[name] = points_m[:, axis]
    if colors_rgb is not None:
        for channel, name in enumerate(("red", "green", "blue")):
            vertices[name] = colors_rgb[:, channel]
    PlyData([PlyElement.describe(vertices, "vertex")], text=False, byte_order="<").write(stream)


def read_ply(path: str | Path) -> tuple[np.ndarray, np.ndarray | None]:
    """Points (m) and, when the file has them, uint8 RGB colours of a PLY file's vertices."""
    try:
        vertices = PlyData.read(str(path))["vertex"]
    except (OSError, KeyError, ValueError) as exc:
        raise OSError(f"{path} is not a readable PLY file with vertices ({exc})") from exc
    points = np.column_stack([np.asarray(vertices[name], dtype=np.float64) for name in "xyz"])
    names = {prop.name for prop in vertices.properties}
    if not {"red", "green", "blue"} <= names:
        return points, None
    colors = np.column_stack(
        [np.asarray(vertices[name], dtype=np.uint8) for name in ("red", "green", "blue")]
    )
    return points, colors
