"""The trunk's axis followed up from its foot: where a leaning or bending trunk stands at each height.

The ground frame finds the trunk's foot as the circle its bark makes in a low slice
(:mod:`canopy_core.ground`). A fruit tree's trunk is rarely plumb above it: it leans (trees are planted
and trained at an angle, wind and a heavy crop bend them) and bends between nodes, a few centimetres by a
metre's height. The crown is told from the trunk within a column round the trunk's axis
(:func:`canopy_core.metrics.crown_mask`), so that column must follow the trunk; a vertical one round the foot
leaves the bark's outline outside it at the crown's height, where its mixed pixels, coloured by the leaves
behind the trunk, pass for foliage and chain the crown base down the trunk (2099002: 0.27-0.53 m low).

The axis is followed by geometry alone, slab by slab, from the foot circle up (:func:`follow_trunk`): in
each slab the trunk is a circle about as wide as the one below (trunks taper by millimetres a slab) whose
centre stands within the steepest lean's reach of it, with many points on it and few inside (a trunk is
solid). A slab without such a circle (a sucker or tall weeds beside the trunk, a fork, leaves round it)
leaves the axis as it was found below and above it; where the crown's leaves hide the trunk for good, the
axis ends, held above at its last circle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from canopy_core.config import MetricsConfig
from canopy_core.ground import TRUNK_RADIUS_RANGE_M, TRUNK_SLICE_M, fit_circle

__all__ = ["SOLID_INSIDE_SHARE", "TrunkAxis", "follow_trunk"]

_FOOT_HEIGHT_M = sum(TRUNK_SLICE_M) / 2
"""The foot circle is the bark's in the ground frame's low slice: the axis's first point stands at its
middle height, and below it the axis is held there."""
SOLID_INSIDE_SHARE = 0.2
"""A slab shows the trunk when at most this many points per point on its circle lie inside it: a trunk is
solid, only the depth noise puts a few of its bark's points inside; leaves round the trunk, a fork's two
stems or a circle drawn through foliage have as many inside as on it, or more."""
_KEPT_SHARE = 0.5
"""A slab's circle holds at least this share of the points on the last slab's: the cameras see the trunk
alike over a few decimetres, where a circle that happens to run through some leaves holds a few."""
_REFINEMENTS = 3
"""Least-squares circle fits per slab, each on the points within the tolerance of the previous fit."""
_COARSE_STEPS = 2
"""The vote over centres runs first on a grid this many tolerances apart (a quarter of the centres to
score where the reach is wide, after slabs without the trunk), then at one tolerance round the best."""


@dataclass(frozen=True, eq=False)
class TrunkAxis:
    """The trunk's axis as the horizontal position (m, world frame) of its centre at a few heights,
    ascending, joined by straight lines and held beyond the first and the last (at least one height)."""

    heights_m: np.ndarray
    """``(K,)`` heights, ascending."""
    centres_xy_m: np.ndarray
    """``(K, 2)`` the trunk's centre at each height."""

    @classmethod
    def vertical(cls, foot_xy_m: np.ndarray | tuple[float, float]) -> TrunkAxis:
        """A trunk standing plumb above its foot: what is known where only the foot was found."""
        return cls(heights_m=np.zeros(1), centres_xy_m=np.asarray(foot_xy_m, dtype=float).reshape(1, 2))

    def xy_at(self, z_m: np.ndarray) -> np.ndarray:
        """``(N, 2)`` the trunk's centre at each of the heights ``z_m`` ``(N,)``."""
        return np.column_stack(
            [np.interp(z_m, self.heights_m, self.centres_xy_m[:, axis]) for axis in range(2)]
        )

    def distance_m(self, points_m: np.ndarray) -> np.ndarray:
        """Each of ``(N, 3)`` points' horizontal distance from the trunk's axis at its own height."""
        return np.linalg.norm(points_m[:, :2] - self.xy_at(points_m[:, 2]), axis=1)


def follow_trunk(
    points_m: np.ndarray,
    foot_xy_m: np.ndarray | tuple[float, float],
    *,
    foot_radius_m: float | None,
    config: MetricsConfig,
) -> TrunkAxis:
    """The trunk's axis through the tree's ``(N, 3)`` points (world frame, z up from the ground at the
    trunk's foot), followed up from the foot circle (centre ``foot_xy_m``, radius ``foot_radius_m``, found
    in the ground frame's low slice, at whose middle height the axis starts).

    Slab by slab (``config.trunk_slab_m`` high) above it, the trunk's circle is sought among the points within
    reach of the one found last: its centre within the steepest lean's shift (``config.trunk_max_lean_deg``
    over the height climbed since) of the last centre (see :func:`_slab_circle`). It continues the axis when
    at least ``config.trunk_min_points``, and half as many points as on the last, lie on it within
    ``config.trunk_bark_tolerance_m``, few inside it (a trunk is solid), and its radius is at most that
    tolerance below the last one's and above the narrowest so far, and no less than a whip's (2 cm). Trunks
    taper by millimetres a slab: a wider circle is a fork or a clump of leaves, even when it widens a little a
    slab; a much narrower one a sucker or a fit on a sliver of arc, though a circle may still narrow by the
    tolerance a slab. Colour plays no part: bark that the camera's white balance turns green is still a
    circle. The axis ends (held above at its last circle) once more than ``config.trunk_max_gap_m`` of slabs
    in a row have not shown the trunk: the crown hides it from there, and a circle found higher up is a branch
    or the leader's tip.

    Without a foot circle (``foot_radius_m`` None: grass and weeds hid the bark, the trunk was only the low
    slice's median), or with ``config.trunk_max_lean_deg`` 0, the axis stands plumb above the foot. Points
    with a coordinate not finite are left out.
    """
    foot = np.asarray(foot_xy_m, dtype=float)
    points_m = points_m[np.isfinite(points_m).all(axis=1)]
    if foot_radius_m is None or config.trunk_max_lean_deg == 0 or points_m.shape[0] == 0:
        return TrunkAxis.vertical(foot)
    slab_m, tolerance_m = config.trunk_slab_m, config.trunk_bark_tolerance_m
    lean_per_m = float(np.tan(np.radians(config.trunk_max_lean_deg)))
    z_m = points_m[:, 2]
    heights, centres = [_FOOT_HEIGHT_M], [foot]
    radius, min_points, last_slab = float(foot_radius_m), config.trunk_min_points, 0
    narrowest_m = radius
    slabs = int(np.ceil((float(z_m.max()) - _FOOT_HEIGHT_M) / slab_m - 0.5))
    for slab in range(1, slabs + 1):
        if (slab - last_slab - 1) * slab_m > config.trunk_max_gap_m + 1e-9:
            break
        middle = _FOOT_HEIGHT_M + slab * slab_m
        allowed_m = lean_per_m * (slab - last_slab) * slab_m
        xy = points_m[np.abs(z_m - middle) < slab_m / 2, :2]  # most axes end within a few slabs: no sort
        near = xy[np.linalg.norm(xy - centres[-1], axis=1) < radius + allowed_m + tolerance_m]
        circle = _slab_circle(
            near, centres[-1], radius, reach_m=allowed_m, min_points=min_points, tolerance_m=tolerance_m
        )
        if circle is None:
            continue
        centre, slab_radius, on_circle = circle
        if (
            max(radius - tolerance_m, TRUNK_RADIUS_RANGE_M[0]) <= slab_radius <= narrowest_m + tolerance_m
            and np.linalg.norm(centre - centres[-1]) <= allowed_m
        ):
            heights.append(middle)
            centres.append(centre)
            radius, last_slab = slab_radius, slab
            narrowest_m = min(narrowest_m, radius)
            min_points = max(config.trunk_min_points, int(_KEPT_SHARE * on_circle))
    return TrunkAxis(heights_m=np.array(heights), centres_xy_m=np.array(centres))


def _slab_circle(
    xy: np.ndarray,
    centre: np.ndarray,
    radius: float,
    *,
    reach_m: float,
    min_points: int,
    tolerance_m: float,
) -> tuple[np.ndarray, float, int] | None:
    """Centre, radius and number of points on it of the trunk's circle among a slab's ``(N, 2)`` points,
    its centre within ``reach_m`` of the last circle's (``centre``, ``radius``); None when fewer than
    ``min_points`` lie on it, or more than a few inside it (``SOLID_INSIDE_SHARE``: a trunk is solid, a view
    sees only its surface).

    Centres on a grid within reach are scored at the last radius (the trunk tapers by millimetres a slab):
    the points on the circle less those inside it, as a solid trunk shows them; weeds or leaves beside the
    trunk, scattered, hold no circle's worth. The vote runs on a coarse grid first, with a band as wide as
    its step, then at the tolerance round the best. The best is refined by least squares on the points
    within the tolerance of it.
    """
    coarse_m = _COARSE_STEPS * tolerance_m
    centre = _best_centre(xy, centre, radius, reach_m=reach_m, step_m=coarse_m, band_m=coarse_m)
    centre = _best_centre(xy, centre, radius, reach_m=coarse_m, step_m=tolerance_m, band_m=tolerance_m)
    for _ in range(_REFINEMENTS):
        on_circle = xy[np.abs(np.linalg.norm(xy - centre, axis=1) - radius) < tolerance_m]
        if on_circle.shape[0] < max(min_points, 3):
            return None
        centre, radius = fit_circle(on_circle)
    distance = np.linalg.norm(xy - centre, axis=1)
    on_circle_count = int(np.count_nonzero(np.abs(distance - radius) < tolerance_m))
    inside = np.count_nonzero(distance < radius - tolerance_m)
    if on_circle_count < min_points or inside > SOLID_INSIDE_SHARE * on_circle_count:
        return None
    return centre, radius, on_circle_count


def _best_centre(
    xy: np.ndarray, centre: np.ndarray, radius: float, *, reach_m: float, step_m: float, band_m: float
) -> np.ndarray:
    """Of the centres on a grid ``step_m`` apart within ``reach_m`` of ``centre`` (``centre`` itself among
    them; the grid's edge may stand half a step farther), the one whose circle of ``radius`` has the most of
    the ``(N, 2)`` points within ``band_m`` of it less those inside that band."""
    count = int(np.ceil(reach_m / step_m - 1e-9))
    steps = step_m * np.arange(-count, count + 1)
    grid = centre + np.stack(np.meshgrid(steps, steps), axis=-1).reshape(-1, 2)
    grid = grid[np.linalg.norm(grid - centre, axis=1) <= reach_m + step_m / 2]
    squared_m2 = (xy[None, :, 0] - grid[:, None, 0]) ** 2 + (xy[None, :, 1] - grid[:, None, 1]) ** 2
    within = np.count_nonzero(squared_m2 < (radius + band_m) ** 2, axis=1)
    inside = np.count_nonzero(squared_m2 < max(radius - band_m, 0.0) ** 2, axis=1)
    scores = within - 2 * inside  # on the circle (within it, not inside) less inside
    return grid[int(np.argmax(scores))]
