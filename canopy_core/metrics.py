"""Canopy metrics of a tree's points in the world frame (metres, z up, ground z = 0 at the trunk base).

The paper's three (Yang et al. 2019): height H (eq. 5), maximum canopy width W (eq. 6) and crown thickness
D from a kernel density of the points' heights (eqs. 7-8); and beyond it: a geometric crown base, crown
volume (convex hull and occupied voxels), projected crown area and the crown diameters along and across
the row. Every function takes the tree's points and nothing else it could get wrong.

The crown is told from what else stands on the ground by geometry (:func:`crown_mask`): weeds, tall grass
and suckers at the trunk's foot are green and joined to the trunk, and fallen fruit lies apart from it, but
all of them are separated from the crown by the bare trunk; so the crown base is the lowest point of the
crown, not of the lowest green thing, and none of them counts in H, W or the volumes.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from scipy.sparse import coo_matrix, csr_matrix
from scipy.sparse.csgraph import breadth_first_order, connected_components, maximum_flow
from scipy.spatial import ConvexHull, QhullError

from canopy_core.config import MetricsConfig
from canopy_core.errors import MeasurementError
from canopy_core.filters import with_neighbours
from canopy_core.kdtree import NearestTree, point_tree
from canopy_core.segment import is_wire_piece
from canopy_core.trunk_axis import TrunkAxis
from canopy_core.voxels import occupied_voxels

__all__ = [
    "CanopyMetrics",
    "CrownMarks",
    "canopy_height",
    "canopy_metrics",
    "crown_base_geometric",
    "crown_base_kde",
    "crown_candidates",
    "crown_diameters",
    "crown_mask",
    "ground_rising",
    "height_density",
    "highest_supported",
    "hull_volume",
    "lowest_crown_point",
    "max_horizontal_distance",
    "measured_points",
    "projected_area",
    "supported_hull",
    "voxel_volume",
    "widest_pair",
]

_SUPPORT_BATCH = 256
"""Candidates for the crown's robust top and base are checked this many at a time, from the extreme inward:
the first batch nearly always holds the answer, where counting every point's neighbours would cost tens of
milliseconds."""
_CROWN_VOXEL_M = 0.04
"""Voxel edge of the crown's grouping into bodies: well below the link distance, so that gaps are measured
to a few centimetres; coarse enough that grouping a tree's tens of thousands of points is fast."""
_CROWN_SHARE_ABOVE = 0.5
"""A body is part of the crown when at least this share of its height lies above the crown's main body's
lowest point: a piece of the crown does; a weed, sucker or fallen apple reaching up to it does not."""


@dataclass(frozen=True)
class CrownMarks:
    """Where H, W and D were read, in the world frame (m): for the report's figures and its 3D viewer.

    ``top_m`` is the point that sets H, raised by its half pitch (its z is H); ``crown_base_point_m`` the
    lowest crown point, lowered by its half pitch (its z is the crown base, D = H minus it);
    ``width_ends_m`` W's two ends on the ground plane, each moved out along W by its half pitch (their
    distance is W).
    """

    top_m: tuple[float, float, float]
    crown_base_point_m: tuple[float, float, float]
    width_ends_m: tuple[tuple[float, float], tuple[float, float]]


@dataclass(frozen=True)
class CanopyMetrics:
    """The metrics of one tree cloud (one view, or the merged views). Lengths in m, areas m², volumes m³;
    ``marks`` says where the extremes were read; ``cut_by_frame`` names the metrics that may read wrong
    (short; the crown base high) because the tree runs out of the view's image (:mod:`canopy_core.framing`;
    a single view's metrics only: the merged ones are refused instead)."""

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
    marks: CrownMarks
    cut_by_frame: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """The metrics as a JSON-ready dict with unit-suffixed keys, ``marks`` nested."""
        return asdict(self)


def canopy_height(
    points_m: np.ndarray, *, ground_z_m: float = 0.0, support_radius_m: float = 0.05, support_points: int = 4
) -> float:
    """Tree height H = z_max - z_ground (eq. 5), with z_max robust to stray points (see
    :func:`highest_supported`)."""
    top = highest_supported(points_m, support_radius_m=support_radius_m, support_points=support_points)
    return float(points_m[top, 2] - ground_z_m)


def highest_supported(points_m: np.ndarray, *, support_radius_m: float, support_points: int) -> int:
    """Index of the highest point with at least ``support_points`` other points within
    ``support_radius_m``: a lone insect, dust speck or flying pixel above the crown is not the top. The
    highest point when none has that support."""
    order = np.argsort(-points_m[:, 2])
    return _first_supported(
        NearestTree(points_m),
        points_m,
        order,
        support_radius_m=support_radius_m,
        support_points=support_points,
    )


def thin_top_m(points_m: np.ndarray, *, top_z_m: float, slab_m: float, width_m: float) -> float:
    """How far down from the top (``top_z_m``) the points stay as thin as a pole: the length (whole slabs)
    of the run of slabs ``slab_m`` high, from the top down, whose points lie (nine in ten) within
    ``width_m`` of their horizontal median, each median within ``width_m`` of the one above. 0 when the top
    slab is wider; an empty slab ends the run (a stake hidden there by a leaf reads short).

    A support stake standing above the crown is such a run over all of its height above the leaves; a
    leader's bare tip over the few centimetres above its last leaves; a crown's top, with leaves all
    round, not at all.
    """
    below = points_m[points_m[:, 2] <= top_z_m]
    slabs = int(np.ceil((top_z_m - below[:, 2].min()) / slab_m)) if below.shape[0] else 0
    above = None
    for count in range(slabs):
        upper = top_z_m - count * slab_m
        slab = below[(below[:, 2] <= upper) & (below[:, 2] > upper - slab_m)]
        if slab.shape[0] == 0:
            return count * slab_m
        centre = np.median(slab[:, :2], axis=0)
        spread = float(np.percentile(np.linalg.norm(slab[:, :2] - centre, axis=1), 90))
        if spread > width_m or (above is not None and float(np.linalg.norm(centre - above)) > width_m):
            return count * slab_m
        above = centre
    return slabs * slab_m


def _first_supported(
    tree: NearestTree,
    points_m: np.ndarray,
    order: np.ndarray,
    *,
    support_radius_m: float,
    support_points: int,
) -> int:
    """The first index of ``order`` (into ``points_m``, the points of ``tree``) whose point has at least
    ``support_points`` others within ``support_radius_m``; ``order[0]`` when none has."""
    for start in range(0, order.size, _SUPPORT_BATCH):
        batch = order[start : start + _SUPPORT_BATCH]
        supported = np.flatnonzero(
            with_neighbours(tree, points_m[batch], count=support_points, radius_m=support_radius_m)
        )
        if supported.size:
            return int(batch[supported[0]])
    return int(order[0])


def max_horizontal_distance(
    points_m: np.ndarray, *, support_radius_m: float | None = None, support_points: int = 0
) -> float:
    """Maximum canopy width W: the largest distance between two points projected on the ground (eq. 6).

    See :func:`widest_pair` for the support asked of the two points; no points have no width.
    """
    if points_m.shape[0] == 0:
        return 0.0
    first, second = widest_pair(points_m, support_radius_m=support_radius_m, support_points=support_points)
    return float(np.linalg.norm(points_m[first, :2] - points_m[second, :2]))


def widest_pair(
    points_m: np.ndarray, *, support_radius_m: float | None = None, support_points: int = 0
) -> tuple[int, int]:
    """Indices of the two points farthest apart projected on the ground: the ends of W (eq. 6).

    Exact: the two farthest points of a set are vertices of its convex hull, so only the vertices of the
    supported hull (:func:`supported_hull`, tens to hundreds) are compared pairwise instead of all N²
    pairs. ``points_m`` holds at least one point; one point is its own pair.
    """
    vertices = supported_hull(points_m, support_radius_m=support_radius_m, support_points=support_points)
    if vertices.size < 3:
        return int(vertices[0]), int(vertices[-1])
    xy = points_m[vertices, :2]
    differences = xy[:, None, :] - xy[None, :, :]
    first, second = np.unravel_index(np.argmax((differences**2).sum(axis=2)), differences.shape[:2])
    return int(vertices[first]), int(vertices[second])


def supported_hull(
    points_m: np.ndarray, *, support_radius_m: float | None = None, support_points: int = 0
) -> np.ndarray:
    """Indices of the vertices of the convex hull of the points projected on the ground, in order round
    it, that W is read from.

    With ``support_radius_m``, as for the top (:func:`canopy_height`), a point counts only with
    ``support_points`` other points within that radius: hull vertices without them are dropped and the
    hull taken again, so no stray point (a flying pixel, a speck of wire) sets W. Fewer than three points
    left (or all on a line): those points.
    """
    xy = points_m[:, :2]
    alive = np.ones(points_m.shape[0], dtype=bool)
    if support_radius_m is not None and points_m.shape[0] > support_points:
        neighbours = NearestTree(points_m)
        while True:
            hull = _hull_vertices(xy[alive])
            indices = np.flatnonzero(alive)[hull]
            supported = with_neighbours(
                neighbours, points_m[indices], count=support_points, radius_m=support_radius_m
            )
            stray = indices[~supported]
            if stray.size == 0 or np.count_nonzero(alive) - stray.size < 3:
                break
            alive[stray] = False
    kept = np.flatnonzero(alive)
    if kept.size < 3:
        return kept
    return kept[_hull_vertices(xy[kept])]


def _hull_vertices(xy: np.ndarray) -> np.ndarray:
    """Indices of the vertices of the convex hull of ``(N, 2)`` points; every index when there is none
    (fewer than three points, or all on a line)."""
    if xy.shape[0] < 3:
        return np.arange(xy.shape[0])
    try:
        return np.asarray(ConvexHull(xy, qhull_options="QJ").vertices)
    except (QhullError, ValueError):  # all points (nearly) equal
        return np.arange(xy.shape[0])


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


def crown_candidates(
    points_m: np.ndarray, trunk: TrunkAxis, *, foliage: np.ndarray | None = None, min_radius_m: float
) -> np.ndarray:
    """Mask of the points that may be crown: foliage, or anything spreading away from the trunk.

    A point is a candidate when its colour is foliage (``foliage`` mask, see :mod:`canopy_core.foliage`) or
    when it lies farther than ``min_radius_m`` from the trunk's axis at its height (``trunk``, see
    :mod:`canopy_core.trunk_axis`; branches and leaves spread out, the trunk does not, however it leans),
    which also serves points without colour. Ground vegetation, suckers and fallen fruit
    are candidates too: :func:`crown_mask` tells them from the crown.
    """
    candidates = trunk.distance_m(points_m) > min_radius_m
    if foliage is not None:
        candidates |= foliage
    return candidates


def crown_mask(
    points_m: np.ndarray,
    trunk: TrunkAxis,
    *,
    candidates: np.ndarray,
    config: MetricsConfig,
    seen_through: np.ndarray | None = None,
) -> np.ndarray:
    """Mask of the crown's points among the ``candidates`` (see :func:`crown_candidates`).

    A candidate another view saw through (``seen_through``, see :func:`canopy_core.visibility.seen_through`)
    is no crown: a mixed pixel, or a trellis wire thinner than a pixel, which only the view that made it
    shows; a leaf or branch another view looks at is seen there or hidden. Without them, a wire's points
    no longer chain the crown out along it. The other candidates outside the trunk's column are grouped
    into bodies separated by gaps wider than
    ``config.crown_link_m`` (on occupied voxels). The crown is the largest body and every body at its
    height, that is with at least half of its own height above the largest body's lowest point: pieces of
    the crown apart from the rest (a sparse cluster, the top leaves) are; ground vegetation, suckers, fallen
    fruit and stray points below the crown, which the bare trunk separates from it, are not, even where they
    reach up to its lowest leaves. Nor is a speck of fewer than ``config.crown_piece_min_voxels`` voxels
    apart from the rest (flying pixels, a glint of wire), nor a body apart from the rest that reaches down
    below ``config.crown_piece_min_bottom_m`` (it rises from the ground: a trellis post, a stake, a tall
    weed beside the trunk; no crown hangs there), nor a body that is a level straight line longer
    than a leaf (a piece of trellis wire beside the crown that the wire search missed; see
    :func:`canopy_core.segment.is_wire_piece`). Candidates inside the column (within
    ``config.trunk_column_radius_m`` of the trunk's axis at their height, which follows a leaning or bending
    trunk up, so that the bark's outline stays inside: suckers, leaves next to the trunk, bark coloured
    by the leaves behind it) join the crown when they are within the link distance of it, but never link
    anything to it: not what grows at the trunk's foot, not each other up the trunk. With no candidate
    outside the column, the crown is all the candidates.

    Parameters
    ----------
    points_m
        ``(N, 3)`` tree points in the world frame.
    trunk
        The trunk's axis (see :func:`canopy_core.trunk_axis.follow_trunk`).
    candidates
        Boolean mask over ``points_m`` of the points that may be crown.
    config
        The link distance, the trunk's column and what makes a wire piece.
    seen_through
        Boolean mask over ``points_m`` of the points another view saw past; None when unknown (one view).

    Returns
    -------
    numpy.ndarray
        Boolean mask over ``points_m``.
    """
    link_m, trunk_column_m = config.crown_link_m, config.trunk_column_radius_m
    radial = trunk.distance_m(points_m)
    in_column = radial <= trunk_column_m
    seen = candidates & ~in_column
    if seen_through is not None:
        seen &= ~seen_through
    grouped = np.flatnonzero(seen)
    if grouped.size == 0:
        return candidates.copy()
    labels, voxels = _bodies(points_m[grouped], link_m=link_m)
    rising = ground_rising(
        points_m[grouped],
        labels == np.argmax(voxels),
        link_m=link_m,
        min_bottom_m=config.crown_piece_min_bottom_m,
    )
    if rising.any():
        grouped = grouped[~rising]
        labels, voxels = _bodies(points_m[grouped], link_m=link_m)
    z = points_m[grouped, 2]
    order = np.lexsort((z, labels))
    starts = np.flatnonzero(np.r_[True, np.diff(labels[order]) != 0])
    bottom = z[order[starts]]
    top = z[order[np.r_[starts[1:], order.size] - 1]]
    main = int(np.argmax(voxels))
    at_crown_height = top - np.maximum(bottom, bottom[main]) >= _CROWN_SHARE_ABOVE * (top - bottom)
    ends = np.r_[starts[1:], order.size]
    pieces = np.arange(voxels.size) != main
    at_crown_height &= ~pieces | (
        (voxels >= config.crown_piece_min_voxels) & (bottom >= config.crown_piece_min_bottom_m)
    )
    for body in np.flatnonzero(at_crown_height):
        if body != main and is_wire_piece(
            points_m[grouped[order[starts[body] : ends[body]]]],
            min_length_m=config.wire_piece_min_length_m,
            max_thickness_m=config.wire_piece_max_thickness_m,
        ):
            at_crown_height[body] = False
    crown = np.zeros(points_m.shape[0], dtype=bool)
    crown[grouped] = at_crown_height[labels]
    column = np.flatnonzero(candidates & in_column)
    near_column = crown & (radial <= trunk_column_m + link_m)
    if column.size and near_column.any():
        distance, _ = NearestTree(points_m[near_column]).query(points_m[column], distance_upper_bound=link_m)
        crown[column[np.isfinite(distance)]] = True
    return crown


def ground_rising(
    points_m: np.ndarray, crown_body: np.ndarray, *, link_m: float, min_bottom_m: float
) -> np.ndarray:
    """Mask of the points that rise from the ground into the crown: tall grass, weeds, a post.

    The points are joined as in :func:`crown_mask` (occupied voxels closer than ``link_m``), and
    ``crown_body`` marks the largest body. What stands on the ground (voxels reaching below
    ``min_bottom_m``) may be joined to the crown through tall vegetation touching its lowest leaves, or a few
    mixed pixels between them. It is parted from the crown's core (the body's voxels at and above its most
    occupied level) along the weakest connection: the fewest links whose removal separates the two (a
    minimum cut, by maximum flow), and of the cuts that weak the one nearest the core. Everything on the
    ground's side of it is returned; nothing when nothing on the ground reaches the core.
    """
    nothing = np.zeros(points_m.shape[0], dtype=bool)
    cells, voxel = _voxels(points_m)
    bottom = np.full(cells.shape[0], np.inf)
    np.minimum.at(bottom, voxel, points_m[:, 2])
    on_ground = bottom < min_bottom_m
    in_crown = np.zeros(cells.shape[0], dtype=bool)
    in_crown[voxel[crown_body]] = True
    in_crown &= ~on_ground
    if not on_ground.any() or not in_crown.any():
        return nothing
    levels, counts = np.unique(cells[in_crown, 2], return_counts=True)
    core = in_crown & (cells[:, 2] >= levels[np.argmax(counts)])
    pairs = point_tree(cells * _CROWN_VOXEL_M).query_pairs(r=link_m, output_type="ndarray")
    n, links = cells.shape[0], pairs.shape[0]
    source, sink = n, n + 1
    tails = np.concatenate([pairs[:, 0], pairs[:, 1], np.full(on_ground.sum(), source), np.flatnonzero(core)])
    heads = np.concatenate([pairs[:, 1], pairs[:, 0], np.flatnonzero(on_ground), np.full(core.sum(), sink)])
    capacity = np.ones(tails.size, dtype=np.int32)
    capacity[2 * links :] = 2 * links + 1  # more than every link together: never cut
    graph = csr_matrix((capacity, (tails, heads)), shape=(n + 2, n + 2))
    flow = maximum_flow(graph, source, sink, method="dinic")
    if flow.flow_value == 0:
        return nothing
    residual = graph - flow.flow
    residual.data = (residual.data > 0).astype(np.int8)
    residual.eliminate_zeros()
    reaches_core = _reachable(residual.T.tocsr(), sink)
    return (_reachable(graph, source) & ~reaches_core)[:n][voxel]


def _reachable(graph: csr_matrix, start: int) -> np.ndarray:
    """Mask of the nodes of a directed graph reachable from ``start``."""
    mask = np.zeros(graph.shape[0], dtype=bool)
    mask[breadth_first_order(graph, start, directed=True, return_predecessors=False)] = True
    return mask


def _voxels(points_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The occupied voxels' integer coordinates ``(M, 3)`` and each point's voxel."""
    voxels = occupied_voxels(points_m, _CROWN_VOXEL_M)
    return voxels.cells - voxels.cells.min(axis=0), voxels.of_point


def _bodies(points_m: np.ndarray, *, link_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Each point's body (points joined through occupied voxels closer than ``link_m``), and each body's
    number of voxels."""
    cells, voxel = _voxels(points_m)
    pairs = point_tree(cells * _CROWN_VOXEL_M).query_pairs(r=link_m, output_type="ndarray")
    graph = coo_matrix(
        (np.ones(pairs.shape[0], dtype=np.int8), (pairs[:, 0], pairs[:, 1])), shape=(len(cells), len(cells))
    )
    count, labels = connected_components(graph, directed=False)
    return labels[voxel], np.bincount(labels, minlength=count)


def crown_base_geometric(
    points_m: np.ndarray, crown: np.ndarray, *, support_radius_m: float, support_points: int
) -> float:
    """Crown base: the height of the lowest supported point of the crown (see :func:`lowest_crown_point`)."""
    lowest = lowest_crown_point(
        points_m, crown, support_radius_m=support_radius_m, support_points=support_points
    )
    return float(points_m[lowest, 2])


def lowest_crown_point(
    points_m: np.ndarray, crown: np.ndarray, *, support_radius_m: float, support_points: int
) -> int:
    """Index of the lowest point of the crown (``crown`` mask, see :func:`crown_mask`) with at least
    ``support_points`` crown neighbours within ``support_radius_m``, so no stray point sets the base.
    Without crown points, the lowest point."""
    members = np.flatnonzero(crown)
    if members.size == 0:
        return int(np.argmin(points_m[:, 2]))
    candidates = points_m[members]
    order = np.argsort(candidates[:, 2])[:5000]
    lowest = _first_supported(
        NearestTree(candidates),
        candidates,
        order,
        support_radius_m=support_radius_m,
        support_points=support_points,
    )
    return int(members[lowest])


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
    return float(occupied_voxels(points_m, voxel_m).cells.shape[0] * voxel_m**3)


def canopy_metrics(
    points_m: np.ndarray,
    *,
    trunk: TrunkAxis,
    foliage: np.ndarray | None = None,
    crown: np.ndarray | None = None,
    pixel_footprint_m: np.ndarray | None = None,
    config: MetricsConfig,
    refuse_pole_top: bool = True,
) -> CanopyMetrics:
    """All metrics of one tree cloud in the world frame; ``foliage`` marks the points coloured as leaves.

    The tree measured is its crown (``crown``, a mask decided already, e.g. on more views together; else
    :func:`crown_mask` of these points) and its trunk: the crown candidates apart from the crown (ground
    vegetation, suckers, fallen fruit, stray points below the crown) are left out of every metric.
    ``thickness_m`` and ``crown_base_m`` are the geometric estimates (the more accurate on trees with a
    clear trunk); ``thickness_kde_m`` and ``crown_base_kde_m`` follow the paper's eqs. 7-8. ``points``
    counts the points given.

    ``pixel_footprint_m`` is each point's depth pixel pitch where it lies (its depth over the focal length
    of the camera that saw it). The last pixel that reads the crown at an extreme (either end of W, the
    top, the lowest leaf) lies on average half a pitch inside the crown's true outline, so each extreme is
    moved out by ``config.edge_px`` pitches there; without footprints, the points' own extremes count.

    With ``refuse_pole_top``, a top as thin as a pole over more than ``config.max_thin_top_m``
    (:func:`thin_top_m`) is refused: a support stake standing above the crown. A single view's cloud is
    not judged so (False): one view sees a leader's bare tip as a thinner line, and over a longer stretch,
    than the views together (on mixed 2091, three trees' tips ran 0.20-0.25 m in one view, none over
    0.15 m merged).

    Raises
    ------
    MeasurementError
        No crown among the points, or (``refuse_pole_top``) a top as thin as a pole too far.
    """
    if crown is None:
        crown = crown_mask(
            points_m,
            trunk,
            candidates=crown_candidates(
                points_m, trunk, foliage=foliage, min_radius_m=config.crown_base_min_radius_m
            ),
            config=config,
        )
    kept = measured_points(points_m, trunk, crown=crown, foliage=foliage, config=config)
    if not crown.any():
        raise MeasurementError(
            f"no crown among the {points_m.shape[0]} tree points: only ground vegetation, fruit or the trunk",
            hint="check that the tree's crown is in view and inside roi.radius_m",
        )
    tree_points = points_m[kept]
    edge_m = (
        config.edge_px * pixel_footprint_m[kept]
        if pixel_footprint_m is not None
        else np.zeros(tree_points.shape[0])
    )
    top = highest_supported(
        tree_points, support_radius_m=config.support_radius_m, support_points=config.top_support_points
    )
    height = float(tree_points[top, 2] + edge_m[top])
    thin = (
        thin_top_m(
            tree_points,
            top_z_m=float(tree_points[top, 2]),
            slab_m=config.support_radius_m,
            width_m=config.pole_width_m,
        )
        if refuse_pole_top
        else 0.0
    )
    if thin > config.max_thin_top_m and not np.isclose(thin, config.max_thin_top_m):  # whole slabs
        raise MeasurementError(
            f"the tree's top {thin:.2f} m is as thin as a pole (each {config.support_radius_m * 100:.0f} cm "
            f"of it within {config.pole_width_m * 100:.0f} cm of its middle), longer than a leader's bare "
            f"tip ({config.max_thin_top_m:.2f} m): most likely a support stake standing above the crown, "
            "which would be measured as the tree's top",
            field="metrics.max_thin_top_m",
            hint="a stake above the crown cannot be told from the tree yet; if no stake stands above this "
            f"tree and its leader is bare that far, measure it with metrics.max_thin_top_m="
            f"{math.ceil(round(thin * 100.0, 6)) / 100.0:.2f} "
            "(canopy measure --set, or a job's config)",
        )
    base_kde = crown_base_kde(
        tree_points[:, 2], height_m=height, bandwidth_m=config.kde_bandwidth_m, threshold=config.kde_threshold
    )
    lowest = lowest_crown_point(
        tree_points,
        crown[kept],
        support_radius_m=config.support_radius_m,
        support_points=config.base_support_points,
    )
    base_geometric = float(tree_points[lowest, 2] - edge_m[lowest])
    upper = tree_points[tree_points[:, 2] >= tree_points[lowest, 2]]
    along, across = crown_diameters(upper)
    first, second = widest_pair(
        tree_points, support_radius_m=config.support_radius_m, support_points=config.top_support_points
    )
    ends = tree_points[[first, second], :2]
    span = float(np.linalg.norm(ends[1] - ends[0]))
    width = span + float(edge_m[[first, second]].sum())
    along_w = (ends[1] - ends[0]) / span if span > 0 else np.zeros(2)
    ends = ends + np.array([-edge_m[first], edge_m[second]])[:, None] * along_w
    marks = CrownMarks(
        top_m=(float(tree_points[top, 0]), float(tree_points[top, 1]), height),
        crown_base_point_m=(float(tree_points[lowest, 0]), float(tree_points[lowest, 1]), base_geometric),
        width_ends_m=((float(ends[0, 0]), float(ends[0, 1])), (float(ends[1, 0]), float(ends[1, 1]))),
    )
    return CanopyMetrics(
        height_m=height,
        width_m=width,
        thickness_m=height - base_geometric,
        crown_base_m=base_geometric,
        thickness_kde_m=height - base_kde,
        crown_base_kde_m=base_kde,
        diameter_along_row_m=along,
        diameter_across_row_m=across,
        projected_area_m2=projected_area(upper),
        volume_hull_m3=hull_volume(upper),
        volume_voxel_m3=voxel_volume(upper, voxel_m=config.voxel_volume_m),
        points=int(points_m.shape[0]),
        marks=marks,
    )


def measured_points(
    points_m: np.ndarray,
    trunk: TrunkAxis,
    *,
    crown: np.ndarray,
    foliage: np.ndarray | None,
    config: MetricsConfig,
) -> np.ndarray:
    """Mask of the points every metric is read from: the crown and what is no crown candidate (the trunk);
    the candidates apart from the crown (ground vegetation, suckers, fallen fruit, stray points below it)
    are not the tree."""
    candidates = crown_candidates(
        points_m, trunk, foliage=foliage, min_radius_m=config.crown_base_min_radius_m
    )
    return np.asarray(crown | ~candidates)
