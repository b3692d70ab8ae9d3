"""Separating the measured tree from whatever else stands in the region of interest.

A cylinder around the balls holds the tree, but also what reaches into it from outside: a neighbour's
crown, a trellis post. Such intruders enter through the cylinder's wall and are separated from the tree by
a gap. The tree itself need not be one connected body in the data: thin scaffold branches hidden by leaves
leave its crown floating above its trunk. So the points are grouped into bodies separated by gaps wider
than ``link_m`` (on occupied voxels: fast, and indifferent to point density), and a body is dropped only
when it touches the wall and is neither joined to the trunk nor a large part of what is in the cylinder,
or when it is a speck of a few voxels.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

__all__ = ["tree_component"]

_TRUNK_SEED_RADIUS_M = 0.35
"""Voxels this close to the trunk's axis, in the lowest part of the cloud, belong to the tree's trunk."""
_TRUNK_SEED_HEIGHT_M = 0.6
_WALL_BAND_M = 0.1
"""A body with points this close to the cylinder's wall comes from outside it."""
_LARGE_SHARE = 0.25
"""A body holding this share of the voxels is (part of) the tree even if it reaches the wall."""
_SPECK_VOXELS = 4


def tree_component(
    points_m: np.ndarray,
    trunk_xy_m: np.ndarray,
    *,
    roi_radius_m: float,
    link_m: float = 0.15,
    voxel_m: float = 0.04,
) -> np.ndarray:
    """Mask of the points that belong to the tree.

    Parameters
    ----------
    points_m
        ``(N, 3)`` candidate tree points in the world frame, inside a vertical cylinder of radius
        ``roi_radius_m`` around the z axis (ground already removed).
    trunk_xy_m
        The trunk's horizontal position.
    roi_radius_m
        The cylinder's radius.
    link_m
        Two voxels closer than this belong to the same body.
    voxel_m
        Voxel edge of the grouping.

    Returns
    -------
    numpy.ndarray
        Boolean mask over ``points_m``.
    """
    if points_m.shape[0] == 0:
        return np.zeros(0, dtype=bool)
    cells, point_cell = np.unique(np.floor(points_m / voxel_m).astype(np.int64), axis=0, return_inverse=True)
    centres = (cells + 0.5) * voxel_m
    pairs = cKDTree(centres).query_pairs(r=link_m, output_type="ndarray")
    graph = coo_matrix(
        (np.ones(pairs.shape[0], dtype=np.int8), (pairs[:, 0], pairs[:, 1])), shape=(len(cells), len(cells))
    )
    count, labels = connected_components(graph, directed=False)
    sizes = np.bincount(labels, minlength=count)
    low = centres[:, 2] < centres[:, 2].min() + _TRUNK_SEED_HEIGHT_M
    near_trunk = np.linalg.norm(centres[:, :2] - trunk_xy_m, axis=1) < _TRUNK_SEED_RADIUS_M
    trunk = np.zeros(count, dtype=bool)
    trunk[labels[low & near_trunk]] = True
    at_wall = np.zeros(count, dtype=bool)
    at_wall[labels[np.linalg.norm(centres[:, :2], axis=1) > roi_radius_m - _WALL_BAND_M]] = True
    large = sizes >= _LARGE_SHARE * len(cells)
    keep = (trunk | large | ~at_wall) & (sizes > _SPECK_VOXELS)
    keep |= trunk
    return keep[labels][point_cell.ravel()]
