"""k-d trees over point clouds, for every neighbour search of the pipeline: one kind for the k nearest
neighbours of each point, another for pairs and balls.

The k nearest (:class:`NearestTree`) are searched by pykdtree, 1.6-1.9 times as fast as SciPy's cKDTree on
the pipeline's clouds, for the same distances to the last bit and the same neighbours, but where several
lie at exactly the same distance: both searches are exact, and which of those comes first, or is the one
nearest, depends on each tree's shape. Measured points seldom tie; cells of a grid often do (the ground
height map's, where an unseen cell as near to two seen ones may take either's height). The searches: the
refinement's correspondences, the normals, the stray-point and support tests, the ground height map's
fill, the wire search's neighbourhoods. Each search runs on one thread: pykdtree would start GNU OpenMP's
threads, one per CPU, and those do not survive a fork: a process forked after them (the views' processes
of :func:`canopy_core.processes.on_each`, or any program's that measures and then forks) waits for ever in
its first search. One thread never starts them.

Pairs within a distance and the points within a ball of each (:func:`point_tree`), which pykdtree does not
search, by SciPy. SciPy's default build splits each node at the median of its points and then shrinks every
node's box to its points: trees that answer a search a little sooner, at twice the cost to build. The
pipeline builds a tree for nearly every search and asks most of them one question, so these are built the
cheap way: split at the middle of the box, sliding to the nearest point when one side would be empty, boxes
left as split; they are searched on one thread (SciPy's ``workers`` left at 1), since threads started for
each search cost more than they saved.

Measured in docs/design.md, "2026-12-07, second: the k-d trees built and searched for less".
"""

from __future__ import annotations

import numpy as np
from pykdtree.kdtree import KDTree
from scipy.spatial import cKDTree
from threadpoolctl import ThreadpoolController

__all__ = ["NearestTree", "point_tree"]

_OPENMP = ThreadpoolController().select(internal_api="openmp")
"""The OpenMP runtimes loaded (pykdtree's among them), held to one thread for each search."""


class NearestTree:
    """The k nearest of fixed ``(N, d)`` points (``data``, float64) to each of a set of queries.

    pykdtree's tree, answering as SciPy's ``cKDTree.query`` does where pykdtree does not: any number of
    points (none included) and any k, the missing neighbours at an infinite distance with index N (pykdtree
    gives k beyond N without a bound a huge finite distance and an index past N), indices as ``intp``.
    Unlike SciPy's, it takes points and queries that are not finite without a word (a NaN query finds
    nothing), a query must be a row of a 2-D array, and the tree cannot be pickled: the pipeline's points
    are finite, its queries come in arrays, and no tree leaves the process that built it.
    """

    def __init__(self, points: np.ndarray) -> None:
        self.data = np.ascontiguousarray(points, dtype=np.float64)
        self._tree = KDTree(self.data) if self.data.shape[0] else None

    def query(
        self, queries: np.ndarray, k: int = 1, *, distance_upper_bound: float = np.inf
    ) -> tuple[np.ndarray, np.ndarray]:
        """Distances and indices of each query's ``k`` nearest points closer than ``distance_upper_bound``,
        nearest first: ``(M,)`` arrays for k 1, ``(M, k)`` else."""
        queries = np.ascontiguousarray(queries, dtype=np.float64)
        count = self.data.shape[0]
        shape = (queries.shape[0],) if k == 1 else (queries.shape[0], k)
        if self._tree is None or queries.shape[0] == 0:
            return np.full(shape, np.inf), np.full(shape, count, dtype=np.intp)
        bound = None if np.isinf(distance_upper_bound) else distance_upper_bound
        with _OPENMP.limit(limits=1):
            distances, found = self._tree.query(queries, k=k, distance_upper_bound=bound)
        indices = found.astype(np.intp)
        missing = indices >= count
        if missing.any():
            distances[missing] = np.inf
            indices[missing] = count
        return distances, indices


def point_tree(points: np.ndarray) -> cKDTree:
    """A tree for the pairs of ``(N, d)`` points within a distance, and the points within a ball: built by
    the sliding-midpoint rule without shrinking the nodes' boxes (see the module's note)."""
    return cKDTree(points, balanced_tree=False, compact_nodes=False)
