"""Calibration ball detection: colour masks, blobs of ball-coloured pixels and robust sphere fits.

A ball is found in one view by its colour (an HSV range); its points are grouped into blobs in the depth
image, blobs of a ball's size get a RANSAC sphere at the ball's known radius, and the likeliest is refined by
robust least squares and checked (:func:`detect_ball`). The camera sits at the origin looking along +z and
sees only the near side of a ball: its centre lies behind the visible surface, and points on the far side of
a sphere (flying pixels strung behind the silhouette) are never counted as its inliers.
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
_LEAST_SQUARES_MAX_POINTS = 2000
"""Each least-squares round uses at most this many inliers, evenly strided: enough for a sub-mm fit."""
_MAX_ROUNDS = 10
"""Least-squares rounds at most, each re-selecting the inliers of the last sphere."""
_RADIUS_PRIOR = 0.01
"""Relative spread of a ball's radius about the nominal one, as a soft prior of the centre's fit: it steadies
the radius (and so the centre's depth) of a small or partly seen ball; being inside the robust loss, it
gives way where thousands of points insist (the real 406 mm ball that Kinect v2 sees as 422 mm)."""
_RADIUS_SPREAD = 0.05
"""Relative spread of the radius a ball is seen with about its nominal one, for ranking candidates: the
diameter given may be a little off (a ball sold as 406 mm that Kinect v2 sees as 422 mm)."""
_MAX_BLOB_WIDTH_RADII = 6.0
"""A blob wider than this many ball radii is neither a ball nor a ball with a small thing touching it."""
_MAX_BLOBS = 12
"""At most this many of the largest ball-sized blobs of one colour are tried (bounds the time per view)."""
_MIN_COMPLETENESS = 0.3
"""Least fraction of the pixels a ball covers that must be inliers of its colour (balls seen whole in real
and simulated Kinect v2 views: 0.5 to 1; spheres through distant background surfaces: 0.25 or less)."""
_TOLERANCE_REFERENCE_RANGE_M = 3.0
"""Up to this range the configured inlier tolerance holds; beyond, it grows as range², like the depth noise
of a time-of-flight camera, so a far ball in sun is still fitted as a ball."""
_MIN_COVERAGE = 0.6
"""Least fraction of the points seen through a ball's outline that lie on it (balls: 0.7 to 1; spheres
through clusters of leaves of the ball's colour: 0.5 or less)."""


@dataclass(frozen=True)
class SphereFit:
    """A calibration ball fitted in one view's depth-camera frame.

    Attributes
    ----------
    center_m
        Centre ``[x, y, z]``, metres, fitted with the radius held softly to the known one.
    radius_m
        Radius of a free fit to the same inliers, metres: a check on the ball's identity and size.
    points
        Inlier points the sphere was fitted to.
    rms_m
        RMS distance of the inliers to the sphere the centre was fitted with, metres.
    candidates
        Points the inliers were chosen from (the ball-coloured points, or all the points given).
    coverage
        Fraction of the points seen through the sphere's outline, and not in front of it, that lie on it:
        near 1 for a solid ball, which hides what is behind it; low for a sphere across unrelated surfaces.
    """

    center_m: np.ndarray
    radius_m: float
    points: int
    rms_m: float
    candidates: int
    coverage: float

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
    """Fit a sphere to the visible side of a ball of known radius, robustly.

    RANSAC draws three points at a time; each triple fixes two centres at the known radius, and the one
    farther from the camera is kept, since the camera (at the origin, looking along +z) sees the near side of
    the ball. Hypotheses are scored by MSAC (truncated squared distance), counting only points on the side
    facing the camera, so flying pixels strung behind the silhouette never support a hypothesis. The best
    one is refined by robust least squares (soft-L1 loss), re-selecting its inliers each round until they
    repeat; the radius is held to the known one by a soft prior inside the same robust loss
    (``_RADIUS_PRIOR``), and a last fit with the radius free gives ``radius_m``.

    Why a soft prior: a radius that is wrong moves the centre along the line of sight by about as much. On
    the real Kinect v2 frames of a ball sold as 406 mm, which the sensor sees as 422 mm, centres fitted with
    the radius fixed at 203 mm lie a median 10 mm (max 13) from the data authors' reference, with it free
    2.0 mm (max 8.1), with the soft prior 1.8 mm (max 8.3). On simulated Kinect v2 views of 10 cm balls at
    2.5-4.7 m, whose mixed pixels at the rim shrink a free radius by about 6 % (up to 12 %), the free
    centres are 4.4 mm off (median; max 12), the fixed and the soft-prior ones 1.6 mm (max 6).

    Parameters
    ----------
    points_m
        ``(N, 3)`` points in the camera frame, metres, N >= 4.
    radius_m
        The ball's known (nominal) radius, metres.
    inlier_tolerance_m
        A point is an inlier when it lies within this distance of the sphere's surface.
    iterations
        RANSAC hypotheses scored.
    rng
        Random generator for the sampling; a fixed seed by default, so the fit is deterministic.

    Returns
    -------
    SphereFit
        Centre, radius, inlier count, RMS residual and coverage among the points given (``candidates`` N).

    Raises
    ------
    ValueError
        Points not ``(N, 3)``, fewer than four, or non-finite; radius, tolerance or iterations not positive;
        fewer than four points on any sphere near the known radius.
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
    return _refine(
        points, centre, radius_m, nominal_radius_m=radius_m, tolerance_m=inlier_tolerance_m, scene_m=points
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
    # Most triples of a cluttered blob fit no sphere of this radius; draw extra so that enough remain.
    triples = scored[rng.integers(0, scored.shape[0], size=(4 * iterations, 3))]
    centres = _far_centres(triples, radius_m)[:iterations]
    if centres.shape[0] == 0:
        raise ValueError(f"no three points lie on a sphere of radius {radius_m} m")
    # Distances and facing through matrix products: |p - c|^2 = |p|^2 - 2 p.c + |c|^2, (p - c).p/|p|.
    norms = np.linalg.norm(scored, axis=1)
    dot = centres @ scored.T
    distance = np.sqrt(np.maximum(norms**2 - 2.0 * dot + np.sum(centres**2, axis=1)[:, None], 0.0))
    facing = norms - dot / norms < 0.0
    cost = np.where(facing, np.minimum((distance - radius_m) ** 2, tolerance_m**2), tolerance_m**2)
    return centres[np.argmin(cost.sum(axis=1))]


def _far_centres(triples: np.ndarray, radius_m: float) -> np.ndarray:
    """Centres of the spheres of radius ``radius_m`` through point triples, the one farther from the camera.

    ``triples`` is ``(K, 3, 3)``; triples that no such sphere passes through, or collinear ones, are dropped.
    """
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
    away = np.where(np.einsum("ij,ij->i", unit_normal, circumcentre) >= 0.0, 1.0, -1.0)
    return circumcentre + (away * np.sqrt(height_sq[ok]))[:, None] * unit_normal


def _inliers(points: np.ndarray, sphere: np.ndarray, tolerance_m: float) -> np.ndarray:
    """Mask of the points within ``tolerance_m`` of the sphere ``[x, y, z, r]``, on its side facing the
    camera (a visible surface's normal points towards the camera).

    Raises
    ------
    ValueError
        When fewer than four points are inliers.
    """
    offsets = points - sphere[:3]
    distance = np.linalg.norm(offsets, axis=1)
    facing = np.einsum("ij,ij->i", offsets, points) < 0.0
    mask = (np.abs(distance - sphere[3]) < tolerance_m) & facing
    if np.count_nonzero(mask) < 4:
        raise ValueError(
            f"only {np.count_nonzero(mask)} of {points.shape[0]} points lie within {tolerance_m} m of the "
            f"sphere; at least 4 are needed"
        )
    return mask


def _refine(
    points: np.ndarray,
    centre: np.ndarray,
    radius_m: float,
    *,
    nominal_radius_m: float,
    tolerance_m: float,
    scene_m: np.ndarray,
) -> SphereFit:
    """Refine a start sphere on ``points`` and describe the result; ``scene_m`` (every point in view, or
    ``points`` themselves) gives its coverage."""
    sphere, inliers = _converge(points, np.append(centre, radius_m), nominal_radius_m, tolerance_m)
    free = _least_squares_sphere(
        inliers[:: _stride(inliers.shape[0])],
        sphere,
        nominal_radius_m=nominal_radius_m,
        tolerance_m=tolerance_m,
        prior_weight=0.0,
    )
    distances = np.linalg.norm(inliers - sphere[:3], axis=1)
    return SphereFit(
        center_m=sphere[:3],
        radius_m=float(free[3]),
        points=int(distances.size),
        rms_m=float(np.sqrt(np.mean((distances - sphere[3]) ** 2))),
        candidates=int(points.shape[0]),
        coverage=_coverage(scene_m, free, tolerance_m),
    )


def _converge(
    points: np.ndarray, sphere: np.ndarray, nominal_radius_m: float, tolerance_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Robust least squares from a start sphere, re-selecting the inliers of the last sphere each round until
    they repeat (converged, or flipping between two sets) or the rounds run out.

    Returns
    -------
    tuple of numpy.ndarray
        The sphere ``[x, y, z, r]`` and its inlier points.
    """
    mask = _inliers(points, sphere, tolerance_m)
    seen: set[bytes] = set()
    for _ in range(_MAX_ROUNDS):
        seen.add(np.packbits(mask).tobytes())
        stride = _stride(int(np.count_nonzero(mask)))
        sphere = _least_squares_sphere(
            points[mask][::stride],
            sphere,
            nominal_radius_m=nominal_radius_m,
            tolerance_m=tolerance_m,
            prior_weight=1.0 / np.sqrt(stride),
        )
        mask = _inliers(points, sphere, tolerance_m)
        if np.packbits(mask).tobytes() in seen:
            break
    return sphere, points[mask]


def _stride(count: int) -> int:
    """The step that thins ``count`` points to at most ``_LEAST_SQUARES_MAX_POINTS``."""
    return int(np.ceil(count / _LEAST_SQUARES_MAX_POINTS))


def _range_tolerance(tolerance_m: float, centre: np.ndarray) -> float:
    """The inlier tolerance for a ball at ``centre`` (camera frame): widened as range² past the reference."""
    return tolerance_m * max(1.0, (float(np.linalg.norm(centre)) / _TOLERANCE_REFERENCE_RANGE_M) ** 2)


def _coverage(scene_m: np.ndarray, sphere: np.ndarray, tolerance_m: float) -> float:
    """Fraction of the points seen through the sphere's outline, and not in front of it, that lie on it.

    A solid ball hides whatever is behind it, so nearly every point whose line of sight crosses its outline
    lies on its surface (or in front of it: an occluder); a sphere fitted across unrelated surfaces has many
    points behind its surface.
    """
    centre, radius_m = sphere[:3], sphere[3]
    distance = np.linalg.norm(scene_m, axis=1)
    closest = scene_m @ centre / distance  # along each line of sight, to its point nearest the centre
    discriminant = closest**2 - (centre @ centre - radius_m**2)
    through = discriminant > 0.0
    seen, distance = scene_m[through], distance[through]
    front = closest[through] - np.sqrt(discriminant[through])
    offsets = seen - centre
    on_sphere = (np.abs(np.linalg.norm(offsets, axis=1) - radius_m) < tolerance_m) & (
        np.einsum("ij,ij->i", offsets, seen) < 0.0
    )
    not_in_front = distance >= front - tolerance_m
    return int(np.count_nonzero(on_sphere & not_in_front)) / max(int(np.count_nonzero(not_in_front)), 1)


def _least_squares_sphere(
    points: np.ndarray, start: np.ndarray, *, nominal_radius_m: float, tolerance_m: float, prior_weight: float
) -> np.ndarray:
    """``[x, y, z, r]`` minimising the soft-L1 loss of the points' distances to the sphere and of the radius'
    departure from the nominal one (in units of ``_RADIUS_PRIOR``), all in one robust loss.

    ``prior_weight`` scales the prior down when the points are a 1-in-k sample of the inliers (1/sqrt(k)).
    The radius is bounded to within a factor two of the nominal one, so that a flat patch cannot run off to
    an infinite sphere; such a fit is then refused for its radius.
    """
    scale = tolerance_m / 2.0
    prior_slope = prior_weight * scale / (_RADIUS_PRIOR * nominal_radius_m)

    def residuals(sphere: np.ndarray) -> np.ndarray:
        distances = np.linalg.norm(points - sphere[:3], axis=1) - sphere[3]
        return np.append(distances, prior_slope * (sphere[3] - nominal_radius_m))

    def jacobian(sphere: np.ndarray) -> np.ndarray:
        offsets = points - sphere[:3]
        directions = offsets / np.linalg.norm(offsets, axis=1, keepdims=True)
        rows = np.column_stack([-directions, -np.ones(points.shape[0])])
        return np.vstack([rows, [0.0, 0.0, 0.0, prior_slope]])

    lower = np.array([-np.inf, -np.inf, -np.inf, nominal_radius_m / 2.0])
    upper = np.array([np.inf, np.inf, np.inf, nominal_radius_m * 2.0])
    result = least_squares(
        residuals,
        np.clip(start, lower, upper),
        jac=jacobian,
        bounds=(lower, upper),
        loss="soft_l1",
        f_scale=scale,
    )
    return np.asarray(result.x, dtype=np.float64)


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
    hue_ok = (hue >= h_low) & (hue <= h_high) if h_low <= h_high else (hue >= h_low) | (hue <= h_high)
    return hue_ok & (saturation >= s_low) & (saturation <= s_high) & (value >= v_low) & (value <= v_high)


def detect_balls(cloud: ViewCloud, config: BallConfig) -> dict[str, SphereFit]:
    """Find every calibration ball of ``config.colors`` in one view (see :func:`detect_ball`).

    Parameters
    ----------
    cloud
        The view's back-projected points, filtered or not (the fit copes with flying pixels itself).
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
    scene = _Scene.of(cloud)
    return {color: _detect(scene, color, config) for color in config.colors}


def detect_ball(cloud: ViewCloud, color: str, config: BallConfig) -> SphereFit:
    """Find the calibration ball of one colour in one view.

    Points of the ball's colour are grouped into blobs (neighbouring depth pixels without a depth jump) and
    the blobs of a ball's size get a RANSAC centre each. Seeds are tried likeliest first: those whose inliers
    fill most of the pixels a ball there would cover, and whose radius is nearest the ball's (apples differ
    mainly in size, and the nearer ones show more points, so a count of points would favour them). Each is
    refined on every point of the colour near its sphere (so a ball split by a branch in front of it is
    fitted whole), and the first that passes the checks is the ball: enough points for a ball at that
    distance, radius, residual, and coverage of its outline (a solid ball hides what is behind it).

    Parameters
    ----------
    cloud
        The view's back-projected points, filtered or not (the fit copes with flying pixels itself).
    color
        A colour name with an HSV range in ``config`` (its own or a default one).
    config
        Ball size, HSV ranges and detection thresholds.

    Returns
    -------
    SphereFit
        The ball, in the view's depth-camera frame.

    Raises
    ------
    BallNotFound
        No point of that colour; too few of them together; no group of them of a ball's size; or, for the
        likeliest sphere, too few points, or a radius, residual or coverage that is not a ball's.
    KeyError
        ``color`` has no HSV range.
    """
    return _detect(_Scene.of(cloud), color, config)


@dataclass(frozen=True)
class _Scene:
    """A view's points with what detection needs of them for every colour."""

    cloud: ViewCloud
    hsv: np.ndarray
    point_at_pixel: np.ndarray
    """Depth-image-shaped index of each pixel's point, -1 where none."""
    pixels_per_steradian: float
    """The depth camera's ``fx * fy``."""

    @classmethod
    def of(cls, cloud: ViewCloud) -> _Scene:
        rows, cols = cloud.pixels[:, 0], cloud.pixels[:, 1]
        shape = (int(rows.max()) + 1, int(cols.max()) + 1) if len(cloud) else (0, 0)
        point_at_pixel = np.full(shape, -1, dtype=np.int64)
        point_at_pixel[rows, cols] = np.arange(len(cloud))
        return cls(
            cloud=cloud,
            hsv=_to_hsv(cloud.colors_rgb),
            point_at_pixel=point_at_pixel,
            pixels_per_steradian=_pixels_per_steradian(cloud),
        )

    def pixels_of_ball(self, centre_m: np.ndarray, radius_m: float) -> float:
        """How many pixels a ball of this radius and centre covers in the image."""
        sine_sq = min((radius_m / float(np.linalg.norm(centre_m))) ** 2, 1.0)
        return 2.0 * np.pi * (1.0 - np.sqrt(1.0 - sine_sq)) * self.pixels_per_steradian

    def points_around(self, pixels: np.ndarray) -> np.ndarray:
        """The points in the pixels' bounding box, widened by half its size on every side."""
        low, high = pixels.min(axis=0), pixels.max(axis=0)
        margin = (high - low) // 2 + 2
        low, high = np.maximum(low - margin, 0), high + margin + 1
        window = self.point_at_pixel[low[0] : high[0], low[1] : high[1]]
        return self.cloud.points_m[window[window >= 0]]


def _pixels_per_steradian(cloud: ViewCloud) -> float:
    """The depth camera's ``fx * fy``, read back from its points (a pixel's column is ``fx x / z + cx``) at
    the two points farthest apart in columns, and in rows; NaN when the points span no row or column."""
    if len(cloud) == 0:
        return float("nan")
    product = np.float64(1.0)
    for axis, pixel_axis in ((0, 1), (1, 0)):
        ends = [np.argmin(cloud.pixels[:, pixel_axis]), np.argmax(cloud.pixels[:, pixel_axis])]
        bearings = cloud.points_m[ends, axis] / cloud.points_m[ends, 2]
        span_px = cloud.pixels[ends[1], pixel_axis] - cloud.pixels[ends[0], pixel_axis]
        with np.errstate(divide="ignore", invalid="ignore"):
            product *= span_px / (bearings[1] - bearings[0])
    return float(product)


def _detect(scene: _Scene, color: str, config: BallConfig) -> SphereFit:
    cloud = scene.cloud
    hsv_range = config.hsv_range(color)
    selected = np.flatnonzero(cloud.has_color & _hsv_mask(scene.hsv, hsv_range))
    if selected.size == 0:
        raise BallNotFound(
            f"no {color} point in the view (HSV range {hsv_range})",
            view=cloud.view,
            color=color,
            hint=f"Check that the ball is in view and lit, or adjust calibration_balls.hsv.{color}",
        )
    candidates = cloud.points_m[selected]
    blobs = _ball_sized_blobs(candidates, cloud.pixels[selected], cloud.view, color, config)
    first_rejection = None
    for centre, blob in _ranked_seeds(candidates, blobs, scene, config):
        try:
            fit = _refine(
                candidates,
                centre,
                config.radius_m,
                nominal_radius_m=config.radius_m,
                tolerance_m=_range_tolerance(config.inlier_tolerance_m, centre),
                scene_m=scene.points_around(cloud.pixels[selected[blob]]),
            )
        except ValueError:
            continue  # the seed's sphere lost its inliers
        rejection = _rejection(
            fit, color, config, ball_pixels=scene.pixels_of_ball(fit.center_m, config.radius_m)
        )
        if rejection is None:
            return fit
        first_rejection = first_rejection or rejection
    message, hint = first_rejection or (
        f"no group of {color} points lies on a sphere of about {config.radius_m * 1000:.0f} mm radius",
        "Something else of that colour may be in view; check balls.diameter_m and the HSV range",
    )
    raise BallNotFound(message, view=cloud.view, color=color, hint=hint)


def _ranked_seeds(
    candidates_m: np.ndarray, blobs: list[np.ndarray], scene: _Scene, config: BallConfig
) -> list[tuple[np.ndarray, np.ndarray]]:
    """RANSAC centres of the blobs, with their blobs, the likeliest ball first.

    A seed is as likely as the fraction of a ball's pixels its inliers fill (small things of the ball's
    colour fill few) times a Gaussian of its radius' relative error (``_RADIUS_SPREAD``; apples differ from
    the ball mainly in size, and the nearer ones fill as many pixels). The radius is that of a linear
    (algebraic) sphere fit to the seed's inliers: cheap, and close to the geometric fit's on inliers.
    """
    rng = np.random.default_rng(0)
    ranked: list[tuple[float, np.ndarray, np.ndarray]] = []
    for blob in blobs:
        points = candidates_m[blob]
        try:
            centre = _ransac_centre(
                points, config.radius_m, config.inlier_tolerance_m, config.ransac_iterations, rng
            )
            inliers = points[_inliers(points, np.append(centre, config.radius_m), config.inlier_tolerance_m)]
        except ValueError:
            continue  # no sphere of about the ball's radius in this blob
        completeness = inliers.shape[0] / scene.pixels_of_ball(centre, config.radius_m)
        radius_error = (_algebraic_radius(inliers) - config.radius_m) / config.radius_m
        ranked.append((completeness * np.exp(-0.5 * (radius_error / _RADIUS_SPREAD) ** 2), centre, blob))
    ranked.sort(key=lambda item: -item[0])
    return [(centre, blob) for _, centre, blob in ranked]


def _algebraic_radius(points_m: np.ndarray) -> float:
    """Radius of the linear least-squares sphere ``|p - m|^2 = 2 (p - m).c + k`` (m: the points' mean)."""
    centred = points_m - points_m.mean(axis=0)
    design = np.column_stack([2.0 * centred, np.ones(centred.shape[0])])
    solution, *_ = np.linalg.lstsq(design, np.einsum("ij,ij->i", centred, centred), rcond=None)
    return float(np.sqrt(max(solution[3] + solution[:3] @ solution[:3], 0.0)))


def _ball_sized_blobs(
    points_m: np.ndarray, pixels: np.ndarray, view: str, color: str, config: BallConfig
) -> list[np.ndarray]:
    """Indices of the largest blobs with enough points and about the size of a ball, largest first.

    A blob is a connected group of pixels (8-neighbourhood) whose neighbours differ in depth by less than
    the ball's radius, so a ball is not joined to a same-coloured object behind it. Its width is its largest
    extent across the line of sight, at its mean depth; a ball's blob is between one radius (mostly hidden)
    and ``_MAX_BLOB_WIDTH_RADII`` radii (with something of its colour touching it) across.

    Raises
    ------
    BallNotFound
        When no blob has enough points, or none of those has the size of a ball.
    """
    labels = _blob_labels(points_m, pixels, max_depth_step_m=config.radius_m)
    order = np.argsort(labels, kind="stable")
    sizes = np.bincount(labels)
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    if sizes.max() < config.min_points:
        raise BallNotFound(
            f"too few {color} points: {labels.size} found, at most {sizes.max()} of them together, "
            f"at least {config.min_points} needed",
            view=view,
            color=color,
            hint="The ball may be hidden, too far or badly lit; move closer or lower balls.min_points",
        )
    ordered = points_m[order]
    bearings = ordered[:, :2] / ordered[:, 2:3]
    extent = np.maximum.reduceat(bearings, starts, axis=0) - np.minimum.reduceat(bearings, starts, axis=0)
    width_m = extent.max(axis=1) * np.add.reduceat(ordered[:, 2], starts) / sizes
    eligible = sizes >= config.min_points
    narrowest_m, widest_m = config.radius_m, _MAX_BLOB_WIDTH_RADII * config.radius_m
    plausible = np.flatnonzero(eligible & (width_m >= narrowest_m) & (width_m <= widest_m))
    if plausible.size == 0:
        raise BallNotFound(
            f"no group of {color} points has the size of a ball ({narrowest_m * 1000:.0f} to "
            f"{widest_m * 1000:.0f} mm across): those of {config.min_points} points or more are "
            f"{width_m[eligible].min() * 1000:.0f} to {width_m[eligible].max() * 1000:.0f} mm across",
            view=view,
            color=color,
            hint="The ball may be mostly hidden, or something of its colour fills the view; check "
            "balls.diameter_m and the HSV range",
        )
    largest = plausible[np.argsort(sizes[plausible])[::-1][:_MAX_BLOBS]]
    return [order[starts[label] : starts[label] + sizes[label]] for label in largest]


def _blob_labels(points_m: np.ndarray, pixels: np.ndarray, *, max_depth_step_m: float) -> np.ndarray:
    """Connected-component label of each point over the 8-neighbourhood of its depth pixel."""
    width = int(pixels[:, 1].max()) + 2
    keys = pixels[:, 0].astype(np.int64) * width + pixels[:, 1]
    order = np.argsort(keys)
    sorted_keys = keys[order]
    depth = points_m[:, 2]
    sources, targets = [], []
    for offset in (1, width - 1, width, width + 1):
        position = np.minimum(np.searchsorted(sorted_keys, keys + offset), keys.size - 1)
        neighbour = order[position]
        smooth = np.abs(depth[neighbour] - depth) < max_depth_step_m
        linked = (sorted_keys[position] == keys + offset) & smooth
        sources.append(np.flatnonzero(linked))
        targets.append(neighbour[linked])
    source, target = np.concatenate(sources), np.concatenate(targets)
    graph = coo_matrix((np.ones(source.size, dtype=np.int8), (source, target)), shape=(keys.size, keys.size))
    return connected_components(graph, directed=False)[1]


def _rejection(
    fit: SphereFit, color: str, config: BallConfig, *, ball_pixels: float
) -> tuple[str, str] | None:
    """Why a fit is not taken for the ball (message and hint), or None when it is plausible.

    ``ball_pixels`` is the number of pixels a ball at the fit's centre would cover.
    """
    if fit.points < max(config.min_points, _MIN_COMPLETENESS * ball_pixels):
        return (
            f"too few {color} points on a sphere: {fit.points} found, where a ball "
            f"{np.linalg.norm(fit.center_m):.1f} m away would show about {ball_pixels:.0f} (at least "
            f"{max(config.min_points, int(np.ceil(_MIN_COMPLETENESS * ball_pixels)))} needed)",
            "The ball may be mostly hidden or badly lit, or something smaller of its colour was found",
        )
    if abs(fit.radius_m - config.radius_m) > config.max_radius_error * config.radius_m:
        return (
            f"fitted radius {fit.radius_m * 1000:.0f} mm, expected {config.radius_m * 1000:.0f} mm "
            f"(more than {config.max_radius_error:.0%} off)",
            "Something else of that colour may be taken for the ball; check balls.diameter_m",
        )
    if fit.rms_m > config.max_rms_m:
        return (
            f"sphere fit residual {fit.rms_m * 1000:.1f} mm exceeds {config.max_rms_m * 1000:.1f} mm",
            "The ball's surface is too noisy or partly hidden; move closer or raise balls.max_rms_m",
        )
    if fit.coverage < _MIN_COVERAGE:
        return (
            f"only {fit.coverage:.0%} of the points seen through the fitted sphere's outline lie on it, "
            f"where a ball shows nearly all: it spans unrelated surfaces, or the depth there is too noisy",
            "Something else of that colour may be in view, or the ball is too far for this light",
        )
    return None
