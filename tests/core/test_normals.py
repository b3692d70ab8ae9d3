"""Surface normals of neighbourhoods in closed form: the same directions as LAPACK's eigenvectors."""

from __future__ import annotations

import numpy as np

from canopy_core.normals import neighbourhood_normals, scatter_about_mean


def _neighbourhoods(seed: int) -> np.ndarray:
    """Noisy patches of planes in random directions, some of them lines (two least eigenvalues equal), one
    a single point (all zeros), centred on their means; ``(N, 9, 3)``."""
    rng = np.random.default_rng(seed)
    count = 500
    spans = rng.normal(size=(count, 2, 3))
    weights = rng.normal(size=(count, 9, 2))
    weights[: count // 10, :, 1] = 0.0  # a tenth lie on a line
    points = np.einsum("nkj,nji->nki", weights, spans) + rng.normal(scale=1e-3, size=(count, 9, 3))
    points[: count // 10] = np.einsum("nkj,nji->nki", weights[: count // 10], spans[: count // 10])
    points[-1] = 0.0
    return points - points.mean(axis=1, keepdims=True)


def test_closed_form_normals_are_the_least_variance_directions_lapack_finds() -> None:
    centred = _neighbourhoods(seed=3)
    scatter = centred.transpose(0, 2, 1) @ centred
    eigenvalues, eigenvectors = np.linalg.eigh(scatter)

    count, size, _ = centred.shape
    normals = neighbourhood_normals(centred.reshape(-1, 3), np.arange(count * size).reshape(count, size))

    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-9)
    planes = eigenvalues[:, 1] - eigenvalues[:, 0] > 1e-4 * eigenvalues[:, 2]
    alignment = np.abs(np.einsum("ij,ij->i", normals[planes], eigenvectors[planes, :, 0]))
    np.testing.assert_allclose(alignment, 1.0, atol=1e-8)
    # Along a line any direction across it is a least-variance one: the normal is across the line.
    spread = np.einsum("nij,nj->ni", scatter[~planes], normals[~planes])
    np.testing.assert_allclose(
        np.einsum("ij,ij->i", spread, normals[~planes]), eigenvalues[~planes, 0], atol=1e-9
    )


def test_scatter_about_the_mean_counts_only_the_points_left_in() -> None:
    """Offsets from a point near each neighbourhood, some points left out (offset 0, not counted): the
    scatter is that of the points left in about their own mean, as ``balls._Scene.normals`` needs it."""
    rng = np.random.default_rng(5)
    count, size = 200, 9
    points = rng.normal(scale=0.05, size=(size, count, 3))
    kept = rng.random((size, count)) < 0.7
    kept[:5] = True  # at least five points left in each
    offsets = [np.where(kept, points[:, :, axis], 0.0) for axis in range(3)]

    scatter = scatter_about_mean(offsets, kept.sum(axis=0))

    for n in range(count):
        inside = points[kept[:, n], n]
        centred = inside - inside.mean(axis=0)
        np.testing.assert_allclose(scatter[n], centred.T @ centred, atol=1e-15)


def test_neighbourhood_normals_keep_their_digits_far_from_the_origin() -> None:
    """Centimetre-sized neighbourhoods 500 m from the origin (a frame's coordinates can be large): the
    normals are those of the same neighbourhoods at the origin, to 1e-12. Summed as raw coordinates, the
    scatter would lose digits to the squares of 500 m and the normals turn by some 1e-9."""
    centred = 0.01 * _neighbourhoods(seed=7)[:-1]
    count, size, _ = centred.shape
    neighbours = np.arange(count * size).reshape(count, size)
    near = neighbourhood_normals(centred.reshape(-1, 3), neighbours)

    far = neighbourhood_normals(centred.reshape(-1, 3) + np.array([500.0, -300.0, 20.0]), neighbours)

    scatter = centred.transpose(0, 2, 1) @ centred
    eigenvalues = np.linalg.eigvalsh(scatter)
    planes = eigenvalues[:, 1] - eigenvalues[:, 0] > 1e-4 * eigenvalues[:, 2]
    np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", near[planes], far[planes])), 1.0, atol=1e-12)
