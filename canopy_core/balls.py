"""Calibration ball detection: colour masks, blobs of ball-coloured pixels and robust known-radius sphere fits.

A ball is found in one view by its colour (an HSV range), grouped into blobs in the depth image, and each
plausible blob is fitted with a sphere of the ball's known radius (RANSAC, then robust least squares). The
camera sits at the origin looking along +z, so only the near side of a ball is seen: its centre lies behind the
visible surface, and points on the far side of a hypothesis (flying pixels strung behind the silhouette) are
never counted as its inliers.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from canopy_core.backproject import ViewCloud
from canopy_core.config import BallConfig
from canopy_core.errors import BallNotFound

__all__ = ["SphereFit", "color_mask", "detect_ball", "detect_balls", "fit_sphere"]

_RANSAC_MAX_POINTS = 1000
"""Hypotheses are scored on a random subset of at most this many points; inliers are then taken from all."""
_REFINE_ROUNDS = 2
"""Least-squares rounds, each re-selecting the inliers around the previous centre."""
_MAX_BLOBS = 12
"""At most this many of the largest plausible blobs of one colour are fitted (bounds the time per view)."""


@dataclass(frozen=True)
class SphereFit:
    """A calibration ball fitted in one view's depth-camera frame.

    Attributes
    ----------
    center_m
        Centre ``[x, y, z]``, metres, fitted with the ball's known radius.
    radius_m
        Radius of a free-radius fit to the same inliers, metres: a check on the ball's identity and size.
    points
        Inlier points the centre was fitted to.
    rms_m
        RMS distance of the inliers to the sphere of the known radius around ``center_m``, metres.
    candidates
        Points the fit chose its inliers from (the ball-coloured blob, or all the points given).
    """

    center_m: np.ndarray
    radius_m: float
    points: int
    rms_m: float
    candidates: int

    def to_dict(self) -> dict[str, Any]:
        """The fit as JSON-ready values: ``center_m`` ``[x, y, z]``, ``radius_m``, ``points``, ``rms_m``."""
        return {
            "center_m": [float(value) for value in self.center_m],
            "radius_m": float(self.radius_m),
            "points": int(self.points),
            "rms_m": float(self.rms_m),
        }


def fit_sphere(
    points_m: np.ndarray,
    *,
    radius_m: float,
    inlier_tolerance_m: float = 0.008,
    iterations: int = 300,
    rng: np.random.Generator | None = None,
) -> SphereFit:
    """Fit a sphere of known radius to the visible side of a ball, robustly.

    RANSAC draws three points at a time; each triple fixes two centres at the known radius, and the one
    farther from the camera is kept, since the camera (at the origin) sees the near side of the ball.
    Hypotheses are scored by MSAC (truncated squared distance), counting only points on the camera-facing
    side. The best centre is refined by robust least squares on its inliers with the radius fixed; a second
    fit with the radius free gives ``radius_m``.

    Parameters
    ----------
    points_m
        ``(N, 3)`` points in the camera frame, metres, N >= 4.
    radius_m
        The ball's known radius, metres.
    inlier_tolerance_m
        A point is an inlier when it lies within this distance of the sphere's surface.
    iterations
        RANSAC hypotheses scored.
    rng
        Random generator for the sampling; a fixed seed by default, so the fit is deterministic.

    Returns
    -------
    SphereFit
        The centre, free radius, inlier count and RMS residual (``candidates`` is N).

    Raises
    ------
    ValueError
        Input not ``(N, 3)``, fewer than four points, non-finite values, non-positive radius or tolerance,
        or fewer than four points lying on any sphere of that radius.
    """
    points = _checked_points(points_m)
    if not (np.isfinite(radius_m) and radius_m > 0.0):
        raise ValueError(f"radius_m must be positive and finite, got {radius_m}")
    if not (np.isfinite(inlier_tolerance_m) and inlier_tolerance_m > 0.0):
        raise ValueError(f"inlier_tolerance_m must be positive and finite, got {inlier_tolerance_m}")
    if iterations < 1:
        raise ValueError(f"iterations must be at least 1, got {iterations}")
    rng = np.random.default_rng(0) if rng is None else rng
    centre = _ransac_centre(points, radius_m, inlier_tolerance_m, iterations, rng)
    for _ in range(_REFINE_ROUNDS):
        inliers = points[_inlier_mask(points, centre, radius_m, inlier_tolerance_m)]
        if inliers.shape[0] < 4:
            raise ValueError(
                f"only {inliers.shape[0]} of {points.shape[0]} points lie within "
                f"{inlier_tolerance_m} m of a sphere of radius {radius_m} m; at least 4 are needed"
            )
        centre = _refine_centre(inliers, centre, radius_m, inlier_tolerance_m)
    residuals = np.linalg.norm(inliers - centre, axis=1) - radius_m
    return SphereFit(
        center_m=centre,
        radius_m=_free_radius(inliers, centre, radius_m, inlier_tolerance_m),
        points=int(inliers.shape[0]),
        rms_m=float(np.sqrt(np.mean(residuals**2))),
        candidates=int(points.shape[0]),
    )


def _checked_points(points_m: np.ndarray) -> np.ndarray:
    points = np.asarray(points_m, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points_m must have shape (N, 3), got {points.shape}")
    if points.shape[0] < 4:
        raise ValueError(f"a sphere fit needs at least 4 points, got {points.shape[0]}")
    if not np.isfinite(points).all():
        raise ValueError("points_m holds non-finite values")
    return points


def _ransac_centre(
    points: np.ndarray, radius_m: float, tolerance_m: float, iterations: int, rng: np.random.Generator
) -> np.ndarray:
    """The MSAC-best centre over sphere hypotheses of the known radius through random point triples."""
    if points.shape[0] > _RANSAC_MAX_POINTS:
        scored = points[rng.choice(points.shape[0], _RANSAC_MAX_POINTS, replace=False)]
    else:
        scored = points
    # Most triples of a cluttered blob fit no sphere of this radius; draw extra so enough remain.
    triples = scored[rng.integers(0, scored.shape[0], size=(4 * iterations, 3))]
    centres = _far_centres(triples, radius_m)[:iterations]
    if centres.shape[0] == 0:
        return _algebraic_centre(points)
    cost = np.full((centres.shape[0], scored.shape[0]), tolerance_m**2)
    offsets = scored[None, :, :] - centres[:, None, :]
    distance = np.abs(np.linalg.norm(offsets, axis=2) - radius_m)
    facing = _facing_camera(offsets, scored)
    cost[facing] = np.minimum(distance[facing] ** 2, tolerance_m**2)
    return centres[np.argmin(cost.sum(axis=1))]


def _far_centres(triples: np.ndarray, radius_m: float) -> np.ndarray:
    """For each ``(3, 3)`` point triple, the centre of the radius-``radius_m`` sphere through it that lies
    farther from the camera; triples that no such sphere passes through (or collinear ones) are dropped."""
    a, b, c = triples[:, 0], triples[:, 1], triples[:, 2]
    u, v = b - a, c - a
    normal = np.cross(u, v)
    normal_sq = np.einsum("ij,ij->i", normal, normal)
    ok = normal_sq > 1e-18
    u, v, a, normal, normal_sq = u[ok], v[ok], a[ok], normal[ok], normal_sq[ok]
    to_circumcentre = (
        np.einsum("ij,ij->i", u, u)[:, None] * np.cross(v, normal)
        + np.einsum("ij,ij->i", v, v)[:, None] * np.cross(normal, u)
    ) / (2.0 * normal_sq[:, None])
    height_sq = radius_m**2 - np.einsum("ij,ij->i", to_circumcentre, to_circumcentre)
    ok = height_sq >= 0.0
    circumcentre = a[ok] + to_circumcentre[ok]
    unit_normal = normal[ok] / np.sqrt(normal_sq[ok])[:, None]
    away = np.sign(np.einsum("ij,ij->i", unit_normal, circumcentre))
    return circumcentre + (away * np.sqrt(height_sq[ok]))[:, None] * unit_normal


def _algebraic_centre(points: np.ndarray) -> np.ndarray:
    """Linear least-squares sphere centre (|p|^2 = 2 p.c + k), a start when no triple fits the radius."""
    design = np.column_stack([2.0 * points, np.ones(points.shape[0])])
    solution, *_ = np.linalg.lstsq(design, np.einsum("ij,ij->i", points, points), rcond=None)
    return solution[:3]


def _facing_camera(offsets: np.ndarray, points: np.ndarray) -> np.ndarray:
    """True where the surface normal (point minus centre) does not point away from the camera.

    The tolerance of a few millimetres admits grazing points at the silhouette.
    """
    rays = points / np.linalg.norm(points, axis=-1, keepdims=True)
    return np.einsum("...j,...j->...", offsets, np.broadcast_to(rays, offsets.shape)) < 0.0


def _inlier_mask(points: np.ndarray, centre: np.ndarray, radius_m: float, tolerance_m: float) -> np.ndarray:
    offsets = points - centre
    distance = np.abs(np.linalg.norm(offsets, axis=1) - radius_m)
    return (distance < tolerance_m) & _facing_camera(offsets, points)


def _refine_centre(points: np.ndarray, centre: np.ndarray, radius_m: float, tolerance_m: float) -> np.ndarray:
    """Robust least-squares centre of a sphere of fixed radius through ``points``."""

    def residuals(c: np.ndarray) -> np.ndarray:
        return np.linalg.norm(points - c, axis=1) - radius_m

    def jacobian(c: np.ndarray) -> np.ndarray:
        offsets = points - c
        return -offsets / np.linalg.norm(offsets, axis=1, keepdims=True)

    result = least_squares(residuals, centre, jac=jacobian, loss="soft_l1", f_scale=tolerance_m / 2.0)
    return np.asarray(result.x, dtype=np.float64)


def _free_radius(points: np.ndarray, centre: np.ndarray, radius_m: float, tolerance_m: float) -> float:
    """Radius of a robust least-squares sphere with free centre and radius, started from the fixed fit."""

    def residuals(params: np.ndarray) -> np.ndarray:
        return np.linalg.norm(points - params[:3], axis=1) - params[3]

    def jacobian(params: np.ndarray) -> np.ndarray:
        offsets = points - params[:3]
        return np.column_stack(
            [-offsets / np.linalg.norm(offsets, axis=1, keepdims=True), -np.ones(points.shape[0])]
        )

    start = np.append(centre, radius_m)
    result = least_squares(residuals, start, jac=jacobian, loss="soft_l1", f_scale=tolerance_m / 2.0)
    return float(result.x[3])


def color_mask(colors_rgb: np.ndarray, hsv_range: list[list[int]]) -> np.ndarray:
    """Which colours lie within an HSV range.

    Parameters
    ----------
    colors_rgb
        ``(N, 3)`` uint8 RGB colours.
    hsv_range
        ``[[h, s, v], [h, s, v]]``, inclusive lower and upper bounds on OpenCV's scale (H 0-180, S and V
        0-255). A lower hue above the upper hue wraps round through 0 (red: ``[[170, ...], [10, ...]]``).

    Returns
    -------
    numpy.ndarray
        ``(N,)`` boolean mask.
    """
    return _hsv_mask(_to_hsv(colors_rgb), hsv_range)


def _to_hsv(colors_rgb: np.ndarray) -> np.ndarray:
    colors = np.ascontiguousarray(colors_rgb, dtype=np.uint8)
    if colors.ndim != 2 or colors.shape[1] != 3:
        raise ValueError(f"colors_rgb must have shape (N, 3), got {colors.shape}")
    if colors.shape[0] == 0:
        return colors.copy()
    return cv2.cvtColor(colors[:, None, :], cv2.COLOR_RGB2HSV).reshape(-1, 3)


def _hsv_mask(hsv: np.ndarray, hsv_range: list[list[int]]) -> np.ndarray:
    (h_low, s_low, v_low), (h_high, s_high, v_high) = hsv_range
    hue, saturation, value = hsv[:, 0], hsv[:, 1], hsv[:, 2]
    if h_low <= h_high:
        hue_ok = (hue >= h_low) & (hue <= h_high)
    else:
        hue_ok = (hue >= h_low) | (hue <= h_high)
    return hue_ok & (saturation >= s_low) & (saturation <= s_high) & (value >= v_low) & (value <= v_high)


def detect_balls(cloud: ViewCloud, config: BallConfig) -> dict[str, SphereFit]:
    """Find every calibration ball of ``config.colors`` in one view.

    Parameters
    ----------
    cloud
        The view's back-projected points (unfiltered: the fit copes with flying pixels itself).
    config
        Ball size, colours and detection thresholds.

    Returns
    -------
    dict[str, SphereFit]
        The fit of each colour, in ``config.colors`` order.

    Raises
    ------
    BallNotFound
        For the first colour whose ball is missing or implausible, naming the view and colour.
    """
    hsv = _to_hsv(cloud.colors_rgb)
    return {color: _detect(cloud, hsv, color, config) for color in config.colors}


def detect_ball(cloud: ViewCloud, color: str, config: BallConfig) -> SphereFit:
    """Find the calibration ball of one colour in one view.

    Points of the ball's colour are grouped into blobs (neighbouring depth pixels without a depth jump);
    each blob with enough points and at least a ball radius across is fitted with :func:`fit_sphere`, and
    the fit with most inliers whose free radius and residual are plausible is kept, then refitted to every
    point of that colour on its sphere (so a ball split by a branch in front of it is fitted whole).

    Parameters
    ----------
    cloud
        The view's back-projected points.
    color
        A colour name of ``config.colors`` (or any with an HSV range in ``config``).
    config
        Ball size, HSV ranges and detection thresholds.

    Returns
    -------
    SphereFit
        The ball's centre in the view's depth-camera frame.

    Raises
    ------
    BallNotFound
        No point of that colour; too few of them together; the best sphere's radius or residual is
        implausible.
    """
    return _detect(cloud, _to_hsv(cloud.colors_rgb), color, config)


@dataclass(frozen=True)
class _Blob:
    points_m: np.ndarray
    width_m: float


def _detect(cloud: ViewCloud, hsv: np.ndarray, color: str, config: BallConfig) -> SphereFit:
    hsv_range = config.hsv_range(color)
    selected = cloud.has_color & _hsv_mask(hsv, hsv_range)
    count = int(np.count_nonzero(selected))
    if count == 0:
        raise BallNotFound(
            f"no {color} point in the view (HSV range {hsv_range})",
            view=cloud.view,
            color=color,
            hint=f"Check that the ball is in view and lit, or adjust calibration_balls.hsv.{color}",
        )
    candidates = cloud.points_m[selected]
    blobs = _blobs(candidates, cloud.pixels[selected], max_depth_step_m=config.radius_m)
    _require_plausible_blob(blobs, count, cloud.view, color, config)
    fits = [fit for blob in _plausible(blobs, config)[:_MAX_BLOBS] if (fit := _fit_blob(blob, config))]
    best = _choose(fits, cloud.view, color, config)
    return _refit_on_sphere(best, candidates, config)


def _blobs(points_m: np.ndarray, pixels: np.ndarray, *, max_depth_step_m: float) -> list[_Blob]:
    """Connected groups of pixels (8-neighbourhood) whose neighbours differ in depth by less than a step."""
    width = int(pixels[:, 1].max()) + 2
    keys = pixels[:, 0].astype(np.int64) * width + pixels[:, 1]
    order = np.argsort(keys)
    sorted_keys = keys[order]
    depth = points_m[:, 2]
    sources, targets = [], []
    for offset in (1, width - 1, width, width + 1):
        position = np.minimum(np.searchsorted(sorted_keys, keys + offset), keys.size - 1)
        neighbour = order[position]
        linked = (sorted_keys[position] == keys + offset) & (np.abs(depth[neighbour] - depth) < max_depth_step_m)
        sources.append(np.flatnonzero(linked))
        targets.append(neighbour[linked])
    source, target = np.concatenate(sources), np.concatenate(targets)
    graph = coo_matrix((np.ones(source.size, dtype=np.int8), (source, target)), shape=(keys.size, keys.size))
    _, labels = connected_components(graph, directed=False)
    by_label = np.argsort(labels, kind="stable")
    splits = np.flatnonzero(np.diff(labels[by_label])) + 1
    return [_blob(points_m[group]) for group in np.split(by_label, splits)]


def _blob(points_m: np.ndarray) -> _Blob:
    """A blob with its width across the line of sight (largest image-plane extent at its median depth)."""
    bearings = points_m[:, :2] / points_m[:, 2:3]
    extent = bearings.max(axis=0) - bearings.min(axis=0)
    return _Blob(points_m=points_m, width_m=float(extent.max() * np.median(points_m[:, 2])))


def _plausible(blobs: list[_Blob], config: BallConfig) -> list[_Blob]:
    """Blobs that could hold the ball, largest first: enough points and at least a radius across."""
    kept = [b for b in blobs if b.points_m.shape[0] >= config.min_points and b.width_m >= config.radius_m]
    return sorted(kept, key=lambda b: b.points_m.shape[0], reverse=True)


def _require_plausible_blob(blobs: list[_Blob], count: int, view: str, color: str, config: BallConfig) -> None:
    largest = max(blobs, key=lambda b: b.points_m.shape[0])
    if largest.points_m.shape[0] < config.min_points:
        raise BallNotFound(
            f"too few {color} points: {count} found, the largest group has {largest.points_m.shape[0]}, "
            f"at least {config.min_points} needed",
            view=view,
            color=color,
            hint="The ball may be hidden, too far or badly lit; move closer or lower balls.min_points",
        )
    if not _plausible(blobs, config):
        widest = max(blob.width_m for blob in blobs)
        raise BallNotFound(
            f"no group of {color} points is as wide as the ball: the widest is {widest * 1000:.0f} mm across, "
            f"the ball's radius is {config.radius_m * 1000:.0f} mm",
            view=view,
            color=color,
            hint="The ball may be mostly hidden; check balls.diameter_m and that the ball is in view",
        )


def _fit_blob(blob: _Blob, config: BallConfig) -> SphereFit | None:
    try:
        return fit_sphere(
            blob.points_m,
            radius_m=config.radius_m,
            inlier_tolerance_m=config.inlier_tolerance_m,
            iterations=config.ransac_iterations,
        )
    except ValueError:
        return None


def _radius_error(fit: SphereFit, config: BallConfig) -> float:
    return abs(fit.radius_m - config.radius_m) / config.radius_m


def _choose(fits: list[SphereFit], view: str, color: str, config: BallConfig) -> SphereFit:
    """The fit with most inliers among the plausible ones, or the reason the best one is not a ball."""
    plausible = [
        fit
        for fit in fits
        if fit.points >= config.min_points
        and _radius_error(fit, config) <= config.max_radius_error
        and fit.rms_m <= config.max_rms_m
    ]
    if plausible:
        return max(plausible, key=lambda fit: fit.points)
    if not fits:
        raise BallNotFound(
            f"no group of {color} points lies on a sphere of radius {config.radius_m * 1000:.0f} mm",
            view=view,
            color=color,
            hint="Something else of that colour may be in view; check balls.diameter_m",
        )
    best = max(fits, key=lambda fit: fit.points)
    if best.points < config.min_points:
        raise BallNotFound(
            f"too few {color} points on a sphere: {best.points} found, at least {config.min_points} needed",
            view=view,
            color=color,
            hint="The ball may be hidden, too far or badly lit; move closer or lower balls.min_points",
        )
    if _radius_error(best, config) > config.max_radius_error:
        raise BallNotFound(
            f"fitted radius {best.radius_m * 1000:.0f} mm, expected {config.radius_m * 1000:.0f} mm "
            f"(more than {config.max_radius_error:.0%} off)",
            view=view,
            color=color,
            hint="Another object of that colour may be taken for the ball; check balls.diameter_m and the HSV "
            "range",
        )
    raise BallNotFound(
        f"sphere fit residual {best.rms_m * 1000:.1f} mm exceeds {config.max_rms_m * 1000:.1f} mm",
        view=view,
        color=color,
        hint="The ball's surface is too noisy or partly hidden; move closer or raise balls.max_rms_m",
    )


def _refit_on_sphere(fit: SphereFit, candidates_m: np.ndarray, config: BallConfig) -> SphereFit:
    """Refine a blob's fit on every point of the colour near its sphere (fragments of a split ball)."""
    near = np.abs(np.linalg.norm(candidates_m - fit.center_m, axis=1) - config.radius_m) < (
        2.0 * config.inlier_tolerance_m
    )
    points = candidates_m[near]
    centre = fit.center_m
    for _ in range(_REFINE_ROUNDS):
        inliers = points[_inlier_mask(points, centre, config.radius_m, config.inlier_tolerance_m)]
        centre = _refine_centre(inliers, centre, config.radius_m, config.inlier_tolerance_m)
    residuals = np.linalg.norm(inliers - centre, axis=1) - config.radius_m
    return SphereFit(
        center_m=centre,
        radius_m=_free_radius(inliers, centre, config.radius_m, config.inlier_tolerance_m),
        points=int(inliers.shape[0]),
        rms_m=float(np.sqrt(np.mean(residuals**2))),
        candidates=int(points.shape[0]),
    )
