"""Calibration ball detection in one view: spheres found by their geometry, then told apart by their colour.

A calibration ball is a sphere of known radius. Every point whose colour is near a ball's (a soft colour
likelihood that tolerates shade and white-balance drift, :func:`color_likelihood`) votes for where the
centre of a sphere through it would lie: one radius behind it along its surface normal. The points of a
ball all vote for its centre, while a flat patch of the ball's colour (straw, soil, fallen leaves, a jacket)
spreads its votes over a plane and a cluster of leaves scatters them, so balls show as peaks of votes (a
Hough transform at the known radius) however much of their colour surrounds them, even joined to it in the
image. Each peak is fitted with a robust sphere on every point near it whatever its colour (a ball's
shaded side is still a ball) and described as a :class:`BallCandidate`: points for its range, radius,
residual, coverage of its outline, and how much of it has each ball's colour.

Which candidate is which ball is decided by :func:`canopy_core.ball_selection.select_balls`, jointly across
views (the balls' triangle is the same from every side) and on the ground; :func:`detect_balls` takes the
likeliest in one view alone.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import cv2
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from canopy_core.backproject import ViewCloud
from canopy_core.config import BallConfig
from canopy_core.errors import BallNotFound
from canopy_core.ground import GroundPlane, view_trunk_foot
from canopy_core.kdtree import point_tree
from canopy_core.normals import scatter_about_mean, scatter_normals
from canopy_core.spheres import SphereFit, ransac_centre, refine_sphere, sphere_coverage, sphere_inliers
from canopy_core.voxels import occupied_voxels

__all__ = [
    "BallCandidate",
    "Objection",
    "ViewBallCandidates",
    "color_likelihood",
    "color_mask",
    "detect_ball",
    "detect_balls",
    "find_ball_candidates",
]

_SATURATION_FALL = 3.0
"""Below the range's floor the saturation term falls as this power of the saturation's share of the floor:
bark and posts at 60-70 % of the red ball's floor saturation score 0.2-0.35, a ball in shade still 1."""
_SEED_LIKELIHOOD = 0.3
"""Points whose colour likelihood for some ball reaches this vote for sphere centres (a shaded or
white-balance-shifted ball pixel reaches 0.4 or more; the fit then takes every point near the sphere)."""
_NORMAL_BASELINE = 0.45
"""A point's normal comes from its neighbours this many ball radii away on each side: wide enough that depth
noise tilts it little, narrow enough that the sphere's curvature does not (a far 10 cm ball is 8 px wide)."""
_MAX_STEP_PX = 8
_NEIGHBOUR_OFFSETS = np.array([(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1)])
_MIN_NORMAL_NEIGHBOURS = 5
"""Fewest points of the window, on the same surface, that a normal is estimated from."""
_VOTE_RADIUS = 0.4
"""Votes within this many ball radii of one another count together: normals from 3x3 windows of Kinect
v2 points at 3-4 m err by 10-20 degrees, which moves a vote by 0.2-0.35 radii."""
_MIN_PEAK = 0.12
"""Least share of a ball's expected pixels that must vote for a centre for it to be tried (balls: 0.3 to
0.7; a flat patch at the same range: 0.15 or less)."""
_MIN_CONCENTRATION = 0.5
"""Least share of the votes within a radius of a peak that lie within ``_VOTE_RADIUS`` radii of it."""
_MAX_BLOB_DIAMETERS = 3.0
"""A group of a colour's pixels wider than this many ball diameters is not a ball seen alone."""
_VOTES_PER_BALL = 300.0
"""Votes are thinned to about this many per ball-sized area before they are counted (a far 10 cm ball gives
50-100, all kept; a near or large one thousands)."""
_MAX_PEAK_VOTES = 2000
"""At most this many of the strongest votes are weighed as peaks (each costs a neighbour query)."""
_MAX_PEAKS = 8
"""At most this many vote peaks per colour and view resting on the ground are fitted (bounds the time per
view); and compact groups of a colour."""
_MAX_FLOATING_PEAKS = 2
"""At most this many vote peaks above the ground are fitted per colour and view, after those on it: enough
to tell the crew that the likeliest sphere of a missing ball's colour hangs in the crown."""
_MAX_VOTE_PEAKS = 24
"""Vote peaks are taken, strongest first, up to this many before they are sorted by where they stand."""
_NEAR_RADII = 1.6
"""A peak's sphere is fitted to the points within this many radii of it (its centre is a few cm off)."""
_SURE_LIKELIHOOD = 0.9
"""Points near a peak with this likelihood of its colour or more surely have it and are fitted: within its
range or just outside it. (On the real Kinect v2 frames, fitting every point of likelihood 0.05 or more lets
the rim's mixed pixels pull the centre: 3.5 mm median error against 1.9.)"""
_MAYBE_LIKELIHOOD = 0.05
"""Points with this likelihood or more may be the ball's and count towards its points: a ball pixel in deep
shade keeps 0.1 or more, other colours, sky and bark about 0."""
_START_SHARE = 0.6
"""A RANSAC sphere with fewer than this share of the points a ball must show is not refined: refining
rarely gains more than a third of the inliers."""
_BESIDE_RADII = 3.0
"""A sphere touching another is looked for among the points within this many radii of the other's centre
(a ball's far side lies 3 radii from the centre of an apple or ball touching it)."""
_SUPPORT_SLACK = 2.0
"""Surface support counts points within this many inlier tolerances of a guessed sphere's surface: a guess a
centimetre off the centre still finds most of a ball's points."""
_SUPPORT_REACH_M = 0.05
"""Surface support looks this far beyond a guessed sphere's radius (more than the slack at any range)."""
_OUTLINE_RADII = 1.8
"""Coverage is judged on the pixels within this many projected radii of the fitted centre."""
_OVER_REACH_RADII = 1.3
_OVER_LOW_RADII = 1.4
_OVER_HIGH_RADII = 4.0
"""What stands right over a sphere (:meth:`_Scene.points_over`): within this many radii of its vertical
axis (a post's face lies about one radius in front of the centre fitted to its foot), from this many radii
above its centre (clear of the ball's own top and its noise) to this many (a post's face over a ball's
height and more; low weeds bend over a ball, they do not stand on it)."""
_RADIUS_SPREAD = 0.05
"""Relative spread of the radius a ball is seen with about its nominal one, for ranking candidates: the
diameter given may be a little off (a ball sold as 406 mm that Kinect v2 sees as 422 mm), and mixed pixels
at the rim shrink a small far ball by about 6 %; apples are 10-40 % smaller."""
_TOLERANCE_REFERENCE_RANGE_M = 3.0
"""Up to this range the configured inlier tolerance holds; beyond, it grows as range², like the depth noise
of a time-of-flight camera, so a far ball in sun is still fitted as a ball."""


@dataclass(frozen=True)
class Objection:
    """Why a sphere is not taken for a ball.

    ``code`` is one word for tools and pictures: ``points``, ``radius``, ``residual``, ``coverage`` (its
    geometry is not a ball's), ``colour`` (too little of the ball's colour) here, and ``floating``,
    ``upright``, ``taken``, ``inconsistent``, ``weaker``, ``missing`` (no sphere at all) from
    :mod:`canopy_core.ball_selection`; ``message`` says it in a sentence, ``hint`` what the crew can do
    about it.
    """

    code: str
    message: str
    hint: str | None = None


@dataclass(frozen=True)
class BallCandidate:
    """A sphere found in one view that may be a calibration ball.

    Attributes
    ----------
    fit
        The sphere, in the view's depth-camera frame.
    expected_points
        Pixels a ball of the nominal radius at the fitted centre covers.
    color_scores
        Per configured colour, the mean colour likelihood of the sphere's points that the colour camera
        sees, whatever their brightness (0: none has that colour, 1: all of them, fully): a ball in
        deep shade is still of its colour.
    problem
        Why the sphere's geometry is not a ball's (too few points, radius, residual, coverage), or None.
    unseen
        True for a ball this view does not show, placed where the other views put it
        (:meth:`ViewBallCandidates.hidden_ball_at`): its fit has no point, and its score is 0.
    """

    fit: SphereFit
    expected_points: float
    color_scores: dict[str, float]
    problem: Objection | None = None
    unseen: bool = False

    @property
    def completeness(self) -> float:
        """Points on the sphere over the pixels a ball there covers (about 0.5-1 for a ball seen whole)."""
        return self.fit.points / max(self.expected_points, 1.0)

    def score(self, color: str, *, radius_m: float) -> float:
        """How likely this is the ``color`` ball, in [0, 1]: completeness times a Gaussian of the radius's
        relative error times the colour score times the coverage of its outline.

        The Gaussian's spread is ``_RADIUS_SPREAD`` widened by the fit's relative residual: in hard sun the
        depth noise alone moves a small ball's free radius by 10-20 %, and it must not then lose to a
        cleaner sphere of the wrong size. The coverage weighs what the colour and the radius cannot: a
        solid ball hides what lies behind it, a sphere fitted across something else (a fallen apple and
        what lies round it) shows some of it through its outline. Without it, on mixed 2118004, a fallen
        red apple 85 mm across, which both views see and fit with a radius of 48-52 mm, outscored the red
        ball, which mixed pixels at its rim shrank to 45-46 mm.
        """
        radius_error = (self.fit.radius_m - radius_m) / radius_m
        spread = float(np.hypot(_RADIUS_SPREAD, self.fit.rms_m / radius_m))
        return (
            min(self.completeness, 1.0)
            * float(np.exp(-0.5 * (radius_error / spread) ** 2))
            * self.color_scores[color]
            * self.fit.coverage
        )

    def objection(self, color: str, config: BallConfig) -> Objection | None:
        """Why this is not the ``color`` ball: its geometry's problem, or too little of that colour."""
        if self.problem is not None:
            return self.problem
        if self.color_scores[color] < config.min_color_score:
            return Objection(
                "colour",
                f"a sphere {self.range_m:.1f} m away has too little of the {color} ball's colour "
                f"({self.color_scores[color]:.0%} of it, at least {config.min_color_score:.0%} needed)",
                f"Something else is there; if it is the ball, check calibration_balls.hsv.{color}",
            )
        return None

    @property
    def range_m(self) -> float:
        """Distance of the centre from the camera."""
        return float(np.linalg.norm(self.fit.center_m))


@dataclass(frozen=True)
class ViewBallCandidates:
    """The spheres found in one view, and per colour how many points had that colour at all."""

    view: str
    candidates: tuple[BallCandidate, ...]
    colored_points: dict[str, int]
    hsv_ranges: dict[str, list[list[int]]]
    scene: _Scene | None = field(default=None, repr=False, compare=False)
    """The view's points, for :meth:`sphere_near`."""
    ruled_out_m: tuple[np.ndarray, ...] = field(default=(), repr=False, compare=False)
    """Centres of spheres shown to be no ball (see :meth:`ruling_out`): none is sought there again."""

    def ruling_out(self, centre_m: np.ndarray, radius_m: float) -> ViewBallCandidates:
        """These spheres without any within ``radius_m`` of ``centre_m``, where no sphere is sought again:
        what the choice took for a ball there is a look-alike the views' surfaces contradicted, and a search
        where the other views place a ball would otherwise fit the same look-alike once more."""
        return replace(
            self,
            candidates=tuple(
                c for c in self.candidates if np.linalg.norm(c.fit.center_m - centre_m) >= radius_m
            ),
            ruled_out_m=(*self.ruled_out_m, np.asarray(centre_m, dtype=float)),
        )

    def sphere_near(self, estimate_m: np.ndarray, color: str, config: BallConfig) -> BallCandidate | None:
        """The sphere of the balls' radius near where the ``color`` ball is expected to be.

        For a ball the other views place here while this one found no sphere there (grass hiding most of
        it, deep shade, too few points for its normals to vote together): its points that may have its
        colour are fitted, or, if that fails, all its points whatever their colour (a ball in deep shade
        is nearly black); the sphere must pass the same geometric checks, but with less of it in view
        (``min_completeness_where_placed``: where a ball is expected, a fragment of a sphere is one), whose
        free radius it may not fix (``radius_error_sds_where_placed``). None when no sphere holds there, or
        the one there was ruled out (:meth:`ruling_out`).
        """
        if self.scene is None:
            return None
        for index in (config.colors.index(color), None):
            candidate = self.scene.candidate_where_placed(estimate_m, index, config)
            if candidate is not None and candidate.problem is None:
                if any(
                    np.linalg.norm(candidate.fit.center_m - c) < config.radius_m for c in self.ruled_out_m
                ):
                    return None
                return candidate
        return None

    def places_of(
        self, color: str, config: BallConfig, *, around_m: np.ndarray, reach_m: float
    ) -> list[np.ndarray]:
        """Where the points of ``color`` gather within ``reach_m`` of ``around_m``, as guesses of a ball's
        centre: the points binned in cells a ball's diameter wide, the ``_MAX_PEAKS`` fullest cells (at
        least half ``config.min_points``) each giving its points' mean pushed a radius farther along the
        camera's ray (a ball's visible side lies a radius before its centre). For a ball no vote found:
        a third of it in view at 4 m gives a dozen points whose normals scatter too much to vote together.
        """
        if self.scene is None:
            return []
        cloud = self.scene.cloud
        index = config.colors.index(color)
        of_color = cloud.has_color & (self.scene.likelihood[index] >= _SEED_LIKELIHOOD)
        of_color &= np.linalg.norm(cloud.points_m - around_m, axis=1) < reach_m
        points = cloud.points_m[of_color]
        if points.shape[0] == 0:
            return []
        voxels = occupied_voxels(points, config.diameter_m)
        cell, counts = voxels.of_point, voxels.counts
        guesses = []
        for fullest in np.argsort(-counts, kind="stable")[:_MAX_PEAKS]:
            if counts[fullest] < config.min_points / 2:
                break
            mean = points[cell == fullest].mean(axis=0)
            guesses.append(mean * (1.0 + config.radius_m / max(float(np.linalg.norm(mean)), 1e-9)))
        return guesses

    def hidden_ball_at(
        self, centre_m: np.ndarray, covariance_m2: np.ndarray, config: BallConfig
    ) -> BallCandidate | None:
        """A ball this view does not show, placed at ``centre_m`` (known to ``covariance_m2``), if the view
        lets one hide there; None when it sees through that place.

        Nothing is fitted: the other views' triangle carried onto two balls this one shows put it there. A
        ball there would end every ray through its outline on its surface or behind something in front of
        it (grass, the trunk, another ball). So the rays through the inner half of its outline, where a
        centimetre or two of placement error still falls on the ball, are followed: when more than
        ``config.max_seen_through_share`` of them reach a surface behind its near side, the place is open
        and no ball lies there. A place outside the image, or without depth readings, hides a ball.
        """
        radius = config.radius_m
        if self.scene is None or any(np.linalg.norm(centre_m - c) < radius for c in self.ruled_out_m):
            return None
        rays = self.scene.window(centre_m, radius, radii=0.5)
        if rays.size:
            points = self.scene.cloud.points_m[rays]
            ranges = np.linalg.norm(points, axis=1)
            directions = points / ranges[:, None]
            along = directions @ centre_m
            miss_sq = np.maximum(centre_m @ centre_m - along**2, 0.0)
            entry = along - np.sqrt(np.maximum(radius**2 - miss_sq, 0.0))
            tolerance = _range_tolerance(config.inlier_tolerance_m, centre_m)
            if np.mean(ranges > entry + tolerance) > config.max_seen_through_share:
                return None
        fit = SphereFit(
            center_m=np.asarray(centre_m, dtype=float),
            radius_m=radius,
            points=0,
            rms_m=0.0,
            coverage=0.0,
            radius_sd_m=float("inf"),
            center_covariance_m2=np.asarray(covariance_m2, dtype=float),
        )
        return BallCandidate(
            fit=fit,
            expected_points=self.scene.pixels_of_ball(centre_m, radius),
            color_scores=dict.fromkeys(config.colors, 0.0),
            unseen=True,
        )

    def surface_support(
        self,
        centres_m: np.ndarray,
        config: BallConfig,
        *,
        color: str | None = None,
        ground: GroundPlane | None = None,
    ) -> np.ndarray:
        """For each of ``(N, 3)`` possible ball centres, the points on the surface of a ball there (within
        ``_SUPPORT_SLACK`` inlier tolerances: the centre is a guess) less those inside it (a ball hides what
        is behind its surface), over the pixels such a ball covers: about 0.5-1 where a ball is seen whole,
        0 or less on open ground, grass or leaves. A quick screen of many places before spheres are fitted
        at the likeliest.

        With ``color``, only surface points that may have it count (likelihood ``_MAYBE_LIKELIHOOD`` or
        more, or unseen by the colour camera), as for a sphere's points in :func:`_candidate_at`. With the
        view's ``ground`` plane, only points higher than half a radius above it count: the ground round a
        ball's foot lies near its surface too.
        """
        if self.scene is None or centres_m.shape[0] == 0:
            return np.zeros(centres_m.shape[0])
        cloud = self.scene.cloud
        radius = config.radius_m
        low, high = centres_m.min(axis=0) - 2 * radius, centres_m.max(axis=0) + 2 * radius
        nearby = np.flatnonzero(((cloud.points_m >= low) & (cloud.points_m <= high)).all(axis=1))
        if ground is not None:
            nearby = nearby[(cloud.points_m[nearby] - ground.point_m) @ ground.normal > radius / 2]
        if nearby.size == 0:
            return np.zeros(centres_m.shape[0])
        points = cloud.points_m[nearby]
        may_be = np.ones(nearby.size, dtype=bool)
        if color is not None:
            likely = self.scene.likelihood[config.colors.index(color), nearby] >= _MAYBE_LIKELIHOOD
            may_be = likely | ~cloud.has_color[nearby]
        close = point_tree(centres_m).sparse_distance_matrix(
            point_tree(points), radius + _SUPPORT_REACH_M, output_type="ndarray"
        )  # every (centre, point) pair within reach, as arrays
        owner, neighbour = close["i"].astype(np.int64), close["j"].astype(np.int64)
        distance = np.linalg.norm(points[neighbour] - centres_m[owner], axis=1)
        tolerance = _SUPPORT_SLACK * _range_tolerances(config.inlier_tolerance_m, centres_m)[owner]
        on = (np.abs(distance - radius) < tolerance) & may_be[neighbour]
        inside = distance < radius - tolerance
        count = centres_m.shape[0]
        surplus = np.bincount(owner, weights=on, minlength=count) - np.bincount(
            owner, weights=inside, minlength=count
        )
        return surplus / np.maximum(self.scene.pixels_of_balls(centres_m, radius), 1.0)

    def ranked(self, color: str, config: BallConfig) -> list[BallCandidate]:
        """The candidates for ``color``: plausible ones first, each group likeliest first."""
        return sorted(
            self.candidates,
            key=lambda c: (
                c.objection(color, config) is not None,
                -c.score(color, radius_m=config.radius_m),
            ),
        )

    def not_found(self, color: str, config: BallConfig) -> BallNotFound:
        """The error for a ``color`` ball that none of the candidates is: the likeliest one's problem."""
        if self.colored_points[color] == 0:
            return BallNotFound(
                f"no {color} point in the view (HSV range {self.hsv_ranges[color]})",
                view=self.view,
                color=color,
                hint=f"Check that the ball is in view and lit, or adjust calibration_balls.hsv.{color}",
            )
        if self.colored_points[color] < config.min_points:
            return BallNotFound(
                f"too few {color} points: {self.colored_points[color]} found, at least {config.min_points} "
                "needed",
                view=self.view,
                color=color,
                hint="The ball may be hidden, too far or badly lit; move closer or lower balls.min_points",
            )
        colored = [c for c in self.candidates if c.color_scores[color] >= config.min_color_score]
        if not colored:
            return BallNotFound(
                f"no sphere of about {config.radius_m * 1000:.0f} mm radius among the "
                f"{self.colored_points[color]} {color} points",
                view=self.view,
                color=color,
                hint="The ball may be hidden, too far or too dark to show its shape, or of another size "
                "than calibration_balls.diameter_m; check with `canopy balls --preview`",
            )
        best = max(colored, key=lambda c: c.score(color, radius_m=config.radius_m))
        objection = best.objection(color, config) or Objection("taken", "every plausible sphere was taken")
        return BallNotFound(objection.message, view=self.view, color=color, hint=objection.hint)


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
    return _likelihood(_to_hsv(colors_rgb), hsv_range, hue_spread=None) == 1.0


def color_likelihood(colors_rgb: np.ndarray, hsv_range: list[list[int]], *, hue_spread: float) -> np.ndarray:
    """How much each colour looks like a ball's colour, in [0, 1]: 1 inside the HSV range, less outside.

    Outside the range the hue term falls as a Gaussian of the hue's distance to it (``hue_spread``, OpenCV
    units); value below the range's floor scales the likelihood down in proportion (a shaded ball keeps
    its hue and saturation but loses value), saturation below it as its cube (shade and exposure leave
    saturation nearly as it is, so a paler colour, bark or straw, is not the ball's). Chromaticity
    (hue, saturation) does not change with exposure, and a white-balance drift of 20 % moves a saturated
    colour's hue by a few units only, so a ball keeps a high likelihood in any light.

    Parameters
    ----------
    colors_rgb
        ``(N, 3)`` uint8 RGB colours.
    hsv_range
        As for :func:`color_mask`.
    hue_spread
        Hue distance at which the hue term is exp(-1/2).
    """
    return _likelihood(_to_hsv(colors_rgb), hsv_range, hue_spread=hue_spread)


def _to_hsv(colors_rgb: np.ndarray) -> np.ndarray:
    colors = np.ascontiguousarray(colors_rgb, dtype=np.uint8)
    if colors.ndim != 2 or colors.shape[1] != 3:
        raise ValueError(f"colors_rgb must have shape (N, 3), got {colors.shape}")
    if colors.shape[0] == 0:
        return colors.copy()
    return cv2.cvtColor(colors[:, None, :], cv2.COLOR_RGB2HSV).reshape(-1, 3)


def _likelihood(
    hsv: np.ndarray, hsv_range: list[list[int]], *, hue_spread: float | None, lit: bool = True
) -> np.ndarray:
    """The colour likelihood of HSV values; with ``hue_spread`` None, 1 inside the range and 0 outside.
    With ``lit`` False, brightness is left out: the likelihood of the colour whatever the light."""
    (h_low, s_low, v_low), (h_high, s_high, v_high) = hsv_range
    hue, saturation, value = (hsv[:, i].astype(np.float32) for i in range(3))
    inside_hue = (hue >= h_low) & (hue <= h_high) if h_low <= h_high else (hue >= h_low) | (hue <= h_high)
    if hue_spread is None:
        inside = inside_hue & (saturation >= s_low) & (saturation <= s_high)
        return (inside & (value >= v_low) & (value <= v_high)).astype(np.float32)
    distance = np.minimum(_hue_distance(hue, h_low), _hue_distance(hue, h_high))
    hue_term = np.where(inside_hue, 1.0, np.exp(-0.5 * (distance / hue_spread) ** 2))
    saturation_term = _band_term(saturation, s_low, s_high) ** _SATURATION_FALL
    value_term = _band_term(value, v_low, v_high) if lit else 1.0
    return (hue_term * saturation_term * value_term).astype(np.float32)


def _hue_distance(hue: np.ndarray, bound: float) -> np.ndarray:
    """Distance round the hue circle (180 OpenCV units) between hues and a bound."""
    difference = np.abs(hue - bound)
    return np.minimum(difference, 180.0 - difference)


def _band_term(channel: np.ndarray, low: float, high: float) -> np.ndarray:
    """1 within [low, high], falling linearly to 0 at 0 below it and at 255 above it."""
    below = np.where(channel >= low, 1.0, channel / max(low, 1.0))
    above = np.where(channel <= high, 1.0, (255.0 - channel) / max(255.0 - high, 1.0))
    return np.clip(np.minimum(below, above), 0.0, 1.0)


def find_ball_candidates(
    cloud: ViewCloud, config: BallConfig, *, ground: GroundPlane | None = None
) -> ViewBallCandidates:
    """Find every sphere of about the balls' radius among the points of the balls' colours in one view.

    Parameters
    ----------
    cloud
        The view's back-projected points, filtered or not (the fit copes with flying pixels itself).
    config
        Ball size, colours and detection thresholds.
    ground
        The view's ground plane, if known: vote peaks resting on it are fitted first (``_MAX_PEAKS`` of
        them), those standing higher than a ball can (apples in a crown) only after them
        (``_MAX_FLOATING_PEAKS``), so that a crown full of apples of a ball's colour does not use up the
        tries before the ball on the ground.

    Returns
    -------
    ViewBallCandidates
        Each sphere once, with its fit, its problem if its geometry is not a ball's, and its colour
        scores; and how many points of each colour the view holds.
    """
    scene = _Scene.of(cloud, config)
    seeds = np.flatnonzero(cloud.has_color & (scene.likelihood.max(axis=0) >= _SEED_LIKELIHOOD))
    colored_points = {
        color: int(np.count_nonzero(cloud.has_color & (scene.likelihood[i] >= _SEED_LIKELIHOOD)))
        for i, color in enumerate(config.colors)
    }
    hsv_ranges = {color: config.hsv_range(color) for color in config.colors}
    if seeds.size < config.min_points:
        return ViewBallCandidates(
            view=cloud.view, candidates=(), colored_points=colored_points, hsv_ranges=hsv_ranges, scene=scene
        )
    seeds, normals = scene.normals(seeds, radius_m=config.radius_m)
    votes = cloud.points_m[seeds] - config.radius_m * normals
    candidates: list[BallCandidate] = []
    for i in range(len(config.colors)):
        of_color = scene.likelihood[i, seeds] >= _SEED_LIKELIHOOD
        if np.count_nonzero(of_color) < config.min_points:
            continue
        peaks = _grounded_first(
            _vote_peaks(votes[of_color], scene.likelihood[i, seeds[of_color]], scene, config.radius_m),
            ground,
            config,
        )
        _add_candidates(candidates, peaks, i, scene, config)
        if ground is not None:
            shaded = _shaded_seeds(i, scene, ground, config)
            if shaded.size >= config.min_points:
                shaded, shaded_normals = scene.normals(shaded, radius_m=config.radius_m)
                shaded_votes = cloud.points_m[shaded] - config.radius_m * shaded_normals
                peaks = _grounded_first(
                    _vote_peaks(shaded_votes, scene.chroma[i, shaded], scene, config.radius_m),
                    ground,
                    config,
                )
                _add_candidates(candidates, peaks, i, scene, config)
        for least in (_SURE_LIKELIHOOD, _SEED_LIKELIHOOD):
            grouped = seeds[scene.likelihood[i, seeds] >= least]
            blobs = _blob_centres(
                cloud.points_m[grouped], cloud.pixels[grouped], config.radius_m, config.min_points
            )
            _add_candidates(candidates, blobs, i, scene, config)
    return ViewBallCandidates(
        view=cloud.view,
        candidates=tuple(candidates),
        colored_points=colored_points,
        hsv_ranges=hsv_ranges,
        scene=scene,
    )


def _shaded_seeds(color: int, scene: _Scene, ground: GroundPlane, config: BallConfig) -> np.ndarray:
    """Indices of the points of a ball's hue too dark to seed (``_SEED_LIKELIHOOD`` of their chroma but not
    of their likelihood) that stand where a ball resting on the ground has its surface: above the view's
    ground plane, at most a diameter and ``config.max_ground_gap_m`` higher.

    A ball in the shadow of the crown, or on the far side of the sun, keeps its hue but loses the brightness
    the colour range asks for (a yellow ball read as RGB 16, 14, 2): its shape still shows it. Only the
    floor's band is searched, where such points are few (soil and mulch in shade, dry leaves); the crown's
    shade would add thousands of dark leaves and apples for nothing.
    """
    cloud = scene.cloud
    dark = cloud.has_color & (scene.chroma[color] >= _SEED_LIKELIHOOD)
    dark &= scene.likelihood[color] < _SEED_LIKELIHOOD
    candidates = np.flatnonzero(dark)
    height = (cloud.points_m[candidates] - ground.point_m) @ ground.normal
    return candidates[(height > 0.0) & (height < config.diameter_m + config.max_ground_gap_m)]


def _add_candidates(
    candidates: list[BallCandidate], peaks: list[np.ndarray], color: int, scene: _Scene, config: BallConfig
) -> None:
    """Fit a sphere at each peak not within a radius of a known one, then look for one beside each new
    sphere (see :func:`_beside`) and keep it if it is a plausible ball; keep each new sphere once.

    The peaks come first: a sphere beside another is found from what is left around it, and a fragment
    of the ball found that way must not keep the ball's own peak from being fitted.
    """
    found: list[BallCandidate] = []
    for peak in peaks:
        if any(np.linalg.norm(peak - other.fit.center_m) < config.radius_m for other in candidates):
            continue  # that sphere is known already (found for another colour, or by another peak)
        candidate = _candidate_at(peak, color, scene, config)
        if candidate is not None and _new(candidate, candidates, config):
            candidates.append(candidate)
            found.append(candidate)
    for candidate in found:
        neighbour = _beside(candidate, color, scene, config)
        if neighbour is not None and neighbour.problem is None and _new(neighbour, candidates, config):
            candidates.append(neighbour)


def _new(candidate: BallCandidate, candidates: list[BallCandidate], config: BallConfig) -> bool:
    """Whether ``candidate``'s sphere is none of ``candidates``' (centres a radius apart or more)."""
    return all(
        np.linalg.norm(candidate.fit.center_m - other.fit.center_m) > config.radius_m for other in candidates
    )


def _beside(candidate: BallCandidate, color: int, scene: _Scene, config: BallConfig) -> BallCandidate | None:
    """A second sphere touching ``candidate``'s, fitted to the points of the colour around it that are not
    on or in it; None when too few are left for a ball.

    A red apple lying against the red ball makes one vote peak of the two, or the ball's few votes lose to
    the apple's: the sphere fitted there is the apple's, and the ball's points are what remains around it.
    """
    radius = config.radius_m
    centre = candidate.fit.center_m
    window = scene.window(centre, radius, radii=_BESIDE_RADII + 0.5)
    points = scene.cloud.points_m[window]
    distance = np.linalg.norm(points - centre, axis=1)
    tolerance = _range_tolerance(config.inlier_tolerance_m, centre)
    around = (distance > radius + tolerance) & (distance < _BESIDE_RADII * radius)
    around &= (scene.likelihood[color, window] >= _SURE_LIKELIHOOD) | ~scene.cloud.has_color[window]
    needed = max(config.min_points, config.min_completeness * candidate.expected_points)
    if np.count_nonzero(around) < needed:
        return None
    rest = points[around].mean(axis=0)
    estimate = rest + radius * rest / np.linalg.norm(rest)
    return _candidate_at(estimate, color, scene, config, apart_from=candidate.fit)


def detect_balls(cloud: ViewCloud, config: BallConfig) -> dict[str, SphereFit]:
    """Find every calibration ball of ``config.colors`` in one view, from this view alone.

    Each colour takes its likeliest plausible sphere, and no sphere is taken for two colours. The
    measurement chooses across views instead (:func:`canopy_core.ball_selection.select_balls`).

    Raises
    ------
    BallNotFound
        For the first colour whose ball is missing or implausible, naming the view and colour.
    """
    from canopy_core.ball_selection import choose_in_view

    chosen = choose_in_view(find_ball_candidates(cloud, config), config)
    return {color: candidate.fit for color, candidate in chosen.items()}


def detect_ball(cloud: ViewCloud, color: str, config: BallConfig) -> SphereFit:
    """Find the calibration ball of one colour in one view: its likeliest plausible sphere.

    Raises
    ------
    BallNotFound
        No point of that colour; too few; no sphere of the ball's size among them; or, for the likeliest
        sphere, too few points for its range, or a radius, residual, coverage or colour that is not a ball's.
    KeyError
        ``color`` has no HSV range.
    """
    candidates = find_ball_candidates(cloud, config.model_copy(update={"colors": [color]}))
    ranked = candidates.ranked(color, config)
    if ranked and ranked[0].objection(color, config) is None:
        return ranked[0].fit
    raise candidates.not_found(color, config)


@dataclass(frozen=True)
class _Scene:
    """A view's points with what detection needs of them: colour likelihoods, the pixel grid, intrinsics."""

    cloud: ViewCloud
    likelihood: np.ndarray
    """``(colours, N)`` colour likelihood of each point for each configured colour (0 without colour)."""
    chroma: np.ndarray
    """As ``likelihood`` but whatever the brightness (hue and saturation only): which colour a sphere found
    by its shape has. A ball in deep shade keeps its hue; its brightness says how it is lit."""
    point_at_pixel: np.ndarray
    """Depth-image-shaped index of each pixel's point, -1 where none."""
    focal_px: tuple[float, float]
    centre_px: tuple[float, float]
    """The depth camera's (fx, fy) and (cx, cy), read back from its points."""
    placed_fits: dict[tuple[int, int | None, bytes], tuple[BallConfig, BallCandidate | None]] = field(
        default_factory=dict, repr=False, compare=False
    )
    """What :meth:`candidate_where_placed` found, by config, colour and place."""
    trunk_feet: dict[tuple[bytes, float], np.ndarray | None] = field(
        default_factory=dict, repr=False, compare=False
    )
    """What :meth:`trunk_foot` found, by ground plane, place and reach."""

    @classmethod
    def of(cls, cloud: ViewCloud, config: BallConfig) -> _Scene:
        rows, cols = cloud.pixels[:, 0], cloud.pixels[:, 1]
        shape = (int(rows.max()) + 1, int(cols.max()) + 1) if len(cloud) else (0, 0)
        point_at_pixel = np.full(shape, -1, dtype=np.int64)
        point_at_pixel[rows, cols] = np.arange(len(cloud))
        hsv = _to_hsv(cloud.colors_rgb)
        likelihood, chroma = (
            np.stack(
                [
                    np.where(
                        cloud.has_color,
                        _likelihood(hsv, config.hsv_range(c), hue_spread=config.hue_spread, lit=lit),
                        0,
                    )
                    for c in config.colors
                ]
            )
            for lit in (True, False)
        )
        focal, centre = _intrinsics(cloud)
        return cls(
            cloud=cloud,
            likelihood=likelihood,
            chroma=chroma,
            point_at_pixel=point_at_pixel,
            focal_px=focal,
            centre_px=centre,
        )

    def candidate_where_placed(
        self, estimate_m: np.ndarray, color: int | None, config: BallConfig
    ) -> BallCandidate | None:
        """The sphere near ``estimate_m`` of colour ``color`` (its index; None for any colour), as sought
        where the other views place a ball (:meth:`ViewBallCandidates.sphere_near`): with
        ``config.min_completeness_where_placed`` and ``config.radius_error_sds_where_placed``.

        The fit is deterministic, and the searches of a choice made again seek at the very places of the
        choice before (a capture whose balls are chosen again five times asked 700 times for 220 places):
        each place's answer is kept with the scene, for the same config object (held, so that its id
        names it while kept)."""
        key = (id(config), color, np.asarray(estimate_m, dtype=float).tobytes())
        if key in self.placed_fits and self.placed_fits[key][0] is config:
            return self.placed_fits[key][1]
        placed = config.model_copy(update={"min_completeness": config.min_completeness_where_placed})
        candidate = _candidate_at(
            estimate_m, color, self, placed, radius_sds=config.radius_error_sds_where_placed
        )
        self.placed_fits[key] = (config, candidate)
        return candidate

    def trunk_foot(self, ground: GroundPlane, near_m: np.ndarray, reach_m: float) -> np.ndarray | None:
        """Where the trunk within ``reach_m`` of ``near_m`` meets this view's ``ground`` plane
        (:func:`canopy_core.ground.view_trunk_foot`), kept with the scene: the searches of a choice made
        again seek the trunk round the same balls (a capture whose balls are chosen again five times
        asked 70 times for 15)."""
        place = (ground.point_m, ground.normal, near_m)
        key = (b"".join(np.asarray(a, dtype=float).tobytes() for a in place), reach_m)
        if key not in self.trunk_feet:
            self.trunk_feet[key] = view_trunk_foot(self.cloud.points_m, ground, near_m, reach_m)
        return self.trunk_feet[key]

    def pixels_of_ball(self, centre_m: np.ndarray, radius_m: float) -> float:
        """How many pixels a ball of this radius and centre covers in the image."""
        return float(self.pixels_of_balls(np.asarray(centre_m)[None, :], radius_m)[0])

    def pixels_of_balls(self, centres_m: np.ndarray, radius_m: float) -> np.ndarray:
        """How many pixels balls of this radius at ``(N, 3)`` centres cover: the solid angle of each
        times the pixels per steradian (a centre nearer than the radius covers a hemisphere)."""
        ranges = np.maximum(np.linalg.norm(centres_m, axis=1), radius_m)
        sine_sq = np.minimum((radius_m / ranges) ** 2, 1.0)
        return 2.0 * np.pi * (1.0 - np.sqrt(1.0 - sine_sq)) * self.focal_px[0] * self.focal_px[1]

    def normals(self, indices: np.ndarray, *, radius_m: float) -> tuple[np.ndarray, np.ndarray]:
        """Those of the points ``indices`` whose surface normal can be estimated (``_MIN_NORMAL_NEIGHBOURS``
        neighbours on their surface), and their unit normals, facing the camera.

        Each normal is the least-variance direction of the point and its 8 neighbours at a pixel step
        that spans ``_NORMAL_BASELINE`` ball radii at the point's range (so the normal of a far ball's
        point, or of a big ball's, is as precise), among those on the same surface (depth within a radius):
        a plane fit, which, unlike differences across the point, still holds where a neighbour on one side
        is hidden (a ball half in grass).
        """
        points = self.cloud.points_m
        rows, cols = self.cloud.pixels[indices, 0], self.cloud.pixels[indices, 1]
        depth = points[indices, 2]
        reach_px = _NORMAL_BASELINE * radius_m * self.focal_px[0] / depth
        step = np.clip(np.rint(reach_px), 1, _MAX_STEP_PX).astype(np.int64)
        height, width = self.point_at_pixel.shape
        # The 9 neighbours of each point, a point to a column.
        window_rows = np.clip(rows + _NEIGHBOUR_OFFSETS[:, :1] * step, 0, height - 1)
        window_cols = np.clip(cols + _NEIGHBOUR_OFFSETS[:, 1:] * step, 0, width - 1)
        neighbours = self.point_at_pixel[window_rows, window_cols]
        seen = np.maximum(neighbours, 0)
        used = (neighbours >= 0) & (np.abs(points[:, 2][seen] - depth) < radius_m)
        count = used.sum(axis=0)
        estimable = count >= _MIN_NORMAL_NEIGHBOURS
        indices, used, count, seen = (
            indices[estimable],
            used[:, estimable],
            count[estimable],
            seen[:, estimable],
        )
        centre = points[indices]
        offsets = [np.where(used, points[:, axis][seen] - centre[:, axis], 0.0) for axis in range(3)]
        normals = scatter_normals(scatter_about_mean(offsets, count))
        normals *= np.where(np.einsum("ij,ij->i", normals, centre) > 0.0, -1.0, 1.0)[:, None]
        return indices, normals

    def points_over(self, centre_m: np.ndarray, up: np.ndarray, radius_m: float) -> int:
        """How many points stand right over a sphere of ``radius_m`` at ``centre_m`` (``up`` the ground's
        unit normal, both in this view's frame): within :data:`_OVER_REACH_RADII` radii of its vertical axis,
        between :data:`_OVER_LOW_RADII` and :data:`_OVER_HIGH_RADII` radii above its centre, and no farther
        from the camera than its centre. Nothing stands there over a ball on the ground; the foot of a post
        fitted as a sphere has the post's face there (in front of the fitted centre, which lies a radius
        behind the surface); the trunk behind a ball stands behind its centre."""
        window = self.window(centre_m, radius_m, radii=_OVER_HIGH_RADII + 1.0)
        offsets = self.cloud.points_m[window] - centre_m
        height = offsets @ up
        across = np.linalg.norm(offsets - height[:, None] * up, axis=1)
        in_front = offsets @ (centre_m / max(float(np.linalg.norm(centre_m)), 1e-9)) <= 0.0
        over = (
            (across < _OVER_REACH_RADII * radius_m)
            & (height > _OVER_LOW_RADII * radius_m)
            & (height < _OVER_HIGH_RADII * radius_m)
            & in_front
        )
        return int(np.count_nonzero(over))

    def window(self, centre_m: np.ndarray, radius_m: float, *, radii: float) -> np.ndarray:
        """Indices of the points whose pixels lie within ``radii`` projected radii of a sphere's centre."""
        (fx, fy), (cx, cy) = self.focal_px, self.centre_px
        depth = max(float(centre_m[2]), 1e-3)
        column, row = fx * centre_m[0] / depth + cx, fy * centre_m[1] / depth + cy
        reach = radii * max(fx, fy) * radius_m / depth + 1.0
        height, width = self.point_at_pixel.shape
        low_row, high_row = max(int(row - reach), 0), min(int(row + reach) + 1, height)
        low_col, high_col = max(int(column - reach), 0), min(int(column + reach) + 1, width)
        if low_row >= high_row or low_col >= high_col:
            return np.zeros(0, dtype=np.int64)
        block = self.point_at_pixel[low_row:high_row, low_col:high_col]
        grid_rows, grid_cols = np.mgrid[low_row:high_row, low_col:high_col]
        inside = (block >= 0) & ((grid_rows - row) ** 2 + (grid_cols - column) ** 2 <= reach**2)
        return block[inside]


def _intrinsics(cloud: ViewCloud) -> tuple[tuple[float, float], tuple[float, float]]:
    """The depth camera's focal lengths and principal point, read back from its points by least squares
    (a pixel's column is ``fx x / z + cx``, its row ``fy y / z + cy``); NaN when the points span no row or
    column."""
    if len(cloud) < 2:
        return (float("nan"), float("nan")), (float("nan"), float("nan"))
    sample = np.linspace(0, len(cloud) - 1, min(len(cloud), 2000)).astype(np.int64)
    points, pixels = cloud.points_m[sample], cloud.pixels[sample].astype(np.float64)
    solved = []
    for axis, pixel_axis in ((0, 1), (1, 0)):
        design = np.column_stack([points[:, axis] / points[:, 2], np.ones(sample.size)])
        (focal, offset), *_ = np.linalg.lstsq(design, pixels[:, pixel_axis], rcond=None)
        solved.append((float(focal), float(offset)))
    (fx, cx), (fy, cy) = solved
    return (fx, fy), (cx, cy)


def _vote_peaks(votes: np.ndarray, weights: np.ndarray, scene: _Scene, radius_m: float) -> list[np.ndarray]:
    """Centres where many votes agree, likeliest first, at least a radius apart (non-maximum suppression).

    A vote's strength is the number of votes within ``_VOTE_RADIUS`` radii of it over the pixels a ball
    centred there would cover, so near and far balls compare alike; its concentration is the share of the
    votes within one radius that lie that close: the votes of a sphere gather at a point (0.6-0.9), those of
    a cylinder of the ball's radius (a post, a trunk) along its axis (about ``_VOTE_RADIUS``), those of a
    plane over a plane (less). Peaks strong and concentrated enough are taken in order of their strength
    weighted by the colour likelihood of the points that voted (``weights``): a ball of the colour before
    a trunk of a near colour.
    """
    expected = np.maximum(scene.pixels_of_balls(votes, radius_m), 1.0)
    # Votes are thinned to about _VOTES_PER_BALL per ball-sized area, so a near or large ball's thousands
    # of agreeing votes cost no more to count than a far one's; counts are scaled back by the share kept.
    kept_share = np.minimum(1.0, _VOTES_PER_BALL / expected)
    kept = np.random.default_rng(0).random(votes.shape[0]) < kept_share
    votes, weights, expected = votes[kept], weights[kept], expected[kept] * kept_share[kept]
    if votes.shape[0] == 0:
        return []
    # Queries on one thread: the views are searched at once, in processes of their own (see
    # canopy_core.processes), which use the cores.
    tree = point_tree(votes)
    # Each vote's count of votes within the radius, itself included, from the list of pairs of votes
    # that close (one walk of the tree): the same counts as asking for each vote's neighbours (both count
    # a distance equal to the radius), in a third of the time.
    pairs = tree.query_pairs(_VOTE_RADIUS * radius_m, output_type="ndarray")
    close = 1 + np.bincount(pairs.ravel(), minlength=votes.shape[0])
    strength = close / expected
    eligible = np.flatnonzero(strength >= _MIN_PEAK)
    eligible = eligible[np.argsort(-strength[eligible], kind="stable")[:_MAX_PEAK_VOTES]]
    around = tree.query_ball_point(votes[eligible], r=radius_m, return_length=True)
    eligible = eligible[close[eligible] >= _MIN_CONCENTRATION * around]
    members = tree.query_ball_point(votes[eligible], r=_VOTE_RADIUS * radius_m)
    weighted = np.array([weights[m].sum() for m in members]) / expected[eligible]
    suppressed = np.zeros(votes.shape[0], dtype=bool)
    peaks: list[np.ndarray] = []
    for rank in np.argsort(-weighted, kind="stable"):
        index = eligible[rank]
        if suppressed[index]:
            continue
        peaks.append(votes[members[rank]].mean(axis=0))
        suppressed[tree.query_ball_point(votes[index], r=radius_m)] = True
        if len(peaks) == _MAX_VOTE_PEAKS:
            break
    return peaks


def _grounded_first(
    peaks: list[np.ndarray], ground: GroundPlane | None, config: BallConfig
) -> list[np.ndarray]:
    """The peaks resting on the ground (at most ``_MAX_PEAKS``, in order), then those standing higher than
    ``config.max_ground_gap_m`` above a ball's height (at most ``_MAX_FLOATING_PEAKS``); all peaks, up to
    ``_MAX_PEAKS``, when no ground is known."""
    if ground is None:
        return peaks[:_MAX_PEAKS]
    floating = [ground.height_of(peak) - config.radius_m > config.max_ground_gap_m for peak in peaks]
    resting = [peak for peak, high in zip(peaks, floating, strict=True) if not high]
    above = [peak for peak, high in zip(peaks, floating, strict=True) if high]
    return resting[:_MAX_PEAKS] + above[:_MAX_FLOATING_PEAKS]


def _blob_centres(
    points_m: np.ndarray, pixels: np.ndarray, radius_m: float, min_points: int
) -> list[np.ndarray]:
    """Likely centres of the compact groups of a colour's points that have a ball's size, largest first.

    The second source of candidates, tried whatever the votes found: a small far ball in sun has normals
    too noisy to gather votes, but its points that surely have its colour stand alone; and where the votes
    find a plausible look-alike, the ball may come from a group alone (2054014: views/2's yellow ball). A
    group is a connected set of pixels (8-neighbourhood) without a depth step of a radius; it is
    ball-sized when it is from half a diameter (a ball mostly hidden) to ``_MAX_BLOB_DIAMETERS`` diameters
    across at its depth. Its likely centre lies one radius behind its mean point, along the line of sight.
    """
    if points_m.shape[0] < min_points:
        return []
    labels = _blob_labels(points_m, pixels, max_depth_step_m=radius_m)
    order = np.argsort(labels, kind="stable")
    sizes = np.bincount(labels)
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    ordered = points_m[order]
    bearings = ordered[:, :2] / ordered[:, 2:3]
    extent = np.maximum.reduceat(bearings, starts, axis=0) - np.minimum.reduceat(bearings, starts, axis=0)
    means = np.add.reduceat(ordered, starts, axis=0) / sizes[:, None]
    width_m = extent.max(axis=1) * means[:, 2]
    sized = (sizes >= min_points) & (width_m >= radius_m) & (width_m <= 2 * _MAX_BLOB_DIAMETERS * radius_m)
    chosen = np.flatnonzero(sized)[np.argsort(-sizes[sized])][:_MAX_PEAKS]
    rays = means[chosen] / np.linalg.norm(means[chosen], axis=1, keepdims=True)
    return list(means[chosen] + radius_m * rays)


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
    return np.asarray(connected_components(graph, directed=False)[1])


def _candidate_at(
    peak: np.ndarray,
    color: int | None,
    scene: _Scene,
    config: BallConfig,
    *,
    apart_from: SphereFit | None = None,
    radius_sds: float = 0.0,
) -> BallCandidate | None:
    """The sphere near a vote peak of the votes of colour ``color`` (its index), described; None when no
    sphere of the radius holds there.

    The sphere is fitted to the points near the peak that surely have the colour (likelihood at least
    ``_SURE_LIKELIHOOD``), and then counted on all that may have it (at least ``_MAYBE_LIKELIHOOD``): a
    ball's shaded side adds to its points, while the mixed pixels at its rim, whose colour is part
    background, do not pull its centre. When that sphere is not a ball's (too few sure points, or a
    sunlit half that misleads the fit), all that may have the colour are fitted, and the better of the
    two is kept. Points the colour camera does not see count as both; with ``color`` None, every point
    does. Points on or inside the sphere ``apart_from`` (a neighbour already found) are left out. The
    radius may be off by ``radius_sds`` of its standard errors more than ``config.max_radius_error``; then
    (where the other views place a ball) the coverage is also judged on the outline of a ball of the known
    radius at the fitted centre, and the better of the two counts: a dozen points on a far ball's cap leave
    the free radius anywhere up to twice the known one, and the outline of such a sphere takes in the
    ground behind the ball (a ball 4.5 m away, two thirds hidden, showed 38 % coverage at its free radius
    of 100 mm).
    """
    radius = config.radius_m
    window = scene.window(peak, radius, radii=_NEAR_RADII + 0.5)
    if apart_from is not None:
        reach = apart_from.radius_m + _range_tolerance(config.inlier_tolerance_m, apart_from.center_m)
        window = window[np.linalg.norm(scene.cloud.points_m[window] - apart_from.center_m, axis=1) > reach]
    points = scene.cloud.points_m[window]
    unseen = ~scene.cloud.has_color[window] if color is not None else np.ones(window.size, dtype=bool)
    likelihood = scene.likelihood[color, window] if color is not None else np.ones(window.size)
    near = np.linalg.norm(points - peak, axis=1) < _NEAR_RADII * radius
    maybe = points[near & ((likelihood >= _MAYBE_LIKELIHOOD) | unseen)]
    sure = points[near & ((likelihood >= _SURE_LIKELIHOOD) | unseen)]
    needed = max(config.min_points, config.min_completeness * scene.pixels_of_ball(peak, radius))
    if maybe.shape[0] < needed:
        return None  # fewer points than a ball there shows, before any fit: not worth one
    outline = scene.cloud.points_m[scene.window(peak, radius, radii=_OUTLINE_RADII + 0.5)]
    maybe_indices = window[near][(likelihood[near] >= _MAYBE_LIKELIHOOD) | unseen[near]]
    best: BallCandidate | None = None
    # The sure points first, when they are enough and fewer than all that may be the ball (with color None
    # both are every point near the peak: fitting them twice would give the same sphere).
    tries = (sure, maybe) if config.min_points <= sure.shape[0] < maybe.shape[0] else (maybe,)
    for fitted in tries:
        try:
            fit = _fit_near(fitted, outline, config, min_start_inliers=_START_SHARE * needed)
        except ValueError:
            continue  # no sphere of about the radius through these points
        if radius_sds > 0.0:  # a fragment's free radius is loose: judge the known ball's outline too
            tolerance = _range_tolerance(config.inlier_tolerance_m, fit.center_m)
            known = sphere_coverage(outline, np.append(fit.center_m, radius), tolerance)
            fit = replace(fit, coverage=max(fit.coverage, known))
        candidate = _described(fit, maybe, maybe_indices, scene, config, radius_sds=radius_sds)
        if candidate.problem is None:
            return candidate
        if best is None or candidate.fit.points > best.fit.points:
            best = candidate
    return best


def _described(
    fit: SphereFit,
    maybe: np.ndarray,
    maybe_indices: np.ndarray,
    scene: _Scene,
    config: BallConfig,
    *,
    radius_sds: float = 0.0,
) -> BallCandidate:
    """A fitted sphere as a candidate: its points counted on every point that may be the ball's
    (``maybe``, whose indices into the view are ``maybe_indices``), its colour scores, its problem."""
    radius = config.radius_m
    tolerance = _range_tolerance(config.inlier_tolerance_m, fit.center_m)
    on_sphere = maybe_indices[sphere_inliers(maybe, np.append(fit.center_m, radius), tolerance, minimum=0)]
    colored = on_sphere[scene.cloud.has_color[on_sphere]]
    scores = {
        name: float(scene.chroma[i, colored].mean()) if colored.size else 0.0
        for i, name in enumerate(config.colors)
    }
    fit = replace(fit, points=max(fit.points, int(on_sphere.size)))
    expected = scene.pixels_of_ball(fit.center_m, radius)
    problem = _geometry_problem(fit, config, expected_points=expected, radius_sds=radius_sds)
    return BallCandidate(fit=fit, expected_points=expected, color_scores=scores, problem=problem)


def _fit_near(
    points: np.ndarray, outline: np.ndarray, config: BallConfig, *, min_start_inliers: float
) -> SphereFit:
    """RANSAC then robust least squares on ``points``; ``outline`` holds every point seen around them.

    Raises
    ------
    ValueError
        When no sphere of about the radius holds four of the points, or the RANSAC sphere holds fewer than
        ``min_start_inliers`` (the least squares, most of a view's detection time, would be wasted).
    """
    if points.shape[0] < 4:
        raise ValueError(f"{points.shape[0]} points cannot fix a sphere")
    centre = ransac_centre(
        points, config.radius_m, config.inlier_tolerance_m, config.ransac_iterations, np.random.default_rng(0)
    )
    tolerance = _range_tolerance(config.inlier_tolerance_m, centre)
    sphere_inliers(points, np.append(centre, config.radius_m), tolerance, minimum=int(min_start_inliers))
    return refine_sphere(
        points,
        centre,
        config.radius_m,
        nominal_radius_m=config.radius_m,
        tolerance_m=tolerance,
        scene_m=outline,
    )


def _range_tolerance(tolerance_m: float, centre: np.ndarray) -> float:
    """The inlier tolerance for a ball at ``centre`` (camera frame): widened as range² past the reference."""
    return float(_range_tolerances(tolerance_m, centre[None, :])[0])


def _range_tolerances(tolerance_m: float, centres_m: np.ndarray) -> np.ndarray:
    """:func:`_range_tolerance` for each of ``(N, 3)`` centres."""
    ranges = np.linalg.norm(centres_m, axis=1)
    return tolerance_m * np.maximum(1.0, (ranges / _TOLERANCE_REFERENCE_RANGE_M) ** 2)


def _geometry_problem(
    fit: SphereFit, config: BallConfig, *, expected_points: float, radius_sds: float = 0.0
) -> Objection | None:
    """Why a sphere is not a calibration ball by its shape, or None when it could be; its radius may be off
    by ``config.max_radius_error`` and ``radius_sds`` of its standard errors."""
    needed = max(config.min_points, int(np.ceil(config.min_completeness * expected_points)))
    if fit.points > config.max_completeness * expected_points:
        return Objection(
            "points",
            f"{fit.points} points on a sphere where a ball {np.linalg.norm(fit.center_m):.1f} m away shows "
            f"at most about {expected_points:.0f}: a larger surface (a post, a trunk) fits it",
            "Something else of that colour and about the ball's curvature is in view",
        )
    if fit.points < needed:
        return Objection(
            "points",
            f"too few points on a sphere: {fit.points} found, where a ball "
            f"{np.linalg.norm(fit.center_m):.1f} m away would show about {expected_points:.0f} (at least "
            f"{needed} needed)",
            "The ball may be mostly hidden or badly lit, or something smaller of its colour was found",
        )
    slack_m = radius_sds * fit.radius_sd_m
    if abs(fit.radius_m - config.radius_m) > config.max_radius_error * config.radius_m + slack_m:
        allowed = f"{config.max_radius_error:.0%}" + (
            f" and {radius_sds:g} standard errors of the fit ({slack_m * 1000:.0f} mm)" if slack_m > 0 else ""
        )
        return Objection(
            "radius",
            f"fitted radius {fit.radius_m * 1000:.0f} mm, expected {config.radius_m * 1000:.0f} mm "
            f"(more than {allowed} off)",
            "Something else of that colour may be taken for the ball; check balls.diameter_m",
        )
    if fit.rms_m > config.max_rms_m:
        return Objection(
            "residual",
            f"sphere fit residual {fit.rms_m * 1000:.1f} mm exceeds {config.max_rms_m * 1000:.1f} mm",
            "The ball's surface is too noisy or partly hidden; move closer or raise balls.max_rms_m",
        )
    if fit.coverage < config.min_coverage:
        return Objection(
            "coverage",
            f"only {fit.coverage:.0%} of the points seen through the fitted sphere's outline lie on it, "
            f"where a ball shows nearly all: it spans unrelated surfaces, or the depth there is too noisy",
            "Something else of that colour may be in view, or the ball is too far for this light",
        )
    return None
