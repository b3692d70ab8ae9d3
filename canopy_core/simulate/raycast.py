"""Casting rays into the scene: triangles through Open3D's RaycastingScene, balls and apples as exact spheres.

Rays leave a pinhole camera through points of its pixels; a ray's direction has unit z in the camera
frame, so its hit distance parameter is the depth along the optical axis. Every hit names a *surface*:
the index of a mesh triangle, or, after the triangles, of a sphere; its colour and kind are looked up there
(a two-coloured apple's colour also depends on the side of it the hit lies on). :class:`ShadowCaster`
casts the rays from the hit points towards the sun, for cast shadows.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import open3d as o3d

from canopy_core.capture import Intrinsics
from canopy_core.simulate.camera import CameraPose, project
from canopy_core.simulate.mesh import Mesh, SurfaceKind

__all__ = ["NO_SURFACE", "RayHits", "SceneRaycaster", "ShadowCaster", "Sphere"]

NO_SURFACE = -1
"""The surface index of a ray that hits nothing (sky)."""
_SECOND_COLOR_EDGE = 0.5
"""Width, in cosine between the normal and ``Sphere.second_side``, of the blend between a sphere's colours."""
_SHADOW_ORIGIN_OFFSET_M = 0.002
"""Shadow rays start this far off the surface, on its side facing the sun, so they do not hit it."""
_SHADOW_SPHERE_RESOLUTION = 8
"""Spheres block the sun as polyhedra of Open3D's UV sphere of this resolution (224 triangles)."""


@dataclass(frozen=True, eq=False)
class Sphere:
    """A ball or an apple: centre (3,) in world coordinates, radius and RGB reflectance in [0, 1].

    ``kind`` is its :class:`SurfaceKind`. A two-coloured sphere (an apple's red blush on a yellow-green
    ground colour) has ``second_color`` where its normal points along ``second_side`` (a unit vector),
    ``color`` on the other side, blended over a band around the dividing great circle. ``label`` says what
    it is, for the ground truth.
    """

    centre: np.ndarray
    radius_m: float
    color: np.ndarray
    kind: SurfaceKind = SurfaceKind.BALL
    second_color: np.ndarray | None = None
    second_side: np.ndarray | None = None
    label: str = ""

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
    length); every ray leaves the camera centre ``origin`` (3,).
    """

    depth_m: np.ndarray
    surface: np.ndarray
    normals: np.ndarray
    directions: np.ndarray
    origin: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        """True where a ray hit a surface."""
        return self.surface != NO_SURFACE


@dataclass(frozen=True, eq=False)
class SceneRaycaster:
    """A static mesh (built into Open3D's BVH once) plus spheres that can be swapped without rebuilding it.

    ``surface_colors`` and ``surface_kinds`` hold per-surface RGB reflectance and :class:`SurfaceKind`: the
    mesh's triangles first, then the spheres (see :meth:`reflectance` for two-coloured spheres).
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
        kinds = np.concatenate([mesh.kinds, np.array([s.kind for s in spheres], dtype=np.int8)])
        return cls(mesh=mesh, spheres=spheres, surface_colors=colors, surface_kinds=kinds, _scene=scene)

    def with_spheres(self, spheres: Sequence[Sphere]) -> SceneRaycaster:
        """The same mesh (and BVH) with other spheres."""
        return self._with(self.mesh, tuple(spheres), self._scene)

    def sphere_surface(self, index: int) -> int:
        """The surface index of sphere ``index``."""
        return self.mesh.triangle_count + index

    def reflectance(self, surface: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """RGB reflectance (..., 3) float32 of the hits on ``surface`` (indices, none ``NO_SURFACE``) with
        world ``normals`` (..., 3): the surface's colour, or on a two-coloured sphere a blend by side."""
        colors = np.take(self.surface_colors, surface, axis=0)
        two_colored = [i for i, sphere in enumerate(self.spheres) if sphere.second_color is not None]
        if not two_colored:
            return colors
        second = np.zeros((len(self.spheres), 3), dtype=np.float32)
        side = np.zeros((len(self.spheres), 3), dtype=np.float32)
        for index in two_colored:
            second[index] = self.spheres[index].second_color
            side[index] = self.spheres[index].second_side
        flat_surface = surface.reshape(-1)
        on_sphere = np.flatnonzero(flat_surface >= self.mesh.triangle_count)
        sphere_index = flat_surface[on_sphere] - self.mesh.triangle_count
        keep = np.isin(sphere_index, two_colored)
        on_sphere, sphere_index = on_sphere[keep], sphere_index[keep]
        cosine = np.einsum("ij,ij->i", normals.reshape(-1, 3)[on_sphere], side[sphere_index])
        weight = np.clip(0.5 + cosine / _SECOND_COLOR_EDGE, 0.0, 1.0)[:, None].astype(np.float32)
        flat_colors = colors.reshape(-1, 3)
        flat_colors[on_sphere] = (1.0 - weight) * flat_colors[on_sphere] + weight * second[sphere_index]
        return colors

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
        hits = RayHits(
            depth_m=depth, surface=surface, normals=normals, directions=directions, origin=pose.position
        )
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


@dataclass(frozen=True, eq=False)
class ShadowCaster:
    """What blocks the sun: the scene's triangles and its spheres (as fine polyhedra) in one Open3D scene."""

    _scene: o3d.t.geometry.RaycastingScene

    @classmethod
    def build(cls, mesh: Mesh, spheres: Sequence[Sphere] = ()) -> ShadowCaster:
        """Index ``mesh`` and ``spheres`` for shadow rays."""
        unit = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=_SHADOW_SPHERE_RESOLUTION)
        unit_vertices, unit_triangles = np.asarray(unit.vertices), np.asarray(unit.triangles)
        vertices = [mesh.vertices] + [sphere.centre + sphere.radius_m * unit_vertices for sphere in spheres]
        offsets = np.cumsum([0] + [len(v) for v in vertices[:-1]])
        triangles = [mesh.triangles] + [unit_triangles + offset for offset in offsets[1:]]
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(
            o3d.core.Tensor.from_numpy(np.concatenate(vertices).astype(np.float32)),
            o3d.core.Tensor.from_numpy(np.concatenate(triangles).astype(np.uint32)),
        )
        return cls(_scene=scene)

    def sunlit(self, hits: RayHits, direction: tuple[float, float, float]) -> np.ndarray:
        """True where a hit point sees the sun in ``direction`` (a unit vector), False where something
        casts a shadow on it; True for rays that hit nothing. Shaped as ``hits.surface``."""
        hit = np.flatnonzero(hits.hit.reshape(-1))
        to_sun = np.asarray(direction, dtype=np.float32)
        normals = hits.normals.reshape(-1, 3)[hit]
        towards_sun = np.where(normals @ to_sun >= 0, np.float32(1.0), np.float32(-1.0))[:, None]
        points = (
            hits.origin.astype(np.float32)
            + hits.depth_m.reshape(-1)[hit, None] * hits.directions.reshape(-1, 3)[hit]
            + np.float32(_SHADOW_ORIGIN_OFFSET_M) * towards_sun * normals
        )
        rays = np.empty((len(hit), 6), dtype=np.float32)
        rays[:, :3] = points
        rays[:, 3:] = to_sun
        occluded = self._scene.test_occlusions(o3d.core.Tensor.from_numpy(rays)).numpy().astype(bool)
        lit = np.ones(hits.surface.size, dtype=bool)
        lit[hit] = ~occluded
        return lit.reshape(hits.surface.shape)


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
