"""Fused point clouds: their points, colours and, per point, the view that saw it and what it is; read and
written as binary PLY (metres, RGB as 8-bit) with plyfile.

What a point is follows the ASPRS LAS classification, so a LAS export carries it as it is: 2 ground, 5
high vegetation (the tree, crown and trunk), 1 anything else (weeds, posts, wires, fruit on the ground),
and 64, the first user-definable class, for the calibration balls.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from enum import IntEnum
from pathlib import Path
from typing import BinaryIO

import numpy as np
from plyfile import PlyData, PlyElement

__all__ = ["Cloud", "PointClass", "ply_bytes", "read_cloud", "write_ply"]


class PointClass(IntEnum):
    """What a point of a fused cloud is, as an ASPRS LAS classification code."""

    OTHER = 1
    GROUND = 2
    TREE = 5
    BALL = 64


@dataclass(frozen=True)
class Cloud:
    """``(N, 3)`` points in metres, and per point (when known) its uint8 RGB colour, the index of the view
    that saw it (in the capture's order) and its :class:`PointClass`."""

    points_m: np.ndarray
    colors_rgb: np.ndarray | None = None
    views: np.ndarray | None = None
    classes: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.points_m.shape[0])

    def only(self, mask: np.ndarray) -> Cloud:
        """The points where ``mask`` holds, with what is known of each."""

        def kept(values: np.ndarray | None) -> np.ndarray | None:
            return None if values is None else values[mask]

        return Cloud(self.points_m[mask], kept(self.colors_rgb), kept(self.views), kept(self.classes))


def write_ply(path: str | Path, cloud: Cloud) -> Path:
    """Write ``cloud`` as binary little-endian PLY: float64 x, y, z; uint8 red, green, blue, view and
    classification where known."""
    target = Path(path)
    with target.open("wb") as stream:
        _write(stream, cloud)
    return target


def ply_bytes(cloud: Cloud) -> bytes:
    """The bytes :func:`write_ply` would write, for storing a cloud somewhere other than a file."""
    stream = io.BytesIO()
    _write(stream, cloud)
    return stream.getvalue()


def _write(stream: BinaryIO, cloud: Cloud) -> None:
    fields = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
    if cloud.colors_rgb is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    if cloud.views is not None:
        fields += [("view", "u1")]
    if cloud.classes is not None:
        fields += [("classification", "u1")]
    vertices = np.empty(len(cloud), dtype=fields)
    for axis, name in enumerate("xyz"):
        vertices[name] = cloud.points_m[:, axis]
    if cloud.colors_rgb is not None:
        for channel, name in enumerate(("red", "green", "blue")):
            vertices[name] = cloud.colors_rgb[:, channel]
    if cloud.views is not None:
        vertices["view"] = cloud.views
    if cloud.classes is not None:
        vertices["classification"] = cloud.classes
    PlyData([PlyElement.describe(vertices, "vertex")], text=False, byte_order="<").write(stream)


def read_cloud(source: str | Path | bytes) -> Cloud:
    """The cloud of a PLY file (a path, or its bytes): points, and colours, views and classes where the
    file has them."""
    try:
        vertices = PlyData.read(io.BytesIO(source) if isinstance(source, bytes) else str(source))["vertex"]
    except (OSError, KeyError, ValueError) as exc:
        where = "the bytes" if isinstance(source, bytes) else source
        raise OSError(f"{where} is not a readable PLY file with vertices ({exc})") from exc
    names = {prop.name for prop in vertices.properties}

    def column(name: str) -> np.ndarray | None:
        return np.asarray(vertices[name], dtype=np.uint8) if name in names else None

    points = np.column_stack([np.asarray(vertices[name], dtype=np.float64) for name in "xyz"])
    colors = (
        np.column_stack([np.asarray(vertices[name], dtype=np.uint8) for name in ("red", "green", "blue")])
        if {"red", "green", "blue"} <= names
        else None
    )
    return Cloud(points, colors, column("view"), column("classification"))
