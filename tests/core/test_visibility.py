"""Free space across views: a point one view shows where another view saw past it is a phantom."""

from __future__ import annotations

import numpy as np

from canopy_core.capture import CameraModel, Intrinsics, View
from canopy_core.visibility import seen_through

INTRINSICS = Intrinsics(width=64, height=48, fx=50.0, fy=50.0, cx=32.0, cy=24.0)
SCALE = 1000.0
"""Depth units per metre."""


def _looking_along_x(camera_x_m: float) -> np.ndarray:
    """World-from-camera pose of a camera at ``(camera_x_m, 0, 0)`` looking along +x (camera x right = world
    -y, camera y down = world -z)."""
    pose = np.eye(4)
    pose[:3, :3] = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    pose[:3, 3] = [camera_x_m, 0.0, 0.0]
    return pose


def _view(name: str, depth_m: np.ndarray) -> View:
    return View(
        name=name,
        depth_raw=np.round(depth_m * SCALE).astype(np.uint16),
        color_rgb=np.zeros((*depth_m.shape, 3), dtype=np.uint8),
        camera=CameraModel(depth=INTRINSICS, depth_scale=SCALE),
    )


def test_a_point_the_other_view_sees_past_is_seen_through_and_one_it_sees_or_cannot_see_is_not() -> None:
    """View 2 (at x = 0, looking along +x) reads a wall 5 m away, but for a patch that reads a leaf 3 m
    away and a patch without readings (sky). View 1's points: one 2 m in front of view 2 where it reads
    the wall (a phantom), one on the leaf, one behind the leaf (hidden from view 2), one where view 2 has no
    reading though it reads surfaces that far (nothing there), and one beyond what view 2 reads at all."""
    depth = np.full((48, 64), 5.0)
    depth[20:29, 40:49] = 3.0  # the leaf, round pixel (44, 24): world y = -(44 - 32) / 50 * z
    depth[10:19, 10:19] = 0.0  # no reading round pixel (14, 14)
    views = [_view("views/1", np.full((48, 64), 4.0)), _view("views/2", depth)]
    poses = [_looking_along_x(8.0) @ np.diag([-1.0, 1.0, -1.0, 1.0]), _looking_along_x(0.0)]
    points = np.array(
        [
            [2.0, 0.0, 0.0],  # before the wall, on an open line of sight
            [3.0, -12 / 50 * 3.0, 0.0],  # on the leaf
            [4.0, -12 / 50 * 4.0, 0.0],  # behind the leaf
            [2.0, 18 / 50 * 2.0, 10 / 50 * 2.0],  # where view 2 reads nothing, nearer than it reads
            [6.0, 18 / 50 * 6.0, 10 / 50 * 6.0],  # there too, but farther than view 2 reads anything
        ]
    )

    settings = {"margin_m": 0.1, "window_px": 1, "reach_percentile": 95.0}
    through = seen_through(points, own_view=0, views=views, world_from_view=poses, **settings)

    assert through.tolist() == [True, False, False, True, False]
    assert not seen_through(points, own_view=1, views=views, world_from_view=poses, **settings)[:3].any()
