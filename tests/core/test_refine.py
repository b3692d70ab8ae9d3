"""ICP anchored to the balls: recovers a small misregistration on shared surfaces, never slides on a plane."""

from __future__ import annotations

import numpy as np
import open3d as o3d
from scipy.spatial.transform import Rotation

from canopy_core.config import IcpConfig
from canopy_core.refine import anchored_icp, refine_views
from canopy_core.register import apply, invert, pose_change

BALLS = np.array([[0.5, 0.1, 0.05], [-0.3, 0.45, 0.05], [-0.25, -0.5, 0.05]])


def _normals(points: np.ndarray) -> np.ndarray:
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.08, max_nn=20))
    return np.asarray(cloud.normals)


def _ground_and_trunk(rng: np.random.Generator) -> np.ndarray:
    ground = np.column_stack([rng.uniform(-1.5, 1.5, (6000, 2)), np.zeros(6000)])
    angle = rng.uniform(0, 2 * np.pi, 1500)
    trunk = np.column_stack([0.08 * np.cos(angle), 0.08 * np.sin(angle), rng.uniform(0, 0.6, 1500)])
    return np.vstack([ground, trunk])


def _small_motion(degrees: float, shift_m: list[float]) -> np.ndarray:
    motion = np.eye(4)
    motion[:3, :3] = Rotation.from_rotvec(np.radians(degrees) * np.array([0.6, 0.8, 0.0])).as_matrix()
    motion[:3, 3] = shift_m
    return motion


def test_anchored_icp_undoes_a_small_misregistration() -> None:
    rng = np.random.default_rng(0)
    target = _ground_and_trunk(rng)
    misregistration = _small_motion(0.4, [0.01, -0.008, 0.006])
    source = apply(misregistration, _ground_and_trunk(rng))
    correction = anchored_icp(
        source,
        target,
        _normals(target),
        apply(misregistration, BALLS),
        BALLS,
        max_correspondence_m=0.05,
        iterations=30,
    )
    translation, rotation = pose_change(invert(misregistration), correction)
    assert translation < 0.002 and rotation < 0.05


def test_anchored_icp_does_not_slide_along_a_plane() -> None:
    rng = np.random.default_rng(1)
    plane = np.column_stack([rng.uniform(-1.5, 1.5, (6000, 2)), np.zeros(6000)])
    source = np.column_stack([rng.uniform(-1.5, 1.5, (6000, 2)), rng.normal(0, 0.003, 6000)])
    correction = anchored_icp(
        source, plane, _normals(plane), BALLS, BALLS, max_correspondence_m=0.05, iterations=30
    )
    assert np.abs(apply(correction, BALLS) - BALLS).max() < 0.002


def test_refinement_is_reported_and_the_reference_never_moves() -> None:
    rng = np.random.default_rng(2)
    first = _ground_and_trunk(rng)
    misregistration = _small_motion(0.3, [0.0, 0.005, 0.004])
    second = apply(misregistration, _ground_and_trunk(rng))
    corrections, reports = refine_views(
        ["views/1", "views/2"],
        [first, second],
        view_anchors_m=[BALLS, apply(misregistration, BALLS)],
        config=IcpConfig(),
    )
    assert np.array_equal(corrections[0], np.eye(4))
    (report,) = reports
    assert report.view == "views/2" and report.accepted, report.reason
    assert report.after.distance_p50_m < report.before.distance_p50_m
    assert pose_change(invert(misregistration), corrections[1])[1] < 0.05
