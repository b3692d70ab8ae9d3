"""Depth cleaning: flying pixels between surfaces go, true silhouettes stay; sparse outliers go."""

from __future__ import annotations

import numpy as np

from canopy_core.filters import reliable_depth_mask, sparse_point_mask


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


def test_lone_points_go_and_a_five_pixel_leaf_stays() -> None:
    rng = np.random.default_rng(0)
    pixel_m = 3.0 / 365.0  # a Kinect v2 pixel's footprint at 3 m
    grid = np.arange(-0.4, 0.4, pixel_m)
    surface = np.column_stack(
        [*(axis.ravel() for axis in np.meshgrid(grid, grid)), np.full(grid.size**2, 3.0)]
    )
    leaf = np.column_stack(
        [0.8 + pixel_m * np.array([[0, 0], [0, 1], [1, 0], [1, 1], [2, 1]]), np.full(5, 3.0)]
    )
    strays = np.column_stack([rng.uniform(-1, 1, (20, 2)), rng.uniform(3.2, 5.0, 20)])
    points = np.vstack([surface, leaf, strays])
    keep = sparse_point_mask(points, range_m=points[:, 2], focal_px=365.0)
    assert keep[: len(surface) + 5].all() and not keep[len(surface) + 5 :].any()


def test_dropouts_do_not_make_a_crown_top_against_the_sky_flying() -> None:
    """Leaves at the top of a crown: readings 2.9-3.0 m interleaved with dropouts (sky)."""
    rng = np.random.default_rng(1)
    depth = rng.uniform(2.9, 3.0, size=(20, 20)).astype(np.float32)
    depth[rng.random((20, 20)) < 0.4] = 0.0
    keep = reliable_depth_mask(depth)
    assert keep[depth > 0].all()
