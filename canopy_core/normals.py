"""Surface normals of point neighbourhoods: the direction in which a point's neighbours spread least.

Detection votes along every coloured point's normal and ICP matches each thinned point along its
normal: tens of thousands of neighbourhoods per capture. Their 3x3 scatter matrices are solved here in
closed form, on the six distinct entries at once: the smallest eigenvalue is the least root of the
characteristic cubic (in trigonometric form, all roots being real), and its eigenvector the longest cross
product of two rows of the matrix less that eigenvalue (each row is orthogonal to it). That is a tenth of
the time of LAPACK's general solver, which spends most of each call on overhead for so small a matrix.
Where the two least eigenvalues nearly coincide (neighbours along a line: the normal is any direction
across it) the cross products vanish and the closed form is imprecise, so those neighbourhoods go to
``numpy.linalg.eigh``, which picks one of the directions left open.
"""

from __future__ import annotations

import numpy as np

__all__ = ["neighbourhood_normals", "scatter_normals"]

_CLOSE_EIGENVALUES = 1e-4
"""The two least eigenvalues of a scatter nearly coincide when they differ by less than this share of the
largest: the closed form's eigenvector then loses digits, and LAPACK solves it."""


def neighbourhood_normals(points_m: np.ndarray, neighbours: np.ndarray) -> np.ndarray:
    """The unit normal (of either sign) of the plane that best fits each neighbourhood: row i of the
    ``(N, K)`` indices ``neighbours`` picks its points from ``points_m`` ``(M, 3)``; ``(N, 3)``.

    The same as the eigenvector of the least eigenvalue of each neighbourhood's scatter about its mean
    (``numpy.linalg.eigh``). Each coordinate is gathered into its own ``(N, K)`` array: the scatter's
    sums over ``(N, K, 3)`` arrays stride across memory and take about three times as long."""
    centred = []
    for axis in range(3):
        coordinate = points_m[:, axis][neighbours]
        centred.append(coordinate - coordinate.mean(axis=1, keepdims=True))
    scatter = np.empty((neighbours.shape[0], 3, 3))
    for i in range(3):
        for j in range(i, 3):
            scatter[:, i, j] = scatter[:, j, i] = np.einsum("nk,nk->n", centred[i], centred[j])
    return scatter_normals(scatter)


def scatter_normals(scatter: np.ndarray) -> np.ndarray:
    """The unit eigenvector (of either sign) of the least eigenvalue of each of ``(N, 3, 3)`` symmetric
    positive semi-definite scatter matrices: the normal of the plane that best fits the points whose scatter
    about their mean it is; ``(N, 3)``."""
    xx, yy, zz = scatter[:, 0, 0], scatter[:, 1, 1], scatter[:, 2, 2]
    xy, xz, yz = scatter[:, 0, 1], scatter[:, 0, 2], scatter[:, 1, 2]
    mean = (xx + yy + zz) / 3.0
    off_diagonal = xy**2 + xz**2 + yz**2
    spread = np.sqrt(((xx - mean) ** 2 + (yy - mean) ** 2 + (zz - mean) ** 2 + 2.0 * off_diagonal) / 6.0)
    safe = np.where(spread > 0.0, spread, 1.0)
    a, b, c = (xx - mean) / safe, (yy - mean) / safe, (zz - mean) / safe
    d, e, f = xy / safe, xz / safe, yz / safe
    half_det = (a * (b * c - f * f) - d * (d * c - f * e) + e * (d * f - b * e)) / 2.0
    angle = np.arccos(np.clip(half_det, -1.0, 1.0)) / 3.0
    largest = mean + 2.0 * spread * np.cos(angle)
    least = mean + 2.0 * spread * np.cos(angle + 2.0 * np.pi / 3.0)
    middle = 3.0 * mean - largest - least
    ax, by, cz = xx - least, yy - least, zz - least
    crosses = np.stack(
        [
            np.stack([xy * yz - xz * by, xz * xy - ax * yz, ax * by - xy * xy], axis=1),
            np.stack([xy * cz - xz * yz, xz * xz - ax * cz, ax * yz - xy * xz], axis=1),
            np.stack([by * cz - yz * yz, yz * xz - xy * cz, xy * yz - by * xz], axis=1),
        ]
    )
    lengths = np.einsum("knj,knj->kn", crosses, crosses)
    longest = np.argmax(lengths, axis=0)
    rows = np.arange(scatter.shape[0])
    normals = crosses[longest, rows]
    length = np.sqrt(lengths[longest, rows])
    solved = (middle - least > _CLOSE_EIGENVALUES * np.abs(largest)) & (length > 0.0)
    normals[solved] /= length[solved, None]
    if not solved.all():
        normals[~solved] = np.linalg.eigh(scatter[~solved])[1][:, :, 0]
    return normals
