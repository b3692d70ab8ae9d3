"""Back-projection of a depth image into a coloured 3D point cloud in the depth camera's frame.

Depth is used at full range (no 3 m truncation) and colour is kept as RGB (not intensity). For native
Kinect v2 pairs each point is projected into the colour camera through ``depth_to_color``; points that the
colour camera cannot see (outside its image, or hidden behind a nearer surface because of the baseline)
are marked as having no colour rather than given a wrong one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from canopy_core.capture import CameraModel, Intrinsics, View

__all__ = ["ViewCloud", "backproject", "project_points"]

_OCCLUSION_CELL_PX = 4
"""Colour-image cell size of the occlusion z-buffer: about one depth pixel's footprint on Kinect v2."""
_OCCLUSION_TOLERANCE = 0.03
"""A point is hidden from the colour camera when it lies this fraction farther than its cell's nearest."""


@dataclass(frozen=True)
class ViewCloud:
    """The points of one view, in its depth camera's frame (metres, OpenCV axes).

    ``pixels`` holds each point's (row, column) in the depth image, so image-space masks and point-space
    results can be related; ``has_color`` is False where the colour camera does not see the point.
    """

    view: str
    points_m: np.ndarray
    colors_rgb: np.ndarray
    has_color: np.ndarray
    pixels: np.ndarray

    def __len__(self) -> int:
        return int(self.points_m.shape[0])

    def select(self, mask: np.ndarray) -> ViewCloud:
        """The subset of points where ``mask`` (boolean or index array) selects."""
        return ViewCloud(
            view=self.view,
            points_m=self.points_m[mask],
            colors_rgb=self.colors_rgb[mask],
            has_color=self.has_color[mask],
            pixels=self.pixels[mask],
        )


def project_points(points_m: np.ndarray, intrinsics: Intrinsics) -> np.ndarray:
    """Pixel coordinates ``(u, v)`` (column, row; float) of camera-frame points with z > 0."""
    z = points_m[:, 2]
    u = intrinsics.fx * points_m[:, 0] / z + intrinsics.cx
    v = intrinsics.fy * points_m[:, 1] / z + intrinsics.cy
    return np.stack([u, v], axis=1)


def backproject(view: View, *, keep: np.ndarray | None = None) -> ViewCloud:
    """Turn a view's depth pixels into coloured 3D points.

    Parameters
    ----------
    view
        The RGB-D pair.
    keep
        Optional boolean mask over the depth image; only pixels that are True and have a reading are used.
        Pass the mask from :func:`canopy_core.filters.reliable_depth_mask` to drop flying pixels.

    Returns
    -------
    ViewCloud
        One point per kept depth pixel, in the depth camera's frame.
    """
    depth_m = view.depth_m
    mask = depth_m > 0
    if keep is not None:
        mask &= keep
    rows, cols = np.nonzero(mask)
    z = depth_m[rows, cols].astype(np.float64)
    intr = view.camera.depth
    points = np.empty((z.size, 3), dtype=np.float64)
    points[:, 0] = (cols - intr.cx) * z / intr.fx
    points[:, 1] = (rows - intr.cy) * z / intr.fy
    points[:, 2] = z
    colors, has_color = _sample_colors(points, rows, cols, view.color_rgb, view.camera)
    return ViewCloud(
        view=view.name,
        points_m=points,
        colors_rgb=colors,
        has_color=has_color,
        pixels=np.stack([rows, cols], axis=1),
    )


def _sample_colors(
    points: np.ndarray, rows: np.ndarray, cols: np.ndarray, color_rgb: np.ndarray, camera: CameraModel
) -> tuple[np.ndarray, np.ndarray]:
    if camera.registered:
        return color_rgb[rows, cols], np.ones(rows.size, dtype=bool)
    assert camera.color is not None and camera.depth_to_color is not None
    transform = camera.depth_to_color
    in_color = points @ transform[:3, :3].T + transform[:3, 3]
    in_front = in_color[:, 2] > 1e-6
    uv = np.full((points.shape[0], 2), -1.0)
    uv[in_front] = project_points(in_color[in_front], camera.color)
    u = np.rint(uv[:, 0]).astype(np.int64)
    v = np.rint(uv[:, 1]).astype(np.int64)
    inside = in_front & (u >= 0) & (u < camera.color.width) & (v >= 0) & (v < camera.color.height)
    visible = inside & ~_occluded(u, v, in_color[:, 2], inside)
    colors = np.zeros((points.shape[0], 3), dtype=np.uint8)
    colors[visible] = color_rgb[v[visible], u[visible]]
    return colors, visible


def _occluded(u: np.ndarray, v: np.ndarray, z: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """Points lying behind a nearer point in the same colour-image cell (hidden by the camera baseline)."""
    hidden = np.zeros(z.size, dtype=bool)
    index = np.flatnonzero(inside)
    if index.size == 0:
        return hidden
    cell = (v[index] // _OCCLUSION_CELL_PX) * 100_000 + (u[index] // _OCCLUSION_CELL_PX)
    order = np.lexsort((z[index], cell))
    sorted_cell = cell[order]
    first = np.r_[True, sorted_cell[1:] != sorted_cell[:-1]]
    nearest = np.maximum.accumulate(np.where(first, np.arange(order.size), 0))
    nearest_z = z[index][order][nearest]
    hidden[index[order]] = z[index][order] > nearest_z * (1.0 + _OCCLUSION_TOLERANCE)
    return hidden
