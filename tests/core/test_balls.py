"""Calibration ball detection: sphere fits on synthetic points, colour masks, detection in rendered Kinect v2
views with look-alikes and flying pixels, and real Kinect v2 frames against the data authors' centres."""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pytest

from canopy_core.backproject import ViewCloud, backproject
from canopy_core.balls import (
    BallCandidate,
    color_likelihood,
    color_mask,
    detect_ball,
    detect_balls,
    find_ball_candidates,
)
from canopy_core.capture import load_capture
from canopy_core.config import BallConfig
from canopy_core.errors import BallNotFound
from canopy_core.ground import GroundPlane
from canopy_core.spheres import SphereFit, fit_sphere

REAL_BALL_DATA = Path(__file__).resolve().parents[3] / "shared" / "data" / "real-kinect2-ball"
REAL_FRAMES = [f"k{camera}_f{frame:03d}" for camera in (1, 2) for frame in range(10)]

WIDTH, HEIGHT, FX, FY, CX, CY = 512, 424, 365.0, 365.0, 256.0, 212.0
"""Kinect v2 depth camera."""

RED, YELLOW, BLUE = (200, 30, 35), (230, 200, 30), (30, 60, 200)
STRAW_PALE = (178, 167, 132)
"""Pale straw: the yellow ball's hue (HSV 46 deg) at saturation 0.26, 60 % of the yellow range's floor."""
BARK, FOLIAGE = (90, 70, 50), (60, 110, 40)


# --- synthetic points on a sphere -------------------------------------------------------------------------


def _visible_sphere_points(
    centre: np.ndarray, radius_m: float, count: int, rng: np.random.Generator
) -> np.ndarray:
    """Points spread over the part of a sphere the camera at the origin sees."""
    directions = rng.normal(size=(4 * count, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    points = centre + radius_m * directions
    visible = np.einsum("ij,ij->i", points - centre, points) < 0.0
    return points[visible][:count]


def _with_depth_noise(points: np.ndarray, sigma_m: float, rng: np.random.Generator) -> np.ndarray:
    """Move each point along its line of sight, as a depth camera's noise does."""
    rays = points / np.linalg.norm(points, axis=1, keepdims=True)
    return points + rays * rng.normal(0.0, sigma_m, size=(points.shape[0], 1))


def _flying_pixels(centre: np.ndarray, radius_m: float, count: int, rng: np.random.Generator) -> np.ndarray:
    """Points strung along the lines of sight just outside the silhouette, from the ball to far behind it."""
    view = centre / np.linalg.norm(centre)
    across = np.cross(view, [0.0, 1.0, 0.0])
    across /= np.linalg.norm(across)
    up = np.cross(view, across)
    angle = rng.uniform(0.0, 2.0 * np.pi, count)
    rim = centre + radius_m * 1.02 * (np.cos(angle)[:, None] * across + np.sin(angle)[:, None] * up)
    return rim * (1.0 + rng.uniform(0.0, 0.5, count) / np.linalg.norm(rim, axis=1))[:, None]


@pytest.mark.parametrize("distance_m", [2.0, 3.0, 4.0])
def test_fit_sphere_recovers_centre_of_noisy_partial_sphere(distance_m: float) -> None:
    rng = np.random.default_rng(int(distance_m * 10))
    centre = np.array([0.4, 0.3, distance_m])
    surface = _with_depth_noise(_visible_sphere_points(centre, 0.05, 240, rng), 0.003, rng)
    clutter = centre + rng.uniform(-0.15, 0.15, size=(30, 3))
    points = np.vstack([surface, _flying_pixels(centre, 0.05, 30, rng), clutter])

    fit = fit_sphere(points, radius_m=0.05)

    assert np.linalg.norm(fit.center_m - centre) < 0.003
    assert abs(fit.radius_m - 0.05) < 0.004
    assert fit.points >= 0.9 * 240
    assert fit.rms_m < 0.004


def test_fit_sphere_recovers_exact_sphere_exactly() -> None:
    centre = np.array([-0.3, 0.2, 2.5])
    points = _visible_sphere_points(centre, 0.05, 200, np.random.default_rng(1))

    fit = fit_sphere(points, radius_m=0.05)

    np.testing.assert_allclose(fit.center_m, centre, atol=1e-6)
    assert fit.radius_m == pytest.approx(0.05, abs=1e-6)
    assert fit.points == 200
    assert fit.rms_m < 1e-6


def test_fit_sphere_places_centre_behind_a_small_visible_cap() -> None:
    rng = np.random.default_rng(2)
    centre = np.array([0.0, 0.0, 3.0])
    cap = _visible_sphere_points(centre, 0.05, 400, rng)
    cap = cap[(cap - centre)[:, 2] < -0.05 * np.cos(np.radians(35.0))]  # the front 35 degrees only

    fit = fit_sphere(_with_depth_noise(cap, 0.001, rng), radius_m=0.05)

    assert fit.center_m[2] > cap[:, 2].max()
    assert np.linalg.norm(fit.center_m - centre) < 0.005


def test_fit_sphere_keeps_the_centre_of_a_ball_5_percent_larger_than_nominal() -> None:
    rng = np.random.default_rng(3)
    centre = np.array([0.2, -0.1, 2.0])
    points = _with_depth_noise(_visible_sphere_points(centre, 0.0525, 300, rng), 0.002, rng)

    fit = fit_sphere(points, radius_m=0.05)

    assert fit.radius_m == pytest.approx(0.0525, abs=0.001)
    assert np.linalg.norm(fit.center_m - centre) < 0.002


def test_the_free_radius_of_a_shallow_cap_stops_at_its_bound() -> None:
    # A 20 degree cap of a sphere three times the ball's radius (a grass tuft, a mound): the free fit's radius
    # runs to its bound, twice the nominal one. It reaches the bound and is held there while the centre is
    # solved; clamped step by step instead, it crept towards it and stopped 0.1 um short after dozens of
    # halved steps.
    rng = np.random.default_rng(0)
    centre, radius = np.array([0.1, 0.2, 3.3]), 0.15
    directions = rng.normal(size=(20000, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    towards_camera = -centre / np.linalg.norm(centre)
    cap = (centre + radius * directions)[directions @ towards_camera > np.cos(np.radians(20))][:200]

    fit = fit_sphere(_with_depth_noise(cap, 0.001, rng), radius_m=0.05)

    assert fit.radius_m == 0.1


def test_fit_sphere_is_deterministic_by_default() -> None:
    rng = np.random.default_rng(4)
    centre = np.array([0.1, 0.1, 3.0])
    points = np.vstack(
        [
            _with_depth_noise(_visible_sphere_points(centre, 0.05, 150, rng), 0.003, rng),
            centre + rng.uniform(-0.2, 0.2, size=(60, 3)),
        ]
    )

    first, second = fit_sphere(points, radius_m=0.05), fit_sphere(points, radius_m=0.05)

    np.testing.assert_array_equal(first.center_m, second.center_m)
    assert first.points == second.points


@pytest.mark.parametrize(
    ("points", "radius_m", "problem"),
    [
        (np.zeros((3, 3)), 0.05, "at least 4 points"),
        (np.zeros((10, 2)), 0.05, "shape"),
        (np.full((10, 3), np.nan), 0.05, "non-finite"),
        (np.ones((10, 3)), 0.0, "radius_m"),
        (np.ones((10, 3)), float("nan"), "radius_m"),
    ],
)
def test_fit_sphere_refuses_bad_input(points: np.ndarray, radius_m: float, problem: str) -> None:
    with pytest.raises(ValueError, match=problem):
        fit_sphere(points, radius_m=radius_m)


def test_sphere_fit_to_dict_is_json_ready() -> None:
    fit = SphereFit(
        center_m=np.array([0.1, 0.2, 3.0]),
        radius_m=0.05,
        points=120,
        rms_m=0.002,
        coverage=0.95,
    )

    assert json.loads(json.dumps(fit.to_dict())) == {
        "center_m": [0.1, 0.2, 3.0],
        "radius_m": 0.05,
        "points": 120,
        "rms_m": 0.002,
    }


# --- colour masks -------------------------------------------------------------------------------------------


def test_color_mask_selects_colours_within_hue_saturation_and_value() -> None:
    colors = np.array([YELLOW, (235, 225, 180), (60, 50, 10), BLUE, RED], dtype=np.uint8)

    mask = color_mask(colors, [[20, 110, 70], [34, 255, 255]])

    assert mask.tolist() == [True, False, False, False, False]  # pale and dark yellow fail S and V


def test_color_likelihood_keeps_a_shaded_ball_and_drops_paler_and_other_hues() -> None:
    yellow = BallConfig().hsv_range("yellow")
    colors = np.array(
        [
            YELLOW,  # the ball, lit: inside the range
            (46, 40, 6),  # the ball in deep shade: same hue and saturation, a fifth of the value
            (255, 200, 24),  # the ball under a warm white balance: hue a little off the range
            STRAW_PALE,  # straw: the ball's hue, 60 % of the range's saturation floor
            FOLIAGE,  # leaves: another hue
        ],
        dtype=np.uint8,
    )

    lit, shade, warm, straw, leaf = color_likelihood(colors, yellow, hue_spread=8.0)

    assert lit == 1.0 and warm > 0.8
    assert 0.4 < shade < 0.8  # counted in proportion to its value: shade keeps hue and saturation
    assert straw < 0.3  # below the saturation floor the likelihood falls as its cube
    assert leaf < 0.2  # 17 hue units off the range: over two hue spreads


def test_color_mask_wraps_red_hue_round_through_zero() -> None:
    crimson, scarlet, orange, green = (200, 20, 60), (200, 40, 20), (230, 120, 20), (40, 200, 40)
    colors = np.array([crimson, scarlet, orange, green], dtype=np.uint8)

    mask = color_mask(colors, [[168, 110, 50], [8, 255, 255]])

    assert mask.tolist() == [True, True, False, False]


# --- detection in rendered Kinect v2 views ------------------------------------------------------------------


@dataclass(frozen=True)
class Sphere:
    center_m: tuple[float, float, float]
    radius_m: float
    rgb: tuple[int, int, int]


@dataclass(frozen=True)
class Panel:
    """A rectangle facing the camera at depth z (a trunk, a branch, a jacket)."""

    x_m: tuple[float, float]
    y_m: tuple[float, float]
    z_m: float
    rgb: tuple[int, int, int]


def _render_view(
    spheres: Sequence[Sphere],
    panels: Sequence[Panel] = (),
    *,
    noise_m: float = 0.003,
    flying_fraction: float = 0.7,
    seed: int = 0,
) -> ViewCloud:
    """A 512x424 Kinect v2 view of spheres and panels before a foliage wall 6 m away, with depth noise and
    flying pixels: most silhouette pixels of a sphere take a depth between it and what lies behind, and
    keep the sphere's colour (the worst case for a colour mask)."""
    rng = np.random.default_rng(seed)
    rows, cols = np.mgrid[0:HEIGHT, 0:WIDTH]
    rays = np.stack([(cols - CX) / FX, (rows - CY) / FY, np.ones_like(cols, dtype=float)], axis=-1)
    depth = np.full((HEIGHT, WIDTH), 6.0)
    colors = np.empty((HEIGHT, WIDTH, 3), dtype=np.uint8)
    colors[...] = FOLIAGE
    sphere_id = np.full((HEIGHT, WIDTH), -1)
    for index, sphere in enumerate(spheres):
        centre = np.asarray(sphere.center_m)
        along = rays @ centre
        ray_sq = np.einsum("ijk,ijk->ij", rays, rays)
        disc = along**2 - ray_sq * (centre @ centre - sphere.radius_m**2)
        z = np.where(disc > 0, (along - np.sqrt(np.maximum(disc, 0.0))) / ray_sq, np.inf)
        nearer = z < depth
        depth[nearer], colors[nearer], sphere_id[nearer] = z[nearer], sphere.rgb, index
    for panel in panels:
        x, y = rays[..., 0] * panel.z_m, rays[..., 1] * panel.z_m
        inside = (x >= panel.x_m[0]) & (x <= panel.x_m[1]) & (y >= panel.y_m[0]) & (y <= panel.y_m[1])
        nearer = inside & (panel.z_m < depth)
        depth[nearer], colors[nearer], sphere_id[nearer] = panel.z_m, panel.rgb, -1
    depth = _add_flying_pixels(depth, sphere_id, flying_fraction, rng)
    depth = depth + rng.normal(0.0, noise_m, depth.shape)
    points = rays.reshape(-1, 3) * depth.reshape(-1, 1)
    return ViewCloud(
        view="views/1",
        points_m=points,
        colors_rgb=colors.reshape(-1, 3),
        has_color=np.ones(points.shape[0], dtype=bool),
        pixels=np.stack([rows.ravel(), cols.ravel()], axis=1),
    )


def _add_flying_pixels(
    depth: np.ndarray, sphere_id: np.ndarray, fraction: float, rng: np.random.Generator
) -> np.ndarray:
    flying = depth.copy()
    for axis in (0, 1):
        behind = np.maximum(np.roll(depth, 1, axis=axis), np.roll(depth, -1, axis=axis))
        rim = (sphere_id >= 0) & (behind > depth + 0.1) & (rng.random(depth.shape) < fraction)
        flying[rim] = depth[rim] + rng.uniform(0.0, 1.0, np.count_nonzero(rim)) * (behind[rim] - depth[rim])
    return flying


BALLS = [
    Sphere((-0.45, 0.55, 2.6), 0.05, RED),
    Sphere((0.3, 0.6, 3.4), 0.05, YELLOW),
    Sphere((0.5, 0.5, 2.2), 0.05, BLUE),
]
LOOK_ALIKES = [
    Sphere((-0.25, -0.2, 2.4), 0.038, RED),  # apples
    Sphere((-0.18, -0.15, 2.45), 0.035, RED),
    Sphere((-0.3, -0.1, 2.5), 0.04, RED),
    *[Sphere((0.1 + 0.07 * i, -0.5 + 0.05 * (i % 3), 3.0), 0.015, YELLOW) for i in range(8)],  # leaves
]
JACKET = Panel((0.9, 1.4), (-0.4, 0.3), 2.8, BLUE)
TRUNK = Panel((-0.08, 0.08), (-1.0, 1.2), 3.0, BARK)


def _error_m(fit: SphereFit, sphere: Sphere) -> float:
    return float(np.linalg.norm(fit.center_m - np.asarray(sphere.center_m)))


def test_detect_balls_finds_each_colour_among_apples_leaves_and_a_jacket() -> None:
    cloud = _render_view([*BALLS, *LOOK_ALIKES], [JACKET, TRUNK])

    fits = detect_balls(cloud, BallConfig())

    assert list(fits) == ["red", "yellow", "blue"]
    for color, ball in zip(fits, BALLS, strict=True):
        assert _error_m(fits[color], ball) < 0.003, color
        assert fits[color].radius_m == pytest.approx(0.05, abs=0.005)


def test_detect_ball_fits_a_ball_split_by_a_branch_in_front_of_it() -> None:
    ball = Sphere((0.0, 0.0, 2.5), 0.05, YELLOW)
    branch = Panel((-0.008, 0.008), (-1.0, 1.0), 2.0, BARK)
    whole = detect_ball(_render_view([ball], seed=1), "yellow", BallConfig())

    split = detect_ball(_render_view([ball], [branch], seed=1), "yellow", BallConfig())

    assert _error_m(split, ball) < 0.003
    assert split.points > 0.6 * whole.points  # both halves, less the branch's strip: one would be half


def test_detect_ball_finds_a_ball_seen_through_a_gap_in_the_foliage() -> None:
    ball = Sphere((0.2, 0.1, 3.0), 0.05, BLUE)
    leaves = Panel((0.1, 0.3), (0.1, 0.2), 2.6, FOLIAGE)  # hides the lower half

    fit = detect_ball(_render_view([ball], [leaves], seed=2), "blue", BallConfig())

    assert _error_m(fit, ball) < 0.004


def test_detect_ball_prefers_the_ball_to_a_nearer_apple_that_shows_more_points() -> None:
    ball = Sphere((0.3, 0.2, 3.6), 0.05, RED)
    apple = Sphere((-0.2, 0.1, 2.0), 0.042, RED)  # 16 % smaller, but three times the points

    fit = detect_ball(_render_view([ball, apple]), "red", BallConfig())

    assert _error_m(fit, ball) < 0.003


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("apart_m", [0.095, 0.105, 0.12])
def test_a_far_red_ball_half_in_grass_is_found_beside_a_red_apple_touching_it(
    seed: int, apart_m: float
) -> None:
    """The apple's votes outnumber the ball's few: one peak lands on the apple. The ball is what remains
    around the apple's sphere (before, it was missed in 11 of these 18 placements and seeds 0-5)."""
    ball = Sphere((0.0, 0.45, 3.9), 0.05, RED)
    apple = Sphere((-apart_m, 0.456, 3.85), 0.044, RED)
    grass = Panel((-0.02, 0.06), (0.43, 0.6), 3.8, FOLIAGE)  # hides the ball's lower right

    found = find_ball_candidates(_render_view([ball, apple], [grass], seed=seed, noise_m=0.005), BallConfig())

    balls = [
        c
        for c in found.candidates
        if c.objection("red", BallConfig()) is None and _error_m(c.fit, ball) < 0.01
    ]
    assert balls


# --- detection failures -------------------------------------------------------------------------------------


def _ball_not_found(cloud: ViewCloud, color: str, config: BallConfig) -> BallNotFound:
    with pytest.raises(BallNotFound) as caught:
        detect_ball(cloud, color, config)
    error = caught.value
    assert (error.view, error.color) == ("views/1", color)
    assert error.to_dict()["code"] == "ball_not_found"
    assert str(error).startswith(f"views/1: {color} ball: ")
    return error


def test_missing_colour_raises_ball_not_found_naming_view_and_colour() -> None:
    error = _ball_not_found(_render_view(BALLS[:2]), "blue", BallConfig())

    assert "no blue point" in error.message
    assert error.hint is not None and "calibration_balls.hsv.blue" in error.hint


def test_points_the_colour_camera_does_not_see_are_never_taken_for_the_ball() -> None:
    cloud = _render_view([Sphere((0.0, 0.0, 2.5), 0.05, RED)])
    unseen = ViewCloud(
        view=cloud.view,
        points_m=cloud.points_m,
        colors_rgb=cloud.colors_rgb,
        has_color=np.zeros(len(cloud), dtype=bool),
        pixels=cloud.pixels,
    )

    error = _ball_not_found(unseen, "red", BallConfig())

    assert "no red point" in error.message


def test_too_few_points_raises_ball_not_found_with_counts_found_and_needed() -> None:
    ball = Sphere((0.0, 0.0, 4.0), 0.05, YELLOW)  # about 9 pixels across

    error = _ball_not_found(_render_view([ball]), "yellow", BallConfig(min_points=100))

    assert re.search(r"too few yellow points: \d+ found, at least 100 needed", error.message)


def test_ball_far_from_the_configured_size_is_not_taken_and_the_hint_names_the_diameter() -> None:
    beach_ball = Sphere((0.0, 0.0, 2.5), 0.08, YELLOW)

    error = _ball_not_found(_render_view([beach_ball]), "yellow", BallConfig())

    assert re.search(r"no sphere of about 50 mm radius among the \d+ yellow points", error.message)
    assert error.hint is not None and "calibration_balls.diameter_m" in error.hint


def test_ball_a_fifth_too_large_is_refused_for_its_fitted_radius() -> None:
    ball = Sphere((0.0, 0.0, 2.5), 0.063, YELLOW)

    error = _ball_not_found(_render_view([ball]), "yellow", BallConfig(max_radius_error=0.15))

    assert re.search(r"fitted radius 6\d mm, expected 50 mm \(more than 15% off\)", error.message)


def test_small_apple_alone_is_refused_for_its_radius() -> None:
    apple = Sphere((0.0, 0.0, 2.5), 0.035, RED)

    error = _ball_not_found(_render_view([apple]), "red", BallConfig())

    assert re.search(r"fitted radius 3\d mm, expected 50 mm \(more than 25% off\)", error.message)


def test_mostly_hidden_ball_is_not_taken_and_the_error_says_what_was_seen() -> None:
    ball = Sphere((0.0, 0.0, 2.0), 0.05, YELLOW)
    leaves = Panel((-0.3, 0.3), (-0.012, 0.5), 1.6, FOLIAGE)  # leaves the top quarter of the ball in view

    error = _ball_not_found(_render_view([ball], [leaves]), "yellow", BallConfig())

    assert re.search(
        r"too few points on a sphere: \d+ found, where a ball 2.0 m away would show about \d+", error.message
    ) or re.search(r"no sphere of about 50 mm radius among the \d+ yellow points", error.message)


def test_noisy_ball_raises_ball_not_found_for_its_residual() -> None:
    ball = Sphere((0.0, 0.0, 2.5), 0.05, YELLOW)

    error = _ball_not_found(_render_view([ball], noise_m=0.004), "yellow", BallConfig(max_rms_m=0.002))

    assert "residual" in error.message and "exceeds 2.0 mm" in error.message


@pytest.mark.parametrize("distance_m", [2.0, 5.5])
def test_flat_patch_of_the_ball_colour_is_not_a_ball(distance_m: float) -> None:
    patch = Panel((-0.06, 0.06), (-0.06, 0.06), distance_m, BLUE)

    error = _ball_not_found(_render_view([], [patch]), "blue", BallConfig())

    assert re.search(r"no sphere of about 50 mm radius among the \d+ blue points", error.message) or (
        "fitted radius 100 mm, expected 50 mm" in error.message
    )


@pytest.mark.parametrize("seed", [0, 2, 4])
def test_cluster_of_yellow_leaves_is_not_a_ball(seed: int) -> None:
    rng = np.random.default_rng(seed)
    middle = np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.3, 0.3), rng.uniform(2.0, 4.0)])
    leaves = [
        Sphere(tuple(middle + rng.normal(0.0, 0.04, 3)), rng.uniform(0.01, 0.02), YELLOW) for _ in range(40)
    ]

    error = _ball_not_found(_render_view(leaves, seed=seed), "yellow", BallConfig())

    assert re.search(r"no sphere of about 50 mm radius among the \d+ yellow points", error.message) or (
        "of the points seen through the fitted sphere's outline lie on it" in error.message
    )


def test_a_large_area_of_the_ball_colour_alone_is_not_a_ball() -> None:
    jacket = Panel((-0.3, 0.3), (-0.4, 0.4), 2.5, BLUE)

    error = _ball_not_found(_render_view([], [jacket]), "blue", BallConfig())

    assert re.search(r"no sphere of about 50 mm radius among the \d{4,} blue points", error.message)


def test_a_sphere_that_shows_what_lies_behind_it_scores_below_a_solid_one() -> None:
    """Two spheres alike in points, radius, residual and colour: the one through whose outline a third of the
    points seen lie behind its surface (a fallen apple and the ground beyond it, fitted as one sphere)
    scores below the one that hides what is behind it, as a solid ball does, in proportion."""
    solid = SphereFit(np.array([0.0, 1.2, 3.5]), 0.048, 70, 0.004, 0.96)
    hollow = replace(solid, coverage=0.64)
    scores = {"red": 1.0, "yellow": 0.0, "blue": 0.0}
    ball = BallCandidate(fit=solid, expected_points=70.0, color_scores=scores)
    look_alike = BallCandidate(fit=hollow, expected_points=70.0, color_scores=scores)
    assert look_alike.score("red", radius_m=0.05) == pytest.approx(
        ball.score("red", radius_m=0.05) * 0.64 / 0.96
    )


# --- real Kinect v2 frames ----------------------------------------------------------------------------------


@pytest.mark.skipif(not REAL_BALL_DATA.is_dir(), reason="real Kinect v2 ball frames not present")
@pytest.mark.parametrize("frame", REAL_FRAMES)
def test_real_kinect_ball_centre_within_10_mm_of_reference(frame: str) -> None:
    capture = load_capture(REAL_BALL_DATA / frame)
    balls = capture.manifest.calibration_balls
    config = BallConfig(diameter_m=balls.diameter_m, colors=balls.colors, hsv=balls.hsv)
    reference = json.loads((REAL_BALL_DATA / frame / "reference.json").read_text())

    fit = detect_balls(backproject(capture.views[0]), config)["yellow"]

    assert np.linalg.norm(fit.center_m - reference["center_m"]) < 0.010


# --- clutter that fooled the colour-first detector ----------------------------------------------------------

STRAW = (153, 134, 76)
"""Dry straw: the yellow ball's hue and nearly its saturation (HSV 45 deg, 0.5, 0.6)."""


def test_yellow_ball_lying_on_straw_of_its_colour_is_found() -> None:
    ball = Sphere((0.1, 0.4, 3.0), 0.05, YELLOW)
    straw = Panel((-0.4, 0.5), (0.3, 0.6), 3.03, STRAW)  # joined to the ball in the image, just behind it

    fit = detect_ball(_render_view([ball], [straw], seed=3), "yellow", BallConfig())

    assert _error_m(fit, ball) < 0.004


def test_ball_in_deep_shade_on_one_side_is_found_with_its_shaded_points() -> None:
    ball = Sphere((0.0, 0.3, 3.2), 0.05, YELLOW)
    cloud = _render_view([ball], seed=4)
    on_ball = np.linalg.norm(cloud.points_m - ball.center_m, axis=1) < 0.06
    shaded = on_ball & (cloud.points_m[:, 0] > ball.center_m[0] - 0.02)  # most of it, away from the sun
    colors = cloud.colors_rgb.copy()
    colors[shaded] = (colors[shaded] * 0.2).astype(np.uint8)  # value 46: below the yellow range's 70
    shade = ViewCloud(cloud.view, cloud.points_m, colors, cloud.has_color, cloud.pixels)

    fit = detect_ball(shade, "yellow", BallConfig())

    assert _error_m(fit, ball) < 0.004
    assert fit.points > 0.8 * np.count_nonzero(on_ball)


def test_balls_are_found_under_a_strong_white_balance_drift() -> None:
    cloud = _render_view([*BALLS, *LOOK_ALIKES], [JACKET, TRUNK], seed=5)
    gains = np.array([1.25, 1.0, 0.8])  # a warm cast, as automatic white balance under low sun gives
    warm = np.clip(cloud.colors_rgb * gains, 0, 255).astype(np.uint8)
    drifted = ViewCloud(cloud.view, cloud.points_m, warm, cloud.has_color, cloud.pixels)

    fits = detect_balls(drifted, BallConfig())

    for color, ball in zip(fits, BALLS, strict=True):
        assert _error_m(fits[color], ball) < 0.003, color


def test_a_post_as_thick_as_the_ball_and_of_its_colour_is_not_taken_for_it() -> None:
    ball = Sphere((0.3, 0.5, 3.0), 0.05, YELLOW)
    # A post seen as a column of small spheres of the ball's radius, 4 cm apart: a cylinder's surface.
    post = [Sphere((-0.5, y, 3.3), 0.05, STRAW) for y in np.arange(-1.0, 0.6, 0.04)]

    fit = detect_ball(_render_view([ball, *post], seed=6), "yellow", BallConfig())

    assert _error_m(fit, ball) < 0.003


def test_a_ball_wholly_in_deep_shade_keeps_its_colour() -> None:
    """Hard sun, the ball in a cast shadow: every pixel at a sixth of its brightness (value about 35, below
    the range's floor). Brightness says how it is lit, not what colour it is."""
    ball = Sphere((0.0, 0.3, 3.2), 0.05, YELLOW)
    cloud = _render_view([ball], seed=4)
    on_ball = np.linalg.norm(cloud.points_m - ball.center_m, axis=1) < 0.06
    colors = cloud.colors_rgb.copy()
    colors[on_ball] = (colors[on_ball] / 6).astype(np.uint8)
    shade = ViewCloud(cloud.view, cloud.points_m, colors, cloud.has_color, cloud.pixels)

    found = find_ball_candidates(shade, BallConfig())

    [candidate] = [c for c in found.candidates if _error_m(c.fit, ball) < 0.004]
    assert candidate.objection("yellow", BallConfig()) is None
    assert candidate.color_scores["yellow"] > 0.8


def test_the_red_ball_on_the_ground_is_found_below_a_crown_full_of_red_apples() -> None:
    """Thirty red apples hang nearer the camera and 1.2-1.6 m above the ground; their votes outnumber the
    far ball's. With the view's ground plane, the peaks resting on it are fitted first. (The miss this
    guards against was on a simulated capture, seed 2028030, where the ball was beyond the eight peaks
    tried; this synthetic scene alone is also found by the compact-group search, without the ground.)"""
    rng = np.random.default_rng(7)
    ball = Sphere((0.6, 0.45, 3.9), 0.05, RED)  # resting on the ground, the plane y = 0.5 (y down)
    apples = [
        Sphere((rng.uniform(-1.0, 1.0), rng.uniform(-1.1, -0.7), rng.uniform(2.6, 3.2)), 0.045, RED)
        for _ in range(30)
    ]
    cloud = _render_view([ball, *apples], seed=8)
    ground = GroundPlane(point_m=np.array([0.0, 0.5, 3.0]), normal=np.array([0.0, -1.0, 0.0]))

    found = find_ball_candidates(cloud, BallConfig(), ground=ground)

    assert any(_error_m(c.fit, ball) < 0.004 for c in found.candidates)
