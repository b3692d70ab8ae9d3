"""The k-d trees: pykdtree's nearest-neighbour search answers as SciPy's does, and leaves a process safe to
fork."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from scipy.spatial import cKDTree

from canopy_core import kdtree
from canopy_core.kdtree import NearestTree


@pytest.mark.parametrize("k", [1, 3, 40])
@pytest.mark.parametrize("bound", [np.inf, 0.08])
def test_the_nearest_are_scipy_s_to_the_last_bit(k: int, bound: float) -> None:
    rng = np.random.default_rng(3)
    points = rng.uniform(-1.0, 1.0, (5000, 3))
    queries = rng.uniform(-1.2, 1.2, (700, 3))
    distances, indices = NearestTree(points).query(queries, k=k, distance_upper_bound=bound)
    expected_distances, expected_indices = cKDTree(points).query(queries, k=k, distance_upper_bound=bound)
    assert distances.shape == expected_distances.shape
    assert np.array_equal(distances, expected_distances)
    assert np.array_equal(indices, expected_indices)
    assert indices.dtype == np.intp


def test_on_a_grid_ties_come_with_scipy_s_distances_and_a_nearest_point() -> None:
    """Cells of a grid tie often: the distance is SciPy's, the point one of those at that distance."""
    rng = np.random.default_rng(5)
    seen = np.column_stack(np.nonzero(rng.random((30, 30)) < 0.3)).astype(float)
    cells = np.indices((30, 30)).reshape(2, -1).T.astype(float)
    distances, indices = NearestTree(seen).query(cells)
    expected, _ = cKDTree(seen).query(cells)
    assert np.array_equal(distances, expected)
    assert np.array_equal(np.linalg.norm(seen[indices] - cells, axis=1), expected)


def test_a_point_at_the_bound_is_not_within_it_as_with_scipy() -> None:
    points = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    distances, indices = NearestTree(points).query(np.array([[2.0, 0.0, 0.0]]), distance_upper_bound=1.0)
    assert np.isinf(distances[0]) and indices[0] == 2


def test_more_neighbours_than_points_and_no_points_come_back_missing() -> None:
    points = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    distances, indices = NearestTree(points).query(np.array([[0.2, 0.0, 0.0]]), k=4)
    assert np.allclose(distances[0, :2], [0.2, 0.8]) and np.isinf(distances[0, 2:]).all()
    assert indices[0].tolist() == [0, 1, 2, 2]
    distances, indices = NearestTree(np.zeros((0, 3))).query(np.ones((3, 3)), k=2)
    assert distances.shape == (3, 2) and np.isinf(distances).all() and (indices == 0).all()


def test_the_searches_thread_limit_reaches_pykdtree_s_openmp() -> None:
    """The limit that keeps a process safe to fork holds pykdtree's own OpenMP library; one it did not
    see would leave the searches on every CPU without a sign."""
    libraries = [controller.filepath for controller in kdtree._OPENMP.lib_controllers]
    assert any("pykdtree" in library for library in libraries), libraries


def test_after_a_search_a_forked_process_can_search_on_every_thread() -> None:
    """GNU OpenMP's threads do not survive a fork: had the search started them, the forked process's
    search on more than one thread would wait for them for ever."""
    script = textwrap.dedent(
        """
        import os, signal, sys
        import numpy as np
        from canopy_core.kdtree import NearestTree
        from pykdtree.kdtree import KDTree
        points = np.random.default_rng(0).uniform(size=(200_000, 3))
        NearestTree(points).query(points, k=5)
        child = os.fork()
        if child == 0:
            signal.alarm(60)  # a search waiting for ever ends the process, and the test fails
            KDTree(points).query(points, k=5)  # pykdtree's own default: one thread per CPU
            os._exit(0)
        _, status = os.waitpid(child, 0)
        sys.exit(os.waitstatus_to_exitcode(status))
        """
    )
    environment = {**os.environ, "OMP_NUM_THREADS": "2"}
    finished = subprocess.run([sys.executable, "-c", script], env=environment, timeout=120, check=False)
    assert finished.returncode == 0
