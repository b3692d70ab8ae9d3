"""Cleaning of depth images and point clouds: depth range, flying pixels, statistical outliers.

Time-of-flight cameras such as Kinect v2 mix the foreground and background depth at every silhouette edge
("flying pixels"); a leafy crown is mostly edges, and those pixels strung out behind it are what makes the
paper's width W too large. They are removed in image space, where neighbourhoods are free, before
back-projection; what remains sparse in 3D is removed by statistical outlier removal.
"""

from __future__ import annotations

import cv2
import numpy as np
import open3d as o3d

__all__ = ["reliable_depth_mask", "statistical_inliers"]


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
    than ``jump_min_m + jump_ratio * depth`` *and* one farther than it by as much, or none at all: it lies
    between a foreground and a background surface, where no real surface is. A missing reading counts as
    far, because the mix of a leaf and a background beyond the sensor's range lands in between with no
    background reading beside it. A true silhouette pixel of the foreground has nothing nearer around it
    and is kept, so the crown's outline is not eroded; a background pixel next to a silhouette has nothing
    farther and is kept too.

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
    farthest = cv2.dilate(np.where(valid, depth, np.float32(np.inf)), kernel, borderType=cv2.BORDER_REPLICATE)
    step = np.float32(jump_min_m) + np.float32(jump_ratio) * depth
    flying = (depth - nearest > step) & (farthest - depth > step)
    return valid & ~flying


def statistical_inliers(points_m: np.ndarray, *, neighbors: int = 16, std_ratio: float = 2.5) -> np.ndarray:
    """Indices of the points kept by statistical outlier removal.

    A point is an outlier when its mean distance to its ``neighbors`` nearest points exceeds the cloud's
    mean of that distance by more than ``std_ratio`` standard deviations (sparse noise: insects, dust,
    flying pixels that escaped the image-space filter).
    """
    if points_m.shape[0] <= neighbors:
        return np.arange(points_m.shape[0])
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points_m))
    _, kept = cloud.remove_statistical_outlier(nb_neighbors=neighbors, std_ratio=std_ratio)
    return np.asarray(kept, dtype=np.int64)
