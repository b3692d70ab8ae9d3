"""k-d trees over point clouds, for every neighbour search of the pipeline.

SciPy's default build splits each node at the median of its points and then shrinks every node's box to
its points: trees that answer a search a little sooner, at twice the cost to build. The pipeline builds a
tree for nearly every search it makes (tens per capture, over thousands to tens of thousands of points)
and asks most of them one question, so it builds them the cheap way: split at the middle of the box,
sliding to the nearest point when one side would be empty, boxes left as split. The searches are exact
either way: the same neighbours, only their cost moves.

The searches run on one thread (SciPy's ``workers`` left at 1). Split over threads started for each
search, they were slower on the whole: most searches are small, and after the views' processes are forked
the threaded searches of the refinement ran slower than one thread's, not faster (measured in
docs/design.md, "2026-12-07: the k-d trees built and searched for less").
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["point_tree"]


def point_tree(points: np.ndarray) -> cKDTree:
    """A k-d tree over ``(N, k)`` points, built by the sliding-midpoint rule without shrinking the nodes'
    boxes (see the module's note)."""
    return cKDTree(points, balanced_tree=False, compact_nodes=False)
