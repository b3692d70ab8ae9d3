"""Coarse registration from ball centres: Kabsch/Umeyama and the paper's Rx·Ry·Rz construction."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from canopy_core.register import apply, invert, paper_transform, pose_change, register_by_balls


def _random_pose(rng: np.random.Generator) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = Rotation.random(random_state=rng).as_matrix()
    pose[:3, 3] = rng.uniform(-3, 3, size=3)
    return pose


def _ball_triangle(rng: np.random.Generator) -> np.ndarray:
    """Red, yellow, blue centres on the ground around a trunk, 2-4 m in front of a camera."""
    angles = np.radians([90.0, 210.0, 330.0]) + rng.uniform(-0.3, 0.3, size=3)
    radius = rng.uniform(0.35, 0.8, size=3)
    return np.column_stack([radius * np.cos(angles), np.full(3, 1.2), 3.0 + radius * np.sin(angles)])


@pytest.mark.parametrize("seed", range(20))
def test_ball_registration_recovers_pose_from_exact_centres(seed: int) -> None:
    rng = np.random.default_rng(seed)
    target = _ball_triangle(rng)
    truth = _random_pose(rng)
    source = apply(invert(truth), target)
    translation, rotation = pose_change(truth, register_by_balls(source, target))
    assert translation < 2e-3 and rotation < 0.1
    assert translation < 1e-9 and rotation < 1e-6  # exact data: exact answer


@pytest.mark.parametrize("seed", range(20))
def test_paper_construction_agrees_with_least_squares_on_exact_centres(seed: int) -> None:
    rng = np.random.default_rng(seed)
    target = _ball_triangle(rng)
    source = apply(invert(_random_pose(rng)), target)
    translation, rotation = pose_change(register_by_balls(source, target), paper_transform(source, target))
    assert translation < 1e-9 and rotation < 1e-6


def test_paper_canonical_frame_puts_normal_on_z_and_yellow_on_x() -> None:
    from canopy_core.register import canonical_ball_frame

    centres = _ball_triangle(np.random.default_rng(3))
    canonical = apply(canonical_ball_frame(*centres), centres)
    assert np.allclose(canonical.mean(axis=0), 0.0, atol=1e-12)
    assert np.allclose(canonical[:, 2], 0.0, atol=1e-12)
    assert canonical[1, 0] > 0 and abs(canonical[1, 1]) < 1e-12


def test_least_squares_spreads_noise_at_least_as_well_as_the_paper() -> None:
    rng = np.random.default_rng(11)
    errors_lsq, errors_paper = [], []
    for _ in range(200):
        target = _ball_triangle(rng)
        truth = _random_pose(rng)
        source = apply(invert(truth), target) + rng.normal(0, 0.003, size=(3, 3))
        errors_lsq.append(pose_change(truth, register_by_balls(source, target))[1])
        errors_paper.append(pose_change(truth, paper_transform(source, target))[1])
    assert np.mean(errors_lsq) <= np.mean(errors_paper)


def test_more_than_three_balls_are_used_together() -> None:
    rng = np.random.default_rng(5)
    target = np.vstack([_ball_triangle(rng), _ball_triangle(rng) + [0.2, 0.0, 0.1]])
    truth = _random_pose(rng)
    translation, rotation = pose_change(truth, register_by_balls(apply(invert(truth), target), target))
    assert translation < 1e-9 and rotation < 1e-6


def test_collinear_centres_are_refused() -> None:
    line = np.array([[0.0, 0, 1], [0.5, 0, 1], [1.0, 0, 1]])
    with pytest.raises(ValueError, match="collinear"):
        register_by_balls(line, line)
    with pytest.raises(ValueError, match="at least 3"):
        register_by_balls(line[:2], line[:2])


def test_pose_change_measures_translation_and_angle() -> None:
    moved = np.eye(4)
    moved[:3, :3] = Rotation.from_euler("z", 3.0, degrees=True).as_matrix()
    moved[:3, 3] = [0.03, 0.04, 0.0]
    translation, rotation = pose_change(np.eye(4), moved)
    assert translation == pytest.approx(0.05) and rotation == pytest.approx(3.0)
