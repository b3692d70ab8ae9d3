"""Cleaning of depth images and point clouds: depth range, flying pixels, stray points.

Time-of-flight cameras such as Kinect v2 mix the foreground and background depth at every silhouette edge
("flying pixels"); a leafy crown is mostly edges, and those pixels strung out behind it are what makes the
paper's width W too large. They are removed in image space, where neighbourhoods are free, before
back-projection; what remains alone in 3D is removed by a range-aware density check.
"""

from __future__ import annotations

import cv2
import numpy as np

from canopy_core.kdtree import NearestTree

__all__ = ["reliable_depth_mask", "sparse_point_mask", "with_neighbours"]


def reliable_depth_mask(
    depth_m: np.ndarray,
    *,
    min_depth_m: float = 0.3,
    max_depth_m: float = 8.0,
    window_px: int = 2,
    jump_ratio: float = 0.03,
    jump_min_m: float = 0.02,
) -> np.ndarray:
    """Pixels with a trustworthy depth reading: in range and not flying.

    A pixel is flying when its ``(2 * window_px + 1)``-square window holds a reading nearer than it by more
    than ``jump_min_m + jump_ratio * depth`` *and* one farther than it by as much: it lies between a
    foreground and a background surface, where no real surface is. A true silhouette pixel of the foreground
    has nothing nearer around it and is kept, so the crown's outline is not eroded; a background pixel next
    to a silhouette has nothing farther and is kept too. A missing reading does not count as far: the top of
    a crown against the sky is full of dropouts, and treating them as far would strip it; the few mixed
    pixels of a leaf before an unread background are left to :func:`sparse_point_mask`.

    Parameters
    ----------
    depth_m
        ``(height, width)`` depth along the optical axis in metres, 0 where there is no reading.
    min_depth_m, max_depth_m
        The sensor's trustworthy range.
    window_px
        Half-size of the neighbourhood; Kinect v2 spreads mixed depths over one to two pixels.
    jump_ratio, jump_min_m
        The depth step, relative and absolute, that counts as a discontinuity.

    Returns
    -------
    numpy.ndarray
        Boolean mask of the image's shape, True where the pixel is kept.
    """
    depth = depth_m.astype(np.float32, copy=False)
    valid = (depth > min_depth_m) & (depth < max_depth_m)
    kernel = np.ones((2 * window_px + 1, 2 * window_px + 1), dtype=np.uint8)
    nearest = cv2.erode(np.where(valid, depth, np.float32(np.inf)), kernel, borderType=cv2.BORDER_REPLICATE)
    farthest = cv2.dilate(np.where(valid, depth, np.float32(0.0)), kernel, borderType=cv2.BORDER_REPLICATE)
    step = np.float32(jump_min_m) + np.float32(jump_ratio) * depth
    flying = (depth - nearest > step) & (farthest - depth > step)
    return valid & ~flying


def sparse_point_mask(
    points_m: np.ndarray,
    *,
    range_m: np.ndarray,
    focal_px: float,
    radius_px: float = 4.0,
    min_neighbors: int = 2,
) -> np.ndarray:
    """Mask of points that have at least ``min_neighbors`` others within a few pixels' footprint.

    The radius grows with each point's range (``radius_px * range / focal``), so a small leaf seen far away
    (a handful of neighbouring pixels: the crown's tip or top) survives, while the stray points a flying
    pixel or an insect leaves, each alone in its neighbourhood, do not. A statistical filter over a fixed
    number of neighbours would remove the small leaf too: its mean neighbour distance is large.

    Parameters
    ----------
    points_m
        ``(N, 3)`` points of one view (any frame).
    range_m
        ``(N,)`` each point's depth from the camera that saw it.
    focal_px
        That camera's focal length in pixels.
    radius_px, min_neighbors
        The neighbourhood, in pixels at the point's range, and how many others it must hold.
    """
    if points_m.shape[0] == 0:
        return np.zeros(0, dtype=bool)
    radius = np.maximum(radius_px * range_m / focal_px, 1e-3)
    return with_neighbours(NearestTree(points_m), points_m, count=min_neighbors, radius_m=radius)


def with_neighbours(
    tree: NearestTree, points_m: np.ndarray, *, count: int, radius_m: float | np.ndarray
) -> np.ndarray:
    """Mask of ``points_m``, each one of ``tree``'s points, that have at least ``count`` others of the
    tree within ``radius_m`` (one radius, or one per point).

    The point itself is its own nearest, so it has them when its (count + 1)-th nearest lies within its
    radius: asking for the count + 1 nearest costs less than counting every point in reach, and the search
    stops at the largest radius (farther, the distance comes back infinite: not within reach either).
    """
    if points_m.shape[0] == 0:
        return np.zeros(0, dtype=bool)
    reach = np.nextafter(float(np.max(radius_m)), np.inf)
    distances, _ = tree.query(points_m, k=count + 1, distance_upper_bound=reach)
    return distances.reshape(points_m.shape[0], -1)[:, -1] <= radius_m
