"""Depth cleaning: flying pixels between surfaces go, true silhouettes stay; sparse outliers go."""

from __future__ import annotations

import numpy as np

from canopy_core.filters import reliable_depth_mask, statistical_inliers


def _edge_scene() -> np.ndarray:
    """A foreground board at 2 m (left half) before a wall at 4 m, with a band of mixed depths between."""
    depth = np.full((60, 80), 4.0, dtype=np.float32)
    depth[:, :40] = 2.0
    depth[:, 40] = 2.7  # flying pixels: part foreground, part background
    depth[:, 41] = 3.4
    return depth


def test_flying_pixels_between_foreground_and_background_are_removed() -> None:
    keep = reliable_depth_mask(_edge_scene())
    assert not keep[:, 40].any() and not keep[:, 41].any()


def test_true_silhouette_and_background_edge_pixels_are_kept() -> None:
    keep = reliable_depth_mask(_edge_scene())
    assert keep[:, :40].all()  # the board's outline is not eroded
    assert keep[:, 42:].all()


def test_ground_seen_at_a_grazing_angle_is_not_taken_for_flying_pixels() -> None:
    """Flat ground 1.2 m below a level Kinect v2 (fy 365), out to 5 m: steep depth gradients, no edges."""
    rows = np.arange(212 + 88, 424, dtype=np.float32)  # 88 px below the horizon: 5 m away
    ground = np.tile((1.2 * 365.0 / (rows - 212.0))[:, None], (1, 64))
    assert ground.max() < 5.0
    assert reliable_depth_mask(ground).all()


def test_out_of_range_and_missing_readings_are_dropped() -> None:
    depth = np.full((10, 10), 3.0, dtype=np.float32)
    depth[0, 0], depth[1, 1], depth[2, 2] = 0.0, 0.1, 9.5
    keep = reliable_depth_mask(depth, min_depth_m=0.3, max_depth_m=8.0)
    assert not keep[0, 0] and not keep[1, 1] and not keep[2, 2]
    assert keep.sum() == 97


def test_statistical_outlier_removal_drops_isolated_points() -> None:
    rng = np.random.default_rng(0)
    dense = rng.normal(0, 0.05, size=(3000, 3))
    strays = rng.uniform(1.0, 2.0, size=(10, 3))
    kept = statistical_inliers(np.vstack([dense, strays]), neighbors=16, std_ratio=2.5)
    assert not np.isin(np.arange(3000, 3010), kept).any()
    assert np.isin(np.arange(3000), kept).mean() > 0.95


def test_flying_pixels_beside_missing_background_are_removed() -> None:
    """A leaf before a background beyond the sensor's range: the mixed pixels have no farther reading."""
    depth = _edge_scene()
    depth[:, 42:] = 0.0
    keep = reliable_depth_mask(depth)
    assert not keep[:, 40].any() and not keep[:, 41].any()
    assert keep[:, :40].all()
