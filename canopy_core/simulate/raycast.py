"""Casting camera rays into the scene: triangles through Open3D's RaycastingScene, balls as exact spheres.

Rays leave a pinhole camera through points of its pixels; a ray's direction has unit z in the camera
frame, so its hit distance parameter is the depth along the optical axis. Every hit names a *surface*:
the index of a mesh triangle, or, after the triangles, of a sphere; its colour and kind are looked up there.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import open3d as o3d

from canopy_core.capture import Intrinsics
from canopy_core.simulate.camera import CameraPose, project
from canopy_core.simulate.mesh import Mesh, SurfaceKind

__all__ = ["NO_SURFACE", "RayHits", "SceneRaycaster", "Sphere"]

NO_SURFACE = -1
"""The surface index of a ray that hits nothing (sky)."""


@dataclass(frozen=True, eq=False)
class Sphere:
    """A ball: centre (3,) in world coordinates, radius and RGB reflectance in [0, 1]."""

    centre: np.ndarray
    radius_m: float
    color: np.ndarray

    def box_corners(self) -> np.ndarray:
        """The 8 corners (8, 3) of the axis-aligned cube that holds the sphere."""
        signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
        return self.centre + self.radius_m * signs


@dataclass(frozen=True, eq=False)
class RayHits:
    """What a camera's rays hit, one entry per ray, arrays shaped ``(rows, columns, samples_per_pixel)``.

    ``depth_m`` is the hit's depth along the optical axis (inf where nothing is hit), ``surface`` its surface
    index (``NO_SURFACE`` for sky), ``normals`` the unit surface normals and ``directions`` the ray
    directions, both in world coordinates (directions have unit length along the optical axis, not unit
    length).
    """

    depth_m: np.ndarray
    surface: np.ndarray
    normals: np.ndarray
    directions: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        """True where a ray hit a surface."""
        return self.surface != NO_SURFACE


@dataclass(frozen=True, eq=False)
class SceneRaycaster:
    """A static mesh (built into Open3D's BVH once) plus spheres that can be swapped without rebuilding it.

    ``surface_colors`` and ``surface_kinds`` hold per-surface RGB reflectance and :class:`SurfaceKind`: the
    mesh's triangles first, then the spheres.
    """

    mesh: Mesh
    spheres: tuple[Sphere, ...]
    surface_colors: np.ndarray
    surface_kinds: np.ndarray
    _scene: o3d.t.geometry.RaycastingScene

    @classmethod
    def build(cls, mesh: Mesh, spheres: Sequence[Sphere] = ()) -> SceneRaycaster:
        """Index ``mesh`` for ray casting and add ``spheres``."""
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(
            o3d.core.Tensor.from_numpy(mesh.vertices.astype(np.float32)),
            o3d.core.Tensor.from_numpy(mesh.triangles.astype(np.uint32)),
        )
        return cls._with(mesh, tuple(spheres), scene)

    @classmethod
    def _with(
        cls, mesh: Mesh, spheres: tuple[Sphere, ...], scene: o3d.t.geometry.RaycastingScene
    ) -> SceneRaycaster:
        colors = np.concatenate(
            [mesh.colors, np.array([s.color for s in spheres], dtype=np.float32).reshape(-1, 3)]
        )
        kinds = np.concatenate([mesh.kinds, np.full(len(spheres), SurfaceKind.BALL, dtype=np.int8)])
        return cls(mesh=mesh, spheres=spheres, surface_colors=colors, surface_kinds=kinds, _scene=scene)

    def with_spheres(self, spheres: Sequence[Sphere]) -> SceneRaycaster:
        """The same mesh (and BVH) with other spheres."""
        return self._with(self.mesh, tuple(spheres), self._scene)

    def sphere_surface(self, index: int) -> int:
        """The surface index of sphere ``index``."""
        return self.mesh.triangle_count + index

    def cast_camera(
        self, pose: CameraPose, intrinsics: Intrinsics, *, subpixel_offsets: np.ndarray | None = None
    ) -> RayHits:
        """Cast rays through every pixel of a camera.

        Parameters
        ----------
        pose, intrinsics
            The camera. Pixel (row, column) has its centre at image coordinates (column, row).
        subpixel_offsets
            (k, 2) offsets (columns, rows) in pixels of the k rays cast through each pixel; one ray
            through the centre when omitted.
        """
        offsets = np.zeros((1, 2)) if subpixel_offsets is None else np.asarray(subpixel_offsets, dtype=float)
        columns = (np.arange(intrinsics.width)[None, :, None] + offsets[:, 0] - intrinsics.cx) / intrinsics.fx
        rows = (np.arange(intrinsics.height)[:, None, None] + offsets[:, 1] - intrinsics.cy) / intrinsics.fy
        shape = (intrinsics.height, intrinsics.width, len(offsets))
        columns, rows = columns.astype(np.float32), rows.astype(np.float32)
        right, down, forward = pose.rotation.T.astype(np.float32)
        rays = np.empty((*shape, 6), dtype=np.float32)
        rays[..., :3] = pose.position
        for axis in range(3):
            rays[..., 3 + axis] = columns * right[axis] + rows * down[axis] + forward[axis]
        result = self._scene.cast_rays(o3d.core.Tensor.from_numpy(rays.reshape(-1, 6)))
        depth = result["t_hit"].numpy().reshape(shape)
        surface = result["primitive_ids"].numpy().view(np.int32).reshape(shape)
        surface[~np.isfinite(depth)] = NO_SURFACE
        normals = result["primitive_normals"].numpy().reshape(*shape, 3)
        directions = rays[..., 3:]
        hits = RayHits(depth_m=depth, surface=surface, normals=normals, directions=directions)
        for index, sphere in enumerate(self.spheres):
            self._add_sphere(hits, pose, intrinsics, sphere, self.sphere_surface(index))
        return hits

    def _add_sphere(
        self, hits: RayHits, pose: CameraPose, intrinsics: Intrinsics, sphere: Sphere, surface: int
    ) -> None:
        """Overwrite, in place, the hits of the rays that meet ``sphere`` before anything else."""
        window = _sphere_window(pose, intrinsics, sphere)
        if window is None:
            return
        directions = hits.directions[window].astype(np.float64)
        to_camera = pose.position - sphere.centre
        a = np.einsum("...i,...i->...", directions, directions)
        b = directions @ to_camera
        c = to_camera @ to_camera - sphere.radius_m**2
        discriminant = b * b - a * c
        with np.errstate(invalid="ignore"):
            t = (-b - np.sqrt(discriminant)) / a
        nearer = (discriminant >= 0) & (t > 0) & (t < hits.depth_m[window])
        if not nearer.any():
            return
        hits.depth_m[window] = np.where(nearer, t, hits.depth_m[window])
        hits.surface[window] = np.where(nearer, surface, hits.surface[window])
        points = pose.position + t[..., None] * directions
        normals = ((points - sphere.centre) / sphere.radius_m).astype(np.float32)
        hits.normals[window] = np.where(nearer[..., None], normals, hits.normals[window])


def _sphere_window(pose: CameraPose, intrinsics: Intrinsics, sphere: Sphere) -> tuple[slice, slice] | None:
    """The rows and columns of the pixels a sphere may cover (from its bounding cube), or None if none."""
    pixels, depth = project(pose, intrinsics, sphere.box_corners())
    if (depth <= 0).all():
        return None
    if (depth <= 0).any():
        return slice(None), slice(None)
    low = np.floor(pixels.min(axis=0)).astype(int) - 1
    high = np.ceil(pixels.max(axis=0)).astype(int) + 2
    column_range = (max(low[0], 0), min(high[0], intrinsics.width))
    row_range = (max(low[1], 0), min(high[1], intrinsics.height))
    if column_range[0] >= column_range[1] or row_range[0] >= row_range[1]:
        return None
    return slice(*row_range), slice(*column_range)
