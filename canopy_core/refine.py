"""ICP refinement of the ball registration, gated so that it can only make things better.

Views from opposite sides of a row share little foliage; what they do share is the ground, the trunk's foot
and the balls, so ICP runs on the region of interest with the ground in it. Pairwise point-to-plane ICP
between every two views feeds an Open3D pose graph (multiway registration, the first view fixed); each
view's refined pose is then accepted only if it brings the view closer to the others (median
correspondence distance) and stays close to the ball registration, which is accurate on
its own: a refinement may not move the balls by more than their registration leaves open. Otherwise the
ball pose is kept and the reason reported.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from canopy_core.config import IcpConfig
from canopy_core.register import apply, invert, pose_change

__all__ = ["AlignmentQuality", "IcpRefinement", "alignment_quality", "refine_views"]

_NORMAL_NEIGHBOURS = 20
_MIN_POINTS = 200


@dataclass(frozen=True)
class AlignmentQuality:
    """How well one view's points meet the other views' points.

    ``fitness`` is the fraction of the view's points with a neighbour in the other views within the
    correspondence distance (Open3D's fitness, which counts *source* points); the percentiles are of those
    neighbour distances, which reveal a bad alignment that a single fitness number hides.
    """

    fitness: float
    inlier_rmse_m: float
    distance_p50_m: float
    distance_p90_m: float


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

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict."""
        return asdict(self)


def alignment_quality(points_m: np.ndarray, others: cKDTree, *, max_distance_m: float) -> AlignmentQuality:
    """Correspondence statistics of ``points_m`` against the points indexed by ``others``."""
    distance, _ = others.query(points_m, distance_upper_bound=max_distance_m)
    matched = distance[np.isfinite(distance)]
    if matched.size == 0:
        return AlignmentQuality(0.0, float("nan"), float("nan"), float("nan"))
    return AlignmentQuality(
        fitness=float(matched.size / points_m.shape[0]),
        inlier_rmse_m=float(np.sqrt(np.mean(matched**2))),
        distance_p50_m=float(np.percentile(matched, 50)),
        distance_p90_m=float(np.percentile(matched, 90)),
    )


def _thinned(points_m: np.ndarray, voxel_m: float) -> o3d.geometry.PointCloud:
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points_m)).voxel_down_sample(voxel_m)
    cloud.estimate_normals(
        o3d.geometry.KDTreeSearchParamHybrid(radius=4 * voxel_m, max_nn=_NORMAL_NEIGHBOURS)
    )
    return cloud


def _pose_graph(clouds: list[o3d.geometry.PointCloud], config: IcpConfig) -> list[np.ndarray]:
    """Multiway registration: pairwise ICP between all views, optimised jointly with view 0 fixed."""
    registration = o3d.pipelines.registration
    graph = registration.PoseGraph()
    for _ in clouds:
        graph.nodes.append(registration.PoseGraphNode(np.eye(4)))
    criteria = registration.ICPConvergenceCriteria(max_iteration=config.max_iterations)
    estimation = registration.TransformationEstimationPointToPlane()
    for source in range(len(clouds)):
        for target in range(source + 1, len(clouds)):
            result = registration.registration_icp(
                clouds[source], clouds[target], config.max_correspondence_m, np.eye(4), estimation, criteria
            )
            information = registration.get_information_matrix_from_point_clouds(
                clouds[source], clouds[target], config.max_correspondence_m, result.transformation
            )
            graph.edges.append(
                registration.PoseGraphEdge(
                    source, target, result.transformation, information, uncertain=False
                )
            )
    option = registration.GlobalOptimizationOption(
        max_correspondence_distance=config.max_correspondence_m, edge_prune_threshold=0.25, reference_node=0
    )
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        registration.global_optimization(
            graph,
            registration.GlobalOptimizationLevenbergMarquardt(),
            registration.GlobalOptimizationConvergenceCriteria(),
            option,
        )
    reference = invert(np.asarray(graph.nodes[0].pose))
    return [reference @ np.asarray(node.pose) for node in graph.nodes]


def refine_views(
    view_names: list[str], points_m: list[np.ndarray], *, anchors_m: np.ndarray, config: IcpConfig
) -> tuple[list[np.ndarray], list[IcpRefinement]]:
    """Refine the poses of views already brought into one frame by the balls.

    Parameters
    ----------
    view_names
        The views, the first one the reference (never moved).
    points_m
        Each view's region-of-interest points in the common frame after the ball registration.
    anchors_m
        The ball centres in the common frame: a refinement may not move them farther than
        ``config.max_ball_shift_m``, since the balls registered each view to within a few millimetres.
    config
        ICP settings and the acceptance bounds.

    Returns
    -------
    (corrections, refinements)
        Per view a 4x4 correction to apply on top of its ball pose (identity where refinement was rejected,
        and for the reference), and per non-reference view the report of what happened.
    """
    corrections = [np.eye(4) for _ in points_m]
    if len(points_m) < 2 or min(p.shape[0] for p in points_m) < _MIN_POINTS:
        return corrections, []
    clouds = [_thinned(points, config.voxel_m) for points in points_m]
    thinned = [np.asarray(cloud.points) for cloud in clouds]
    poses = _pose_graph(clouds, config)
    reports = []
    for index in range(1, len(points_m)):
        others = np.concatenate(
            [apply(corrections[j], thinned[j]) for j in range(len(thinned)) if j != index]
        )
        others_tree = cKDTree(others)
        before = alignment_quality(thinned[index], others_tree, max_distance_m=config.max_correspondence_m)
        after = alignment_quality(
            apply(poses[index], thinned[index]), others_tree, max_distance_m=config.max_correspondence_m
        )
        translation, rotation = pose_change(np.eye(4), poses[index])
        ball_shift = float(np.linalg.norm(apply(poses[index], anchors_m) - anchors_m, axis=1).max())
        if ball_shift > config.max_ball_shift_m or rotation > config.max_rotation_deg:
            accepted, reason = (
                False,
                (
                    f"would move the balls by {ball_shift * 1000:.0f} mm and turn the view "
                    f"{rotation:.2f} deg, more than the {config.max_ball_shift_m * 1000:.0f} mm / "
                    f"{config.max_rotation_deg:.1f} deg "
                    "the ball registration leaves open"
                ),
            )
        elif not after.distance_p50_m < before.distance_p50_m:
            accepted, reason = False, "did not bring the view closer to the others (median distance)"
        else:
            accepted, reason = True, "improved the median correspondence distance"
        if accepted:
            corrections[index] = poses[index]
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
            )
        )
    return corrections, reports
