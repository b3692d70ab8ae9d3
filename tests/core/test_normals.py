"""Surface normals of neighbourhoods in closed form: the same directions as LAPACK's eigenvectors."""

from __future__ import annotations

import numpy as np

from canopy_core.normals import neighbourhood_normals


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
