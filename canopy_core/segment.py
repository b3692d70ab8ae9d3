"""Separating the measured tree from whatever else stands in the region of interest.

A cylinder around the balls holds the tree, but also what reaches into it: a neighbour's crown, a trellis
post, a weed. The tree is one connected body from its trunk's foot up; anything separated from it by a
gap wider than ``link_m`` is something else. Connectivity is computed on occupied voxels (fast, and immune
to the point density varying with distance), then carried back to the points.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

__all__ = ["tree_component"]

_TRUNK_SEED_RADIUS_M = 0.35
"""Voxels this close to the trunk's axis, in the lowest part of the cloud, seed the tree's component."""
_TRUNK_SEED_HEIGHT_M = 0.6


def tree_component(
    points_m: np.ndarray, trunk_xy_m: np.ndarray, *, link_m: float = 0.15, voxel_m: float = 0.04
) -> np.ndarray:
    """Mask of the points connected to the trunk.

    Parameters
    ----------
    points_m
        ``(N, 3)`` candidate tree points in the world frame (ground already removed).
    trunk_xy_m
        The trunk's horizontal position.
    link_m
        Two voxels closer than this are connected; a wider gap separates two bodies.
    voxel_m
        Voxel edge for the connectivity graph.

    Returns
    -------
    numpy.ndarray
        Boolean mask over ``points_m``. If nothing stands near the trunk (no trunk seen), every point is
        kept: the region of interest alone decides.
    """
    if points_m.shape[0] == 0:
        return np.zeros(0, dtype=bool)
    cells, point_cell = np.unique(np.floor(points_m / voxel_m).astype(np.int64), axis=0, return_inverse=True)
    point_cell = point_cell.ravel()
    centres = (cells + 0.5) * voxel_m
    pairs = cKDTree(centres).query_pairs(r=link_m, output_type="ndarray")
    graph = coo_matrix(
        (np.ones(pairs.shape[0], dtype=np.int8), (pairs[:, 0], pairs[:, 1])), shape=(len(cells), len(cells))
    )
    _, labels = connected_components(graph, directed=False)
    low = centres[:, 2] < centres[:, 2].min() + _TRUNK_SEED_HEIGHT_M
    near_trunk = np.linalg.norm(centres[:, :2] - trunk_xy_m, axis=1) < _TRUNK_SEED_RADIUS_M
    seeds = np.unique(labels[low & near_trunk])
    if seeds.size == 0:
        return np.ones(points_m.shape[0], dtype=bool)
    return np.isin(labels, seeds)[point_cell]
