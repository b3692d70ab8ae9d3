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

from collections.abc import Sequence

import numpy as np

__all__ = ["neighbourhood_normals", "scatter_about_mean", "scatter_normals"]

_CLOSE_EIGENVALUES = 1e-4
"""The two least eigenvalues of a scatter nearly coincide when they differ by less than this share of the
largest: the closed form's eigenvector then loses digits, and LAPACK solves it."""


def neighbourhood_normals(points_m: np.ndarray, neighbours: np.ndarray) -> np.ndarray:
    """The unit normal (of either sign) of the plane that best fits each neighbourhood: row i of the
    ``(N, K)`` indices ``neighbours`` picks its points from ``points_m`` ``(M, 3)``; ``(N, 3)``.

    The same as the eigenvector of the least eigenvalue of each neighbourhood's scatter about its mean
    (``numpy.linalg.eigh``), which is taken from the offsets of its points from its first."""
    columns = neighbours.T
    offsets = [points_m[:, axis][columns] - points_m[:, axis][columns[0]] for axis in range(3)]
    return scatter_normals(scatter_about_mean(offsets, neighbours.shape[1]))


def scatter_about_mean(offsets: Sequence[np.ndarray], count: np.ndarray | int) -> np.ndarray:
    """The ``(N, 3, 3)`` scatter matrices about their mean of N neighbourhoods of ``count`` points each (one
    count, or one per neighbourhood), given the x, y and z offsets of their points from a point near them:
    three ``(K, N)`` arrays, a neighbourhood to a column, a point left out an offset of 0.

    The sum of the offsets' outer products less the outer product of their sum over the count: offsets from
    a nearby point are small numbers, so no digits are lost. Each coordinate in its own array, so that the
    sums run along memory: over ``(N, K, 3)`` arrays they stride across it and take several times as long.
    """
    totals = [offset.sum(axis=0) for offset in offsets]
    scatter = np.empty((offsets[0].shape[1], 3, 3))
    for i in range(3):
        for j in range(i, 3):
            entry = (offsets[i] * offsets[j]).sum(axis=0) - totals[i] * totals[j] / count
            scatter[:, i, j] = scatter[:, j, i] = entry
    return scatter


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
