"""Canopy metrics of a tree's points in the world frame (metres, z up, ground z = 0 at the trunk base).

The paper's three (Yang et al. 2019): height H (eq. 5), maximum canopy width W (eq. 6) and crown thickness
D from a kernel density of the points' heights (eqs. 7-8); and beyond it: a geometric crown base, crown
volume (convex hull and occupied voxels), projected crown area and the crown diameters along and across
the row. Every function takes the tree's points and nothing else it could get wrong.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy.spatial import ConvexHull, QhullError, cKDTree

from canopy_core.config import MetricsConfig

__all__ = [
    "CanopyMetrics",
    "canopy_height",
    "canopy_metrics",
    "crown_base_geometric",
    "crown_base_kde",
    "crown_diameters",
    "height_density",
    "hull_volume",
    "max_horizontal_distance",
    "projected_area",
    "voxel_volume",
]

_TOP_BATCH = 256
"""Candidates for the robust top are checked this many at a time, highest first."""


@dataclass(frozen=True)
class CanopyMetrics:
    """The metrics of one tree cloud (one view, or the merged views). Lengths in m, areas m², volumes m³."""

    height_m: float
    width_m: float
    thickness_m: float
    crown_base_m: float
    thickness_kde_m: float
    crown_base_kde_m: float
    diameter_along_row_m: float
    diameter_across_row_m: float
    projected_area_m2: float
    volume_hull_m3: float
    volume_voxel_m3: float
    points: int

    def to_dict(self) -> dict[str, float | int]:
        """The metrics as a JSON-ready dict with unit-suffixed keys."""
        return asdict(self)


def canopy_height(
    points_m: np.ndarray, *, ground_z_m: float = 0.0, support_radius_m: float = 0.05, support_points: int = 4
) -> float:
    """Tree height H = z_max - z_ground (eq. 5), with z_max robust to stray points.

    z_max is the highest point with at least ``support_points`` other points within ``support_radius_m``:
    a lone insect, dust speck or flying pixel above the crown does not raise it.
    """
    z = points_m[:, 2]
    order = np.argsort(-z)
    tree = cKDTree(points_m)
    for start in range(0, order.size, _TOP_BATCH):
        batch = order[start : start + _TOP_BATCH]
        neighbours = tree.query_ball_point(points_m[batch], r=support_radius_m, return_length=True) - 1
        supported = np.flatnonzero(neighbours >= support_points)
        if supported.size:
            return float(z[batch[supported[0]]] - ground_z_m)
    z_max = z.max()
    return float(z_max - ground_z_m)


def max_horizontal_distance(points_m: np.ndarray) -> float:
    """Maximum canopy width W: the largest distance between two points projected on the ground (eq. 6).

    Exact: the two farthest points of a set are vertices of its convex hull, so only hull vertices
    (tens to hundreds) are compared pairwise instead of all N² pairs.
    """
    xy = points_m[:, :2]
    if xy.shape[0] < 3:
        return float(np.linalg.norm(xy[0] - xy[-1])) if xy.shape[0] else 0.0
    try:
        vertices = xy[ConvexHull(xy, qhull_options="QJ").vertices]
    except (QhullError, ValueError):  # all points (nearly) equal
        return float(np.ptp(xy, axis=0).max())
    differences = vertices[:, None, :] - vertices[None, :, :]
    return float(np.sqrt((differences**2).sum(axis=2).max()))


def height_density(
    z_m: np.ndarray, *, bandwidth_m: float, step_m: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Gaussian kernel density f(z) = 1/(n h) sum K((z - z_i) / h) of the heights (eq. 7), per metre.

    Evaluated on a regular grid by binning and convolving with the sampled kernel, which is exact up to
    the bin width (``step_m``, a tenth of h by default) and linear in n.

    Returns
    -------
    (grid_m, density_per_m)
    """
    step = step_m or bandwidth_m / 10.0
    low, high = z_m.min() - 3 * bandwidth_m, z_m.max() + 3 * bandwidth_m
    edges = np.arange(low, high + step, step)
    counts, _ = np.histogram(z_m, bins=edges)
    half = int(np.ceil(4 * bandwidth_m / step))
    offsets = np.arange(-half, half + 1) * step
    kernel = np.exp(-0.5 * (offsets / bandwidth_m) ** 2) / (np.sqrt(2 * np.pi) * bandwidth_m)
    density = np.convolve(counts, kernel, mode="full")[half : half + counts.size] / z_m.size
    return (edges[:-1] + edges[1:]) / 2.0, density


def crown_base_kde(z_m: np.ndarray, *, height_m: float, bandwidth_m: float, threshold: float) -> float:
    """Crown base z_f of eq. 8: the lowest height where the height density first exceeds a threshold.

    The paper's threshold, 3e-4 with z in millimetres, depends on the unit and on the tree's size; here the
    density is made dimensionless by multiplying by H, so ``threshold`` = 1 means "as dense as points spread
    evenly over the tree's height", and the same value serves small and tall trees, in any unit.
    """
    grid, density = height_density(z_m, bandwidth_m=bandwidth_m)
    above = np.flatnonzero(density * height_m >= threshold)
    return float(grid[above[0]]) if above.size else float(z_m.min())


def crown_base_geometric(
    points_m: np.ndarray,
    trunk_xy_m: np.ndarray,
    *,
    foliage: np.ndarray | None = None,
    min_radius_m: float,
    support_radius_m: float,
    support_points: int,
) -> float:
    """Crown base: the lowest supported point of foliage, or of anything spreading away from the trunk.

    A point is crown when its colour is foliage (``foliage`` mask, see :mod:`canopy_core.foliage`) or
    when it lies farther than ``min_radius_m`` from the trunk's axis (branches and leaves spread out; the
    trunk does not), which also serves points without colour. It counts only with ``support_points``
    neighbours within ``support_radius_m``, so no stray point sets the base.
    """
    crown = np.linalg.norm(points_m[:, :2] - trunk_xy_m, axis=1) > min_radius_m
    if foliage is not None:
        crown |= foliage
    candidates = points_m[crown]
    if candidates.shape[0] == 0:
        return float(points_m[:, 2].min())
    order = np.argsort(candidates[:, 2])[:5000]
    tree = cKDTree(candidates)
    neighbours = tree.query_ball_point(candidates[order], r=support_radius_m, return_length=True) - 1
    supported = np.flatnonzero(neighbours >= support_points)
    return float(candidates[order[supported[0]], 2] if supported.size else candidates[order[0], 2])


def crown_diameters(points_m: np.ndarray) -> tuple[float, float]:
    """Crown extent along the row (world x) and across it (world y)."""
    extent = points_m[:, :2].max(axis=0) - points_m[:, :2].min(axis=0)
    return float(extent[0]), float(extent[1])


def projected_area(points_m: np.ndarray) -> float:
    """Area of the convex hull of the points projected on the ground, m²."""
    try:
        return float(ConvexHull(points_m[:, :2]).volume)
    except (QhullError, ValueError):
        return 0.0


def hull_volume(points_m: np.ndarray) -> float:
    """Volume of the 3D convex hull of the points, m³ (an upper bound of the crown's volume)."""
    try:
        return float(ConvexHull(points_m).volume)
    except (QhullError, ValueError):
        return 0.0


def voxel_volume(points_m: np.ndarray, *, voxel_m: float) -> float:
    """Volume of the voxels of edge ``voxel_m`` that hold at least one point, m³."""
    cells = np.unique(np.floor(points_m / voxel_m).astype(np.int64), axis=0)
    return float(cells.shape[0] * voxel_m**3)


def canopy_metrics(
    points_m: np.ndarray, *, trunk_xy_m: np.ndarray, foliage: np.ndarray | None = None, config: MetricsConfig
) -> CanopyMetrics:
    """All metrics of one tree cloud in the world frame; ``foliage`` marks the points coloured as leaves.

    ``thickness_m`` and ``crown_base_m`` are the geometric estimates (the more accurate on trees with a
    clear trunk); ``thickness_kde_m`` and ``crown_base_kde_m`` follow the paper's eqs. 7-8.
    """
    height = canopy_height(
        points_m, support_radius_m=config.support_radius_m, support_points=config.top_support_points
    )
    base_kde = crown_base_kde(
        points_m[:, 2], height_m=height, bandwidth_m=config.kde_bandwidth_m, threshold=config.kde_threshold
    )
    base_geometric = crown_base_geometric(
        points_m,
        trunk_xy_m,
        foliage=foliage,
        min_radius_m=config.crown_base_min_radius_m,
        support_radius_m=config.support_radius_m,
        support_points=config.base_support_points,
    )
    crown = points_m[points_m[:, 2] >= base_geometric]
    along, across = crown_diameters(crown)
    return CanopyMetrics(
        height_m=height,
        width_m=max_horizontal_distance(points_m),
        thickness_m=height - base_geometric,
        crown_base_m=base_geometric,
        thickness_kde_m=height - base_kde,
        crown_base_kde_m=base_kde,
        diameter_along_row_m=along,
        diameter_across_row_m=across,
        projected_area_m2=projected_area(crown),
        volume_hull_m3=hull_volume(crown),
        volume_voxel_m3=voxel_volume(crown, voxel_m=config.voxel_volume_m),
        points=int(points_m.shape[0]),
    )
