"""Triangle meshes with a colour and a surface kind per triangle, and the primitives the scene is built from.

Every object of the synthetic orchard (ground, bark, leaves, posts, wires, weeds) is one of these meshes;
the renderer looks a hit triangle's colour and kind up by its index, so a mesh carries them per triangle.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from enum import IntEnum

import cv2
import numpy as np
from scipy.spatial import cKDTree

__all__ = ["Mesh", "SurfaceKind", "hsv_to_rgb", "merge_meshes", "tube"]


class SurfaceKind(IntEnum):
    """What a surface is made of; it decides how the surface is shaded."""

    GROUND = 0
    BARK = 1
    LEAF = 2
    POST = 3
    BALL = 4
    FRUIT = 5
    WIRE = 6


@dataclass(frozen=True, eq=False)
class Mesh:
    """A triangle mesh in world coordinates (metres).

    ``colors`` are linear RGB reflectances in [0, 1], one row per triangle; ``kinds`` holds each triangle's
    :class:`SurfaceKind`.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    colors: np.ndarray
    kinds: np.ndarray

    @property
    def triangle_count(self) -> int:
        """Number of triangles."""
        return int(self.triangles.shape[0])

    def translated(self, offset: np.ndarray) -> Mesh:
        """The same mesh moved by ``offset`` (3,)."""
        return Mesh(self.vertices + np.asarray(offset, dtype=float), self.triangles, self.colors, self.kinds)

    def keep_triangles(self, keep: np.ndarray) -> Mesh:
        """The mesh with only the triangles where ``keep`` is True (vertices are left as they are)."""
        return Mesh(self.vertices, self.triangles[keep], self.colors[keep], self.kinds[keep])

    def without_triangles_near(self, points: cKDTree, distance_m: float) -> Mesh:
        """The mesh without the triangles having a vertex closer than ``distance_m`` to one of ``points``."""
        if self.triangle_count == 0:
            return self
        nearest_m, _ = points.query(self.vertices, distance_upper_bound=distance_m)
        vertex_near = np.isfinite(nearest_m)
        return self.keep_triangles(~vertex_near[self.triangles].any(axis=1))


def merge_meshes(meshes: Sequence[Mesh]) -> Mesh:
    """One mesh holding all the triangles of ``meshes``, in order."""
    offsets = np.cumsum([0] + [len(mesh.vertices) for mesh in meshes[:-1]])
    return Mesh(
        vertices=np.concatenate([mesh.vertices for mesh in meshes]),
        triangles=np.concatenate(
            [mesh.triangles + offset for mesh, offset in zip(meshes, offsets, strict=True)]
        ),
        colors=np.concatenate([mesh.colors for mesh in meshes]),
        kinds=np.concatenate([mesh.kinds for mesh in meshes]),
    )


def hsv_to_rgb(hue_deg: np.ndarray, saturation: np.ndarray, value: np.ndarray) -> np.ndarray:
    """RGB in [0, 1], (n, 3) float32, of colours given by hue (degrees), saturation and value in [0, 1];
    none for none (a ground patch that covers no point: OpenCV refuses an empty image)."""
    hsv = np.stack(
        [np.mod(hue_deg, 360.0), np.clip(saturation, 0.0, 1.0), np.clip(value, 0.0, 1.0)], axis=-1
    ).astype(np.float32)
    if hsv.shape[0] == 0:
        return np.zeros((0, 3), dtype=np.float32)
    return cv2.cvtColor(hsv[None], cv2.COLOR_HSV2RGB)[0]


def tube(
    centerline: np.ndarray,
    radii_m: np.ndarray,
    *,
    color: np.ndarray,
    kind: SurfaceKind,
    sides: int = 8,
) -> Mesh:
    """A tube of circular section along a polyline: trunks, branches, posts, wires and shoots.

    Parameters
    ----------
    centerline
        (n, 3) points along the tube's axis, n >= 2.
    radii_m
        (n,) radius at each point; give the last one ~0 for a closed tip.
    color
        RGB in [0, 1] of every triangle.
    kind
        The surface kind of every triangle.
    sides
        Number of faces around the tube.
    """
    centerline = np.asarray(centerline, dtype=float)
    if centerline.ndim != 2 or centerline.shape[0] < 2:
        raise ValueError("a tube needs at least two centreline points")
    tangents = np.gradient(centerline, axis=0)
    tangents /= np.linalg.norm(tangents, axis=1, keepdims=True)
    overall = centerline[-1] - centerline[0]
    # One reference axis for the whole tube keeps the rings from twisting between segments.
    reference = np.eye(3)[int(np.argmin(np.abs(overall)))]
    first = np.cross(tangents, reference)
    first /= np.linalg.norm(first, axis=1, keepdims=True)
    second = np.cross(tangents, first)
    angles = np.linspace(0.0, 2.0 * np.pi, sides, endpoint=False)
    ring = (
        np.cos(angles)[None, :, None] * first[:, None, :] + np.sin(angles)[None, :, None] * second[:, None, :]
    )
    vertices = centerline[:, None, :] + np.asarray(radii_m, dtype=float)[:, None, None] * ring
    index = np.arange(centerline.shape[0] * sides).reshape(-1, sides)
    here, ahead = index[:-1], index[1:]
    here_next, ahead_next = np.roll(here, -1, axis=1), np.roll(ahead, -1, axis=1)
    triangles = np.concatenate(
        [
            np.stack([here, here_next, ahead_next], axis=-1).reshape(-1, 3),
            np.stack([here, ahead_next, ahead], axis=-1).reshape(-1, 3),
        ]
    ).astype(np.int32)
    return Mesh(
        vertices=vertices.reshape(-1, 3),
        triangles=triangles,
        colors=np.tile(np.asarray(color, dtype=np.float32), (len(triangles), 1)),
        kinds=np.full(len(triangles), kind, dtype=np.int8),
    )
