"""Fitting a sphere of known radius to the visible side of a ball in one camera's points, robustly.

The camera sits at the origin looking along +z and sees only the near side of a ball: its centre lies
behind the visible surface, and points on the far side of a sphere (flying pixels strung behind the
silhouette) are never counted as its inliers. :func:`fit_sphere` is the whole fit; :func:`ransac_centre`,
:func:`refine_sphere` and :func:`sphere_inliers` are its steps, for the ball detector (``balls.py``), which
seeds them from its own candidates.
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["SphereFit", "fit_sphere", "ransac_centre", "refine_sphere", "sphere_coverage", "sphere_inliers"]

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
_NEWTON_STEPS = 50
"""Most Newton steps of one robust least-squares fit (a fit converges in 3-8)."""
_CONVERGED_M = 1e-7
"""A fit has converged when a step moves the sphere less than this, or no longer step downhill does."""


@dataclass(frozen=True)
class SphereFit:
    """A sphere (a calibration ball, or something taken for one) fitted in one view's depth-camera frame.

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
    center_covariance_m2
        Covariance of ``center_m`` for the known radius, square metres (from the residuals and the fit's
        Jacobian): millimetres for a ball seen whole, centimetres along the line of sight for a dozen noisy
        points on its cap; infinite when the points cannot fix the centre.
    radius_sd_m
        Standard error of ``radius_m``, metres: how well the inliers fix the free radius. A far ball's cap
        of a dozen noisy points hardly does (a sphere a centimetre larger, its centre a centimetre farther,
        fits them as well); infinite when they cannot fix it at all.
    coverage
        Fraction of the points seen through the sphere's outline, and not in front of it, that lie on it:
        near 1 for a solid ball, which hides what is behind it; low for a sphere across unrelated surfaces.
    """

    center_m: np.ndarray
    radius_m: float
    points: int
    rms_m: float
    coverage: float
    radius_sd_m: float = 0.0
    center_covariance_m2: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))

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
        Centre, radius, inlier count, RMS residual and coverage among the points given.

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
    centre = ransac_centre(points, radius_m, inlier_tolerance_m, iterations, rng)
    return refine_sphere(
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


def ransac_centre(
    points: np.ndarray, radius_m: float, tolerance_m: float, iterations: int, rng: np.random.Generator
) -> np.ndarray:
    """The MSAC-best centre over sphere hypotheses of the known radius through random point triples.

    Hypotheses are scored on at most ``_RANSAC_MAX_POINTS`` of the points, counting only points on the side
    of a sphere that faces the camera.

    Raises
    ------
    ValueError
        When no three of the points lie on a sphere of that radius.
    """
    if points.shape[0] > _RANSAC_MAX_POINTS:
        scored = points[rng.choice(points.shape[0], _RANSAC_MAX_POINTS, replace=False)]
    else:
        scored = points
    # Most triples of a cluttered blob fit no sphere of this radius; draw extra so that enough remain.
    drawn = rng.integers(0, scored.shape[0], size=(4 * iterations, 3))
    rows = np.ascontiguousarray(scored.T)
    centres = _far_centres(rows[:, drawn[:, 0]], rows[:, drawn[:, 1]], rows[:, drawn[:, 2]], radius_m)
    centres = centres[:iterations]
    if centres.shape[0] == 0:
        raise ValueError(f"no three points lie on a sphere of radius {radius_m} m")
    # Distances and facing through matrix products: |p - c|^2 = |p|^2 - 2 p.c + |c|^2, (p - c).p/|p|.
    norms = np.linalg.norm(scored, axis=1)
    dot = centres @ scored.T
    distance = np.sqrt(np.maximum(norms**2 - 2.0 * dot + np.sum(centres**2, axis=1)[:, None], 0.0))
    facing = norms - dot / norms < 0.0
    cost = np.where(facing, np.minimum((distance - radius_m) ** 2, tolerance_m**2), tolerance_m**2)
    return centres[np.argmin(cost.sum(axis=1))]


def _far_centres(a: np.ndarray, b: np.ndarray, c: np.ndarray, radius_m: float) -> np.ndarray:
    """Centres of the spheres of radius ``radius_m`` through the point triples ``a``, ``b``, ``c`` (``(3, K)``
    each: coordinates by row), the one farther from the camera, ``(M, 3)``; triples that no such sphere
    passes through, or collinear ones, are dropped.

    Worked on rows of coordinates: the same sums on ``(K, 3)`` arrays stride across memory and cost several
    times as much for the thousand triples of a fit.
    """
    u, v = b - a, c - a
    normal = _cross(u, v)
    normal_sq = _dot(normal, normal)
    kept = np.flatnonzero(normal_sq > 1e-18)
    u, v, a, normal = (each.take(kept, axis=1) for each in (u, v, a, normal))
    normal_sq = normal_sq[kept]
    to_circumcentre = (_dot(u, u) * _cross(v, normal) + _dot(v, v) * _cross(normal, u)) / (2.0 * normal_sq)
    height_sq = radius_m**2 - _dot(to_circumcentre, to_circumcentre)
    kept = np.flatnonzero(height_sq >= 0.0)
    circumcentre = a.take(kept, axis=1) + to_circumcentre.take(kept, axis=1)
    height_sq = height_sq[kept]
    unit_normal = normal.take(kept, axis=1) / np.sqrt(normal_sq[kept])
    away = np.where(_dot(unit_normal, circumcentre) >= 0.0, 1.0, -1.0)
    return (circumcentre + away * np.sqrt(height_sq) * unit_normal).T


def _dot(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Dot products of the columns of two ``(3, K)`` arrays, ``(K,)``."""
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Cross products of the columns of two ``(3, K)`` arrays, ``(3, K)``."""
    return np.stack([u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]])


def sphere_inliers(
    points: np.ndarray, sphere: np.ndarray, tolerance_m: float, *, minimum: int = 4
) -> np.ndarray:
    """Mask of the points within ``tolerance_m`` of the sphere ``[x, y, z, r]``, on its side facing the
    camera (a visible surface's normal points towards the camera).

    Raises
    ------
    ValueError
        When fewer than ``minimum`` points are inliers (four fix a sphere).
    """
    offsets = points - sphere[:3]
    distance = np.linalg.norm(offsets, axis=1)
    facing = np.einsum("ij,ij->i", offsets, points) < 0.0
    mask = (np.abs(distance - sphere[3]) < tolerance_m) & facing
    if np.count_nonzero(mask) < minimum:
        raise ValueError(
            f"only {np.count_nonzero(mask)} of {points.shape[0]} points lie within {tolerance_m} m of the "
            f"sphere; at least {minimum} are needed"
        )
    return mask


def refine_sphere(
    points: np.ndarray,
    centre: np.ndarray,
    radius_m: float,
    *,
    nominal_radius_m: float,
    tolerance_m: float,
    scene_m: np.ndarray,
) -> SphereFit:
    """Refine a start sphere on ``points`` and describe the result.

    Parameters
    ----------
    points
        ``(N, 3)`` points the inliers are chosen from, camera frame.
    centre, radius_m
        The start sphere.
    nominal_radius_m
        The ball's known radius, held softly (``_RADIUS_PRIOR``).
    tolerance_m
        Inlier distance from the surface.
    scene_m
        Every point seen around the sphere (or ``points`` themselves), for its coverage.

    Returns
    -------
    SphereFit
        The fit.

    Raises
    ------
    ValueError
        When the sphere keeps fewer than four inliers.
    """
    sphere, mask = _converge(points, np.append(centre, radius_m), nominal_radius_m, tolerance_m)
    inliers = points[mask]
    free = _least_squares_sphere(
        inliers[:: _stride(inliers.shape[0])],
        sphere,
        nominal_radius_m=nominal_radius_m,
        tolerance_m=tolerance_m,
        prior_weight=0.0,
    )
    distances = np.linalg.norm(inliers - sphere[:3], axis=1)
    fit = SphereFit(
        center_m=sphere[:3],
        radius_m=float(free[3]),
        points=int(distances.size),
        rms_m=float(np.sqrt(np.mean((distances - sphere[3]) ** 2))),
        coverage=sphere_coverage(scene_m, free, tolerance_m),
        radius_sd_m=_radius_sd(inliers, free),
        center_covariance_m2=_center_covariance(inliers, sphere),
    )
    return fit


def _center_covariance(points: np.ndarray, sphere: np.ndarray) -> np.ndarray:
    """Covariance of the centre of ``sphere`` ``[x, y, z, r]`` fitted to ``points`` with its radius known."""
    return _fit_covariance(points, sphere, free_radius=False)


def _radius_sd(points: np.ndarray, sphere: np.ndarray) -> float:
    """Standard error of the radius of ``sphere`` ``[x, y, z, r]`` fitted freely to ``points``."""
    return float(np.sqrt(max(_fit_covariance(points, sphere, free_radius=True)[3, 3], 0.0)))


def _fit_covariance(points: np.ndarray, sphere: np.ndarray, *, free_radius: bool) -> np.ndarray:
    """The linearised covariance of a least-squares sphere fit to ``points``: the residuals' variance times
    the inverse normal matrix of the Jacobian of the distances to the surface, over the centre and, when
    ``free_radius``, the radius. Infinite when the points cannot fix those parameters."""
    parameters = 4 if free_radius else 3
    if points.shape[0] <= parameters:
        return np.full((parameters, parameters), np.inf)
    offsets = points - sphere[:3]
    distance = np.linalg.norm(offsets, axis=1)
    jacobian = -offsets / distance[:, None]
    if free_radius:
        jacobian = np.column_stack([jacobian, -np.ones(points.shape[0])])
    variance = float(np.sum((distance - sphere[3]) ** 2)) / (points.shape[0] - parameters)
    try:
        return variance * np.linalg.inv(jacobian.T @ jacobian)
    except np.linalg.LinAlgError:
        return np.full((parameters, parameters), np.inf)


def _converge(
    points: np.ndarray, sphere: np.ndarray, nominal_radius_m: float, tolerance_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Robust least squares from a start sphere, re-selecting the inliers of the last sphere each round until
    they repeat (converged, or flipping between two sets) or the rounds run out.

    Returns
    -------
    tuple of numpy.ndarray
        The sphere ``[x, y, z, r]`` and the mask of its inliers over ``points``.
    """
    mask = sphere_inliers(points, sphere, tolerance_m)
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
        mask = sphere_inliers(points, sphere, tolerance_m)
        if np.packbits(mask).tobytes() in seen:
            break
    return sphere, mask


def _stride(count: int) -> int:
    """The step that thins ``count`` points to at most ``_LEAST_SQUARES_MAX_POINTS``."""
    return int(np.ceil(count / _LEAST_SQUARES_MAX_POINTS))


def sphere_coverage(scene_m: np.ndarray, sphere: np.ndarray, tolerance_m: float) -> float:
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
    The radius is held within a factor two of the nominal one, so that a flat patch cannot run off to
    an infinite sphere; such a fit is then refused for its radius.

    Solved by Newton's method on the loss itself. With residuals f (the distances to the surface, and the
    prior's), z = (f / s)^2 and rho(z) = 2 (sqrt(1 + z) - 1), the gradient is J' rho'(z) f and the Hessian
    J' (1 + z)^(-3/2) J plus each distance's own curvature, rho'(z) f (I - u u') / |p - c| over the centre
    (u the unit direction from the centre to the point). Reweighted Gauss-Newton, which keeps only
    J' rho'(z) J, converges linearly, in 10-20 steps; Newton's steps converge in 3-8. Where the Hessian is
    not positive definite (far from a minimum) the Gauss-Newton step is taken instead; a step that would
    take the radius past its bound takes it to the bound, the centre solved for that radius, and a radius at
    its bound that the gradient pushes past stays there while the centre is solved alone. Each step is
    halved until the loss falls; a step shorter than ``_CONVERGED_M`` is not taken, nor its loss worked out:
    the fit has converged, and the sphere held is returned.
    """
    scale = tolerance_m / 2.0
    prior_slope = prior_weight * scale / (_RADIUS_PRIOR * nominal_radius_m)
    lowest, highest = nominal_radius_m / 2.0, nominal_radius_m * 2.0
    count = points.shape[0]
    jacobian = np.zeros((count + 1, 4))  # the distances' rows, then the prior's
    jacobian[:count, 3] = -1.0
    jacobian[count, 3] = prior_slope

    def residuals(sphere: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The residuals f, the offsets from the points to the centre, and their lengths (the directions
        are only worked out for the spheres stepped to, not for each halving tried)."""
        offsets = sphere[:3] - points
        lengths = np.maximum(np.sqrt(np.einsum("ij,ij->i", offsets, offsets)), 1e-12)
        values = np.empty(count + 1)
        np.subtract(lengths, sphere[3], out=values[:count])
        values[count] = prior_slope * (sphere[3] - nominal_radius_m)
        return values, offsets, lengths

    def loss(values: np.ndarray) -> tuple[float, np.ndarray]:
        """The loss, and 1 + z per residual (which the next step's weights need)."""
        spread = 1.0 + (values / scale) ** 2
        return float(np.sqrt(spread).sum()) - values.size, spread

    sphere = np.asarray(start, dtype=np.float64).copy()
    sphere[3] = np.clip(sphere[3], lowest, highest)
    values, offsets, lengths = residuals(sphere)
    current, spread = loss(values)
    for _ in range(_NEWTON_STEPS):
        slope = 1.0 / np.sqrt(spread)  # rho'(z)
        directions = offsets / lengths[:, None]
        jacobian[:count, :3] = directions
        weighted = jacobian.T * slope
        gradient = weighted @ values
        hessian = (weighted / spread) @ jacobian
        bend = slope[:count] * values[:count] / lengths
        hessian[:3, :3] -= (directions.T * bend) @ directions
        hessian[(0, 1, 2), (0, 1, 2)] += bend.sum()
        pushed_out = (sphere[3] <= lowest and gradient[3] > 0.0) or (
            sphere[3] >= highest and gradient[3] < 0.0
        )
        solved = 3 if pushed_out else 4
        step = np.zeros(4)
        try:
            step[:solved] = -np.linalg.solve(hessian[:solved, :solved], gradient[:solved])
            downhill = float(gradient @ step) < 0.0
        except np.linalg.LinAlgError:
            downhill = False
        matrix = hessian
        if not downhill:
            matrix = weighted @ jacobian  # Gauss-Newton's
            try:
                step[:solved] = -np.linalg.solve(matrix[:solved, :solved], gradient[:solved])
            except np.linalg.LinAlgError:
                break
        bound = None
        if not lowest <= sphere[3] + step[3] <= highest:
            # To the bound, the centre solved for that radius. Were the radius clamped alone, the centre's
            # step, sized for the whole radius step, would overshoot: the fit crept to the bound in dozens
            # of halved steps (a grass tuft's free fit: up to 117 loss evaluations, where 5-10 are usual).
            # Kept only when it goes downhill; else the radius is clamped as before.
            reach = highest if sphere[3] + step[3] > highest else lowest
            bounded = np.append(np.zeros(3), reach - sphere[3])
            with contextlib.suppress(np.linalg.LinAlgError):
                bounded[:3] = -np.linalg.solve(matrix[:3, :3], gradient[:3] + matrix[:3, 3] * bounded[3])
                if np.isfinite(bounded).all() and float(gradient @ bounded) < 0.0:
                    step, bound = bounded, reach
        while True:
            trial = sphere + step
            # The whole step to a bound lands on it exactly (the sum may miss it by a rounding).
            trial[3] = bound if bound is not None else min(max(trial[3], lowest), highest)
            bound = None
            if math.sqrt((trial - sphere) @ (trial - sphere)) < _CONVERGED_M:
                return sphere  # converged: no step downhill longer than that is left to find
            trial_values, trial_offsets, trial_lengths = residuals(trial)
            trial_loss, trial_spread = loss(trial_values)
            if trial_loss <= current:
                break
            step /= 2.0
        sphere, values, offsets, lengths = trial, trial_values, trial_offsets, trial_lengths
        current, spread = trial_loss, trial_spread
    return sphere
