"""Free space across views: where one view saw past a place that another view shows a point at.

A depth pixel that sees a thin thing (a trellis wire, a leaf's edge) blends its depth with what lies behind
it, and the point it gives stands anywhere between the two (mixed pixels). Behind a wire seen only in
that way, such points make specks in mid-air, beside or below the crown, that look like leaves; and a
wire itself, thinner than a pixel, is seen by one view where the other sees past it. Another view looking
at the same place from elsewhere sees through such a point: its depth there reads farther. A real leaf
or branch the other view looks at reads where it stands, or nearer (something hides it); only a view's
phantoms are seen through. This is evidence of geometry across views, whatever the colours.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from canopy_core.backproject import project_points
from canopy_core.capture import View
from canopy_core.register import apply

__all__ = ["seen_through"]


def seen_through(
    points_m: np.ndarray,
    *,
    own_view: int,
    views: Sequence[View],
    world_from_view: Sequence[np.ndarray],
    margin_m: float,
    window_px: int,
    reach_percentile: float,
) -> np.ndarray:
    """Mask of the ``(N, 3)`` world-frame points of view ``own_view`` that another view saw past.

    A point is seen past by view j when it projects into j's depth image in front of j's camera and every
    pixel within ``window_px`` of it saw past it (a point at a leaf's edge may project a pixel off the
    leaf): read at least ``margin_m`` deeper than the point (along j's optical axis), or read nothing
    though the point is nearer than j reads surfaces (``reach_percentile`` of its readings: leaves, bark
    and soil return the sensor's light well, so a pixel without a reading that near saw nothing there;
    behind a wire, what a view sees past is often the sky or the far ground, out of its range).
    ``world_from_view`` holds each view's depth-camera pose in the world frame.
    """
    through = np.zeros(points_m.shape[0], dtype=bool)
    offsets = np.arange(-window_px, window_px + 1)
    for index, (view, pose) in enumerate(zip(views, world_from_view, strict=True)):
        if index == own_view or points_m.shape[0] == 0:
            continue
        local = apply(np.linalg.inv(pose), points_m)
        depth = view.depth_m
        readings = depth[depth > 0.0]
        if readings.size == 0:
            continue
        reach_m = float(np.percentile(readings, reach_percentile))
        rows_max, cols_max = depth.shape[0] - 1, depth.shape[1] - 1
        ahead = local[:, 2] > 0.0
        pixels = np.rint(project_points(local[ahead], view.camera.depth)).astype(np.int64)
        inside = (
            (pixels[:, 0] >= window_px)
            & (pixels[:, 0] <= cols_max - window_px)
            & (pixels[:, 1] >= window_px)
            & (pixels[:, 1] <= rows_max - window_px)
        )
        candidates = np.flatnonzero(ahead)[inside]
        cols = pixels[inside, 0][:, None, None] + offsets[None, None, :]
        rows = pixels[inside, 1][:, None, None] + offsets[None, :, None]
        window = depth[rows, cols].reshape(candidates.size, -1)
        depth_m = local[candidates, 2]
        unread = np.where(depth_m < reach_m, np.inf, 0.0)
        nearest = np.where(window > 0.0, window, unread[:, None]).min(axis=1)
        through[candidates] |= nearest > depth_m + margin_m
    return through
