"""Canopy metrics on point sets whose answers are known exactly."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from canopy_core.config import MetricsConfig
from canopy_core.metrics import (
    canopy_height,
    canopy_metrics,
    crown_base_geometric,
    crown_base_kde,
    hull_volume,
    max_horizontal_distance,
    projected_area,
    voxel_volume,
)


def _ellipsoid_crown(
    rng: np.random.Generator, *, centre_z: float, radii: tuple[float, float, float], n: int
) -> np.ndarray:
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    scale = rng.uniform(0.7, 1.0, size=(n, 1)) ** (1 / 3)
    return direction * scale * np.array(radii) + [0.0, 0.0, centre_z]


def _tree(rng: np.random.Generator) -> np.ndarray:
    trunk_z = rng.uniform(0.0, 1.0, size=800)
    angle = rng.uniform(0, 2 * np.pi, size=800)
    trunk = np.column_stack([0.06 * np.cos(angle), 0.06 * np.sin(angle), trunk_z])
    return np.vstack([trunk, _ellipsoid_crown(rng, centre_z=2.0, radii=(0.8, 0.6, 1.0), n=20000)])


def test_height_is_top_of_supported_points_above_ground() -> None:
    tree = _tree(np.random.default_rng(0))
    assert canopy_height(tree, ground_z_m=0.0) == pytest.approx(tree[:, 2].max(), abs=0.02)
    assert canopy_height(tree, ground_z_m=0.5) == pytest.approx(tree[:, 2].max() - 0.5, abs=0.02)


def test_height_ignores_a_lone_stray_point_above_the_crown() -> None:
    tree = _tree(np.random.default_rng(1))
    with_insect = np.vstack([tree, [[0.1, 0.0, 3.6]]])
    assert canopy_height(with_insect) == pytest.approx(canopy_height(tree))
    assert canopy_height(with_insect) < 3.1


def test_width_is_hull_diameter_of_horizontal_projection() -> None:
    rng = np.random.default_rng(2)
    points = rng.uniform(-1, 1, size=(400, 3)) * [1.0, 0.4, 2.0]
    brute = max(np.linalg.norm(a[:2] - b[:2]) for a, b in itertools.combinations(points, 2))
    assert max_horizontal_distance(points) == pytest.approx(brute, rel=1e-12)


def test_width_ignores_height() -> None:
    points = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 5.0], [0.0, 1.0, -3.0], [0.5, 0.5, 9.0]])
    assert max_horizontal_distance(points) == pytest.approx(np.sqrt(2.0))


def test_kde_crown_base_finds_where_the_crown_starts_above_a_sparse_trunk() -> None:
    tree = _tree(np.random.default_rng(3))
    base = crown_base_kde(tree[:, 2], height_m=3.0, bandwidth_m=0.04, threshold=0.25)
    assert 0.96 <= base <= 1.12  # the crown's lowest points are at z = 1.0; h = 0.04 smooths by about h


def test_kde_threshold_is_unit_independent() -> None:
    z = _tree(np.random.default_rng(4))[:, 2]
    metres = crown_base_kde(z, height_m=3.0, bandwidth_m=0.04, threshold=0.25)
    millimetres = crown_base_kde(z * 1000, height_m=3000.0, bandwidth_m=40.0, threshold=0.25)
    assert millimetres / 1000 == pytest.approx(metres, abs=1e-3)


def test_geometric_crown_base_is_lowest_point_away_from_trunk() -> None:
    tree = _tree(np.random.default_rng(5))
    base = crown_base_geometric(tree, np.zeros(2), min_radius_m=0.25, support_radius_m=0.05, support_points=4)
    expected = tree[np.linalg.norm(tree[:, :2], axis=1) > 0.25, 2].min()
    assert base == pytest.approx(expected, abs=0.03)


def test_volumes_and_area_of_a_filled_box() -> None:
    grid = np.stack(np.meshgrid(*[np.linspace(0, 1, 21)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    box = grid * [2.0, 1.0, 0.5]
    assert hull_volume(box) == pytest.approx(1.0)
    assert projected_area(box) == pytest.approx(2.0)
    assert voxel_volume(box + 1e-6, voxel_m=0.25) == pytest.approx(9 * 5 * 3 * 0.25**3)


def test_canopy_metrics_reports_paper_and_extra_metrics_consistently() -> None:
    tree = _tree(np.random.default_rng(6))
    metrics = canopy_metrics(tree, trunk_xy_m=np.zeros(2), config=MetricsConfig())
    assert metrics.height_m == pytest.approx(3.0, abs=0.02)
    assert metrics.width_m == pytest.approx(1.6, abs=0.03)
    assert metrics.thickness_m == pytest.approx(metrics.height_m - metrics.crown_base_m)
    assert metrics.diameter_along_row_m == pytest.approx(1.6, abs=0.03)
    assert metrics.diameter_across_row_m == pytest.approx(1.2, abs=0.03)
    assert metrics.volume_voxel_m3 > 0 and 0 < metrics.volume_hull_m3 < 4 / 3 * np.pi * 0.8 * 0.6 * 1.0
    assert metrics.points == tree.shape[0]
