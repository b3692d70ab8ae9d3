"""ICP refinement of the ball registration, anchored to the balls and gated so it can only help.

Views from opposite sides of a row share little foliage; what they do share is the ground, the trunk's foot
and the balls, so ICP runs on the low band of the region of interest. Plain ICP slides along the ground
there (the plane holds it only in height and tilt), by centimetres, away from a ball registration that
places the balls to millimetres across the ground. So each view is refined by a point-to-plane ICP whose
cost also holds the view's ball centres to the reference's (Gauss-Newton on both, weighted by their noise):
the ground and trunk correct tilt and height, the balls keep what the surfaces leave free. Views are
refined one at a time against all the others (multiway for three or more).

The balls hold tilt only through the heights of their centres, which is where their fits err most: a few
millimetres of noise over a triangle of 0.6-1.5 m is half a degree to a degree, and weeds or grass under
a ball drag its fit down by centimetres (2056020: 31 mm, a tilt of 2.4 degrees, H 10 % and D 14 % off).
The ground, seen round the trunk by every view, fixes the tilt ten times better. So a refinement is
accepted when it brings the view closer to the others (median correspondence distance) and moves the
balls across the ground (slide) and turns the view about the vertical (yaw) no farther than the balls'
fits leave open; its tilt and height are the ground's, up to the disagreement that fails the registration
(:func:`check_icp_agreement`). Otherwise the ball pose stays and the reason is reported.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from canopy_core.config import IcpConfig
from canopy_core.errors import RegistrationFailed
from canopy_core.kdtree import NearestTree
from canopy_core.normals import neighbourhood_normals
from canopy_core.register import apply, pose_change
from canopy_core.voxels import occupied_voxels

__all__ = [
    "AlignmentQuality",
    "IcpRefinement",
    "IcpSurface",
    "alignment_quality",
    "anchored_icp",
    "check_icp_agreement",
    "icp_surface",
    "refine_views",
    "refinement_bounds",
    "yaw_deg",
]

_NORMAL_NEIGHBOURS = 20
_MIN_POINTS = 200
"""A view with fewer points in the band ICP works on is not refined (nor are the others)."""
_SURFACE_SIGMA_M = 0.005
"""Depth noise of a Kinect v2 surface point at 3-4 m: the weight of a surface correspondence."""
_SURFACE_EFFECTIVE_POINTS = 300
"""How many independent measurements all surface correspondences together are worth."""
_CONVERGED_RAD = 2e-5
_CONVERGED_M = 1e-4
"""ICP stops when a step turns less than this (0.001 deg) and moves less than this (0.1 mm)."""
_ANCHOR_SIGMA_M = 0.003
"""Accuracy of a fitted ball centre: the weight holding the balls together."""


@dataclass(frozen=True)
class AlignmentQuality:
    """How well one view's points meet the other views' points.

    ``fitness`` is the fraction of the view's points with a neighbour in the other views within the
    correspondence distance (Open3D's fitness, which counts *source* points); the percentiles are of those
    neighbour distances, which reveal a bad alignment that a single fitness number hides. The distances
    are None when no point has a neighbour within the correspondence distance.
    """

    fitness: float
    inlier_rmse_m: float | None
    distance_p50_m: float | None
    distance_p90_m: float | None


@dataclass(frozen=True)
class IcpRefinement:
    """The outcome of refining one view's pose."""

    view: str
    accepted: bool
    reason: str
    before: AlignmentQuality
    after: AlignmentQuality
    translation_change_m: float
    rotation_change_deg: float
    ball_shift_m: float
    ball_slide_m: float
    yaw_change_deg: float

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict."""
        return asdict(self)


def alignment_quality(
    points_m: np.ndarray, others: NearestTree, *, max_distance_m: float
) -> AlignmentQuality:
    """Correspondence statistics of ``points_m`` against the points indexed by ``others``."""
    distance, _ = others.query(points_m, distance_upper_bound=max_distance_m)
    matched = distance[np.isfinite(distance)]
    if matched.size == 0:
        return AlignmentQuality(0.0, None, None, None)
    return AlignmentQuality(
        fitness=float(matched.size / points_m.shape[0]),
        inlier_rmse_m=float(np.sqrt(np.mean(matched**2))),
        distance_p50_m=float(np.percentile(matched, 50)),
        distance_p90_m=float(np.percentile(matched, 90)),
    )


def _closer(after: AlignmentQuality, before: AlignmentQuality) -> bool:
    """True when the median correspondence distance fell (and there were correspondences to compare)."""
    return (
        after.distance_p50_m is not None
        and before.distance_p50_m is not None
        and after.distance_p50_m < before.distance_p50_m
    )


@dataclass(frozen=True)
class IcpSurface:
    """A view's points as ICP matches them (see :func:`icp_surface`)."""

    points_m: np.ndarray
    """``(M, 3)`` the points thinned to one per voxel (each voxel's mean); none when too few were given."""
    normals: np.ndarray
    """``(M, 3)`` their unit normals."""
    source_points: int
    """How many points they were thinned from."""


def icp_surface(points_m: np.ndarray, voxel_m: float) -> IcpSurface:
    """A view's ``(N, 3)`` points thinned to one per voxel of edge ``voxel_m`` (each voxel's mean), with
    unit normals (the least-variance direction of the ``_NORMAL_NEIGHBOURS`` nearest thinned points); left
    empty when there are fewer than ``_MIN_POINTS`` points, too few to refine a view by. A step of its own,
    so that each view's is worked out in its own process (see :func:`canopy_core.alignment.align_views`)."""
    if points_m.shape[0] < _MIN_POINTS:
        return IcpSurface(np.zeros((0, 3)), np.zeros((0, 3)), int(points_m.shape[0]))
    voxels = occupied_voxels(points_m, voxel_m)
    sums = np.column_stack([np.bincount(voxels.of_point, weights=points_m[:, axis]) for axis in range(3)])
    thinned = sums / voxels.counts[:, None]
    neighbours = min(_NORMAL_NEIGHBOURS, thinned.shape[0])
    _, index = NearestTree(thinned).query(thinned, k=neighbours)
    normals = neighbourhood_normals(thinned, index.reshape(thinned.shape[0], neighbours))
    return IcpSurface(thinned, normals, int(points_m.shape[0]))


def anchored_icp(
    source_m: np.ndarray,
    target: NearestTree,
    target_normals: np.ndarray,
    source_anchors_m: np.ndarray,
    target_anchors_m: np.ndarray,
    *,
    max_correspondence_m: float,
    iterations: int,
    surface_sigma_m: float = _SURFACE_SIGMA_M,
    anchor_sigma_m: float = _ANCHOR_SIGMA_M,
) -> np.ndarray:
    """Point-to-plane ICP with anchor points held to their counterparts; returns the 4x4 correction.

    ``target`` indexes the target points (its ``data``), ``target_normals`` their unit normals.

    Minimises w sum (n_q . (C p - q))² / surface_sigma² + sum |C a - b|² / anchor_sigma² over rigid C by
    Gauss-Newton with small-angle updates, re-matching each source point to its nearest target point
    (within ``max_correspondence_m``) at every iteration. ``w`` scales the surface term to at most the
    weight of ``_SURFACE_EFFECTIVE_POINTS`` independent points, so the balls still count.
    """
    correction = np.eye(4)
    for _ in range(iterations):
        moved = apply(correction, source_m)
        distance, index = target.query(moved, distance_upper_bound=max_correspondence_m)
        matched = np.isfinite(distance)
        p, q, n = moved[matched], target.data[index[matched]], target_normals[index[matched]]
        anchors = apply(correction, source_anchors_m)
        # Correspondences between two views' samplings of one surface are not independent (shared bumps,
        # the sensor's bias at the same grazing angle): together they weigh as _SURFACE_EFFECTIVE_POINTS.
        surface_weight = np.sqrt(min(1.0, _SURFACE_EFFECTIVE_POINTS / max(p.shape[0], 1))) / surface_sigma_m
        surface_rows = np.hstack([np.cross(p, n), n]) * surface_weight
        surface_residual = np.einsum("ij,ij->i", p - q, n) * surface_weight
        anchor_rows = np.concatenate([np.hstack([-_skew(a), np.eye(3)]) for a in anchors]) / anchor_sigma_m
        anchor_residual = (anchors - target_anchors_m).ravel() / anchor_sigma_m
        jacobian = np.vstack([surface_rows, anchor_rows])
        residual = np.concatenate([surface_residual, anchor_residual])
        step = np.linalg.solve(jacobian.T @ jacobian, -jacobian.T @ residual)
        update = np.eye(4)
        update[:3, :3] = Rotation.from_rotvec(step[:3]).as_matrix()
        update[:3, 3] = step[3:]
        correction = update @ correction
        if np.linalg.norm(step[:3]) < _CONVERGED_RAD and np.linalg.norm(step[3:]) < _CONVERGED_M:
            break
    return correction


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def refine_views(
    view_names: list[str],
    surfaces: list[IcpSurface],
    *,
    view_anchors_m: list[np.ndarray],
    found_by_position: list[bool] | None = None,
    config: IcpConfig,
) -> tuple[list[np.ndarray], list[IcpRefinement]]:
    """Refine the poses of views already brought into one frame by the balls.

    Parameters
    ----------
    view_names
        The views, the first one the reference (never moved).
    surfaces
        Each view's region-of-interest points in the common frame after the ball registration, its z axis
        up (the ground's normal), thinned for ICP (:func:`icp_surface`).
    view_anchors_m
        Each view's own ball centres mapped into the common frame by its ball pose (matching rows). ICP
        holds them to the reference's, and a refinement may not slide them across the ground farther
        than ``config.max_ball_shift_m`` nor turn the view about the vertical more than
        ``config.max_rotation_deg``: the balls registered each view there to within a few millimetres. A
        row of NaN (a ball placed where the others put it, not seen in that view or the reference) holds
        nothing.
    found_by_position
        Per view, whether one of its balls was found where the other views place it (a fragment of the
        ball, fitted to a few centimetres, or a ball placed there unseen). A view with one, and every view
        when the reference has one, may slide and turn as far as
        ``config.max_ball_shift_found_by_position_m`` and ``config.max_rotation_found_by_position_deg``.
        None: no view has one.
    config
        ICP settings and the acceptance bounds.

    Returns
    -------
    (corrections, refinements)
        Per view a 4x4 correction to apply on top of its ball pose (identity where refinement was rejected,
        and for the reference), and per non-reference view the report of what happened.
    """
    if not len(view_names) == len(surfaces) == len(view_anchors_m):
        raise ValueError(
            f"{len(view_names)} views, {len(surfaces)} surfaces and {len(view_anchors_m)} sets of anchors "
            "given: one of each per view"
        )
    corrections = [np.eye(4) for _ in surfaces]
    if len(surfaces) < 2 or min(surface.source_points for surface in surfaces) < _MIN_POINTS:
        return corrections, []
    reports = []
    for index in range(1, len(surfaces)):
        points = surfaces[index].points_m
        others = [surface for j, surface in enumerate(surfaces) if j != index]
        moves = [correction for j, correction in enumerate(corrections) if j != index]
        others_tree = NearestTree(
            np.concatenate([apply(move, other.points_m) for move, other in zip(moves, others, strict=True)])
        )
        target_normals = np.concatenate(
            [other.normals @ move[:3, :3].T for move, other in zip(moves, others, strict=True)]
        )
        held = np.isfinite(view_anchors_m[index]).all(axis=1) & np.isfinite(view_anchors_m[0]).all(axis=1)
        anchors = view_anchors_m[index][held]
        correction = anchored_icp(
            points,
            others_tree,
            target_normals,
            anchors,
            view_anchors_m[0][held],
            max_correspondence_m=config.max_correspondence_m,
            iterations=config.max_iterations,
        )
        before = alignment_quality(points, others_tree, max_distance_m=config.max_correspondence_m)
        after = alignment_quality(
            apply(correction, points), others_tree, max_distance_m=config.max_correspondence_m
        )
        translation, rotation = pose_change(np.eye(4), correction)
        moved = apply(correction, anchors) - anchors
        ball_shift = float(np.linalg.norm(moved, axis=1).max(initial=0.0))
        slide = float(np.linalg.norm(moved[:, :2], axis=1).max(initial=0.0))
        yaw = yaw_deg(correction)
        loose = found_by_position is not None and (found_by_position[index] or found_by_position[0])
        max_slide, max_yaw = refinement_bounds(config, found_by_position=loose)
        if slide > max_slide or yaw > max_yaw:
            accepted, reason = (
                False,
                (
                    f"would slide the balls by {slide * 1000:.0f} mm across the ground and turn the view "
                    f"{yaw:.2f} deg about the vertical, more than the {max_slide * 1000:.0f} mm / "
                    f"{max_yaw:.1f} deg the ball registration leaves open"
                ),
            )
        elif not _closer(after, before):
            accepted, reason = False, "did not bring the view closer to the others (median distance)"
        else:
            accepted, reason = True, "improved the median correspondence distance"
        if accepted:
            corrections[index] = correction
        reports.append(
            IcpRefinement(
                view=view_names[index],
                accepted=accepted,
                reason=reason,
                before=before,
                after=after,
                translation_change_m=translation,
                rotation_change_deg=rotation,
                ball_shift_m=ball_shift,
                ball_slide_m=slide,
                yaw_change_deg=yaw,
            )
        )
    return corrections, reports


def yaw_deg(correction: np.ndarray) -> float:
    """How far the 4x4 ``correction`` turns about the vertical (the z axis), degrees: the twist of its
    rotation's swing-twist decomposition about z, apart from the tilt of the vertical itself."""
    *_, z, w = Rotation.from_matrix(correction[:3, :3]).as_quat()
    twist = 2.0 * np.arctan2(z, w)
    return float(abs(np.degrees((twist + np.pi) % (2.0 * np.pi) - np.pi)))


def refinement_bounds(config: IcpConfig, *, found_by_position: bool) -> tuple[float, float]:
    """How far the balls' fits leave a view's pose open: ``(shift_m, turn_deg)``, how far its balls may move
    and it may turn, the ball registration's own accuracy; looser where a ball was found by position (a
    fragment, its centre known to a few centimetres) in the view or the reference. A refinement is kept
    within these across the ground and about the vertical (:func:`refine_views`); a choice of balls that
    the surfaces must confirm meets them in every direction (``alignment._within_refinement_bounds``)."""
    if found_by_position:
        return config.max_ball_shift_found_by_position_m, config.max_rotation_found_by_position_deg
    return config.max_ball_shift_m, config.max_rotation_deg


def check_icp_agreement(reports: list[IcpRefinement], config: IcpConfig) -> None:
    """Refuse a ball registration that the views' own surfaces contradict.

    The anchored ICP holds the balls to each other with their fits' accuracy (millimetres), so when it
    still moves a view's balls by more than ``config.max_disagreement_m``, or turns the view by more than
    ``config.max_disagreement_deg``, to line up the ground and the trunk's foot, the balls and the surfaces
    tell different poses. The balls then lie: a look-alike was taken for one of them in some view and
    happened to make a triangle of the right sides (a sphere fitted on the trunk at another height, an
    apple where the ball's mirror image would lie, fragments of a yard's clutter with balls nearly in a
    line), and every number measured from that registration would be wrong without a sign.

    Raises
    ------
    RegistrationFailed
        Naming the first such view and how far its balls would have to move or the view turn.
    """
    for report in reports:
        moved = report.ball_shift_m > config.max_disagreement_m
        turned = report.rotation_change_deg > config.max_disagreement_deg
        if moved or turned:
            beyond = (
                f"its balls moved by {report.ball_shift_m * 1000:.0f} mm, more than their fits allow "
                f"({config.max_disagreement_m * 1000:.0f} mm)"
                if moved
                else f"the view turned by {report.rotation_change_deg:.1f} degrees, more than the balls "
                f"leave open ({config.max_disagreement_deg:.0f} degrees)"
            )
            raise RegistrationFailed(
                f"the views' ground and trunk line up only with {beyond}: something else of a ball's "
                "colour was probably taken for it in some view",
                view=report.view,
                field="icp.max_disagreement_m" if moved else "icp.max_disagreement_deg",
                hint="check with `canopy balls --preview` which sphere was taken for each ball; clear what "
                "looks like a ball from around them, or re-lay them in open view, and capture again",
            )
