"""The world frame of a tree: z up from a robust ground-plane fit, origin on the ground at the tree.

The paper takes "up" from the plane of the three ball centres. Balls lie on uneven ground, so a few
centimetres of bump under one ball tilts that plane by degrees; here the balls' plane only seeds a robust
plane fit of the ground points around the tree (metres of ground, so the bumps average out), and the
ground height under the trunk comes from a local fit around the trunk's base, so neither the balls nor
the bumps bias the height H.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from canopy_core.config import GroundConfig
from canopy_core.kdtree import NearestTree

__all__ = [
    "CAMERA_UP",
    "TRUNK_RADIUS_RANGE_M",
    "TRUNK_SLICE_M",
    "GroundFrame",
    "GroundHeightMap",
    "GroundPlane",
    "ball_plane",
    "fit_circle",
    "fit_ground_frame",
    "ground_height_map",
    "horizontal_distance",
    "sees_trunk_near",
    "view_ground_plane",
    "view_trunk_foot",
]

CAMERA_UP = np.array([0.0, -1.0, 0.0])
"""Up for a camera held roughly level, in its own frame (OpenCV axes: y points down)."""
_RANSAC_SAMPLE = 20_000
_RANSAC_HYPOTHESES = 200
TRUNK_SLICE_M = (0.12, 0.35)
"""The trunk's foot is found in this slice above the ground (m): above the grass and the balls, below the
lowest branches."""
_TRUNK_SEARCH_RADIUS_M = 0.8
_TRUNK_EXCLUSION_M = 0.12
_TRUNK_HYPOTHESES = 1000
"""Circles tried through three points of the trunk's slice."""
TRUNK_RADIUS_RANGE_M = (0.02, 0.2)
"""Trunks of fruit trees, from a whip to an old tree."""
_TRUNK_TOLERANCE_M = 0.01
"""Bark lies this close to the trunk's circle seen from above (depth noise, a slight lean over the slice)."""
_FLOOR_RING_M = 0.25
"""A ball's floor is read within this horizontal distance of its centre."""
_TRUNK_MIN_POINTS = 20
"""A trunk's slice (or the arc found in it) holds at least this many points."""
_TRUNK_SCORED_POINTS = 4000
"""Each circle is scored on at most this many points of the slice, drawn at random."""
_BATCH_ELEMENTS = 256_000
"""Circles (or first points of circles) are judged in batches of about this many circle-point pairs, so
that each batch's arrays stay a few megabytes however many points a slice holds."""
_RIVAL_SHARE = 0.3
"""A circle standing apart from the best-supported one (farther than a trunk's largest diameter) with at
least this share of its bark (and ``_TRUNK_MIN_POINTS``) is a rival upright: a trellis post near the trunk is
as round as the trunk and, where weeds hide the trunk's foot, better seen (held-out near posts 2120034 and
tuning 2117015: the trunk showed 43 % and 45 % of the post's bark). Of such rivals the trunk is the one the
crown stands over (:func:`_over_by_crown`). Less than this is too little to be told from weeds: at a
quarter, a tuft's circle (29 %) where a post beyond the search pulled the crown's middle was taken for the
trunk (tuning near posts 2119007)."""
_CROWN_ABOVE_M = 2 * TRUNK_SLICE_M[1]
"""Points higher than this in the frame are the crown's, and whatever stands in it, when the trunk is told
from rival uprights by what stands over it: above the trunk's slice, twice as high."""
UPRIGHT_CLEARANCE_M = 0.3
"""The middle of a crown is taken without the points this near an upright that may be the trunk (a post
2-4 m tall is a column of points of its own, which would pull the middle towards it)."""
CLEARLY_NEARER = 0.5
"""An upright is taken over another for the trunk by the crown it stands under only when it stands at most
this share of the other's distance from the crown's middle: crowns lean and grow lopsided by decimetres."""
_MAX_VIEW_TILT_DEG = 45.0
"""A view's ground is within this of the camera's up: crews hold the camera roughly level."""
_MIN_VIEW_GROUND_SHARE = 0.05
"""A view's ground plane holds at least this share of its points (floors fill a fifth to a half of a view)."""


@dataclass(frozen=True)
class GroundFrame:
    """The world frame found for a capture, and how it was found.

    ``world_from_reference`` maps the reference view's camera frame to the world: z up, y across the row
    (away from the reference camera), x along it; origin below the balls' centroid at the ground height
    of the trunk's base, or at the trunk's foot (:meth:`round_trunk`).
    """

    world_from_reference: np.ndarray
    ground_points: int
    ground_rms_m: float
    tilt_from_ball_plane_deg: float
    """How far the ground plane found round the balls tilts from the plane of the balls' centres (0 when no
    ground plane was found there)."""
    on_ground: bool
    """Whether the balls rest on the ground found: its plane tilts less than ``max_tilt_from_balls_deg`` from
    theirs, or every ball stands one radius above the floor round it (``ball_rest_tolerance_m``); then the
    frame stands on the ground. Else the frame is the balls' plane, which a sphere taken for a ball but lying
    off the ground tilts (see ``ball_heights_m``); True when no ground plane was found."""
    ball_heights_m: tuple[float, ...]
    """Each ball centre's height above the floor right round it, along the ground's normal, the frame
    standing on it or not (the balls' radius each when no ground was found): a ball's stands one radius
    high."""
    trunk_xy_m: tuple[float, float]
    trunk_points: int
    """How many points the trunk was found from: its bark's arc, or the whole low slice near the balls
    (grass and weeds hiding the trunk) when no trunk-sized circle holds them; 0 when nothing stands at a
    trunk's height near the balls, and ``trunk_xy_m`` is only the balls' centre."""
    ground_height_at_trunk_m: float
    trunk_radius_m: float | None
    """The radius of the circle the trunk's bark makes in the low slice; None when no trunk-sized circle was
    found there and the trunk is only the slice's median."""
    origin_at_trunk: bool = False
    """Whether the origin stands at the trunk's foot (see :meth:`round_trunk`; ``trunk_xy_m`` then 0)."""

    @property
    def trunk_on_bark(self) -> bool:
        """Whether the trunk was found on its bark (a trunk-sized circle), not only as the low slice's
        median."""
        return self.trunk_radius_m is not None

    def round_trunk(self) -> GroundFrame:
        """This frame with its origin moved to the trunk's foot where its bark was found (else itself): the
        frame the tree is measured in, whose region of interest is the cylinder round the origin. It is
        then the tree's however the crew laid the balls round it (2089047: their centroid 0.38 m off the
        trunk left a branch tip 1.74 m from it, outside the 1.5 m cylinder; W 9.7 % narrow)."""
        if not self.trunk_on_bark or self.origin_at_trunk:
            return self
        shift = np.eye(4)
        shift[:2, 3] = -np.array(self.trunk_xy_m)
        return replace(
            self,
            world_from_reference=shift @ self.world_from_reference,
            trunk_xy_m=(0.0, 0.0),
            origin_at_trunk=True,
        )


def ball_plane(ball_centres: np.ndarray, *, up_hint: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centroid and unit normal (oriented along ``up_hint``) of the plane through the ball centres."""
    centroid = ball_centres.mean(axis=0)
    _, _, vt = np.linalg.svd(ball_centres - centroid)
    normal = vt[2]
    return centroid, normal if normal @ up_hint > 0 else -normal


def horizontal_distance(points: np.ndarray, origin: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Distance of each point from the vertical line through ``origin`` along unit ``up``."""
    offset = points - origin
    return np.linalg.norm(offset - np.outer(offset @ up, up), axis=1)


def _plane_fit(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    centroid = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centroid, full_matrices=False)
    return centroid, vt[2]


def _ransac_ground(
    points: np.ndarray, tolerance_m: float, *, up: np.ndarray | None = None, max_tilt_deg: float = 90.0
) -> np.ndarray:
    """Indices (into ``points``) of the inliers of the plane with most points within ``tolerance_m``.

    All hypotheses (planes through three random points, tilted at most ``max_tilt_deg`` from ``up`` when
    it is given) are scored at once on a sample of the points.
    """
    rng = np.random.default_rng(0)
    sample = (
        points
        if points.shape[0] <= _RANSAC_SAMPLE
        else points[rng.choice(points.shape[0], _RANSAC_SAMPLE, replace=False)]
    )
    triples = sample[rng.integers(0, sample.shape[0], size=(_RANSAC_HYPOTHESES, 3))]
    normals = np.cross(triples[:, 1] - triples[:, 0], triples[:, 2] - triples[:, 0])
    length = np.linalg.norm(normals, axis=1)
    usable = length > 1e-9
    normals = normals[usable] / length[usable, None]
    triples = triples[usable]
    if up is not None:
        level = np.abs(normals @ up) >= np.cos(np.radians(max_tilt_deg))
        normals, triples = normals[level], triples[level]
    if normals.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    offsets = -np.einsum("ij,ij->i", normals, triples[:, 0])
    scores = [
        np.count_nonzero(np.abs(sample @ n + d) < tolerance_m) for n, d in zip(normals, offsets, strict=True)
    ]
    best = int(np.argmax(scores))
    return np.flatnonzero(np.abs(points @ normals[best] + offsets[best]) < tolerance_m)


@dataclass(frozen=True)
class GroundPlane:
    """A ground plane: a point on it and its unit normal pointing up, in some frame (metres)."""

    point_m: np.ndarray
    normal: np.ndarray

    def height_of(self, point_m: np.ndarray) -> float:
        """Height of a point above the plane, metres."""
        return float((point_m - self.point_m) @ self.normal)


def view_ground_plane(
    points_m: np.ndarray,
    *,
    up_hint: np.ndarray,
    tolerance_m: float,
    max_tilt_deg: float = _MAX_VIEW_TILT_DEG,
    min_share: float = _MIN_VIEW_GROUND_SHARE,
) -> GroundPlane | None:
    """The ground plane one view sees, in its camera frame, before anything else is known of the scene.

    The largest plane tilted at most ``max_tilt_deg`` from ``up_hint`` (the camera's up, -y, for a camera
    held roughly level): looking across an orchard row, that is the floor; the row's fruit wall and posts are
    near vertical and crowns are not planes. Used to tell a ball resting on the ground from an apple in a
    crown.

    Returns
    -------
    GroundPlane or None
        None when no such plane holds ``min_share`` of the points.
    """
    if points_m.shape[0] < 50:
        return None
    inliers = _ransac_ground(points_m, tolerance_m, up=up_hint, max_tilt_deg=max_tilt_deg)
    if inliers.size < max(50, min_share * points_m.shape[0]):
        return None
    point, normal = _plane_fit(points_m[inliers])
    return GroundPlane(point_m=point, normal=normal if normal @ up_hint > 0 else -normal)


def fit_ground_frame(
    points_m: np.ndarray,
    ball_centres_m: np.ndarray,
    *,
    ball_radius_m: float,
    up_hint: np.ndarray,
    forward_hint: np.ndarray,
    search_radius_m: float,
    config: GroundConfig,
) -> GroundFrame:
    """Fit the ground around the balls and build the world frame.

    Parameters
    ----------
    points_m
        ``(N, 3)`` points of all views, in the reference view's frame.
    ball_centres_m
        ``(B, 3)`` ball centres in the same frame, B >= 3.
    ball_radius_m
        The balls' radius: their centres stand this high above the ground they rest on.
    up_hint, forward_hint
        Roughly up (the reference camera's -y) and the reference camera's viewing direction.
    search_radius_m
        Ground is sought within this horizontal distance of the balls' centroid.
    config
        Ground-fit settings.
    """
    centroid, ball_up = ball_plane(ball_centres_m, up_hint=up_hint)
    contact = centroid - ball_radius_m * ball_up
    near_balls = np.zeros(points_m.shape[0], dtype=bool)
    for centre in ball_centres_m:
        near_balls |= np.linalg.norm(points_m - centre, axis=1) < 1.5 * ball_radius_m + 0.01
    candidates = np.flatnonzero(
        (np.abs((points_m - contact) @ ball_up) < config.search_band_m)
        & (horizontal_distance(points_m, centroid, ball_up) < search_radius_m)
        & ~near_balls
    )
    up = ball_up
    ground = candidates
    tilt_deg, heights = 0.0, np.full(ball_centres_m.shape[0], ball_radius_m)
    on_ground = True
    plane = _ground_round_balls(points_m, candidates, config)
    if plane is not None:
        plane_point, normal, inliers = plane
        normal = normal if normal @ ball_up > 0 else -normal
        tilt_deg = float(np.degrees(np.arccos(np.clip(normal @ ball_up, -1, 1))))
        heights = _heights_above_floor(
            points_m[~near_balls],
            ball_centres_m,
            (ball_centres_m - plane_point) @ normal,
            normal,
            ball_radius_m,
            config,
        )
        on_ground = tilt_deg < config.max_tilt_from_balls_deg or bool(
            np.all(np.abs(heights - ball_radius_m) < config.ball_rest_tolerance_m)
        )
        if on_ground:
            up, ground = normal, inliers
            contact = centroid - ((centroid - plane_point) @ up) * up
    rotation = _world_rotation(up, forward_hint)
    ground_world = (points_m[ground] - contact) @ rotation.T
    trunk_xy, trunk_points, trunk_radius = _trunk_position(points_m, contact, rotation, search_radius_m)
    ground_height = _local_ground_height(ground_world, trunk_xy, config.trunk_radius_m)
    world_from_reference = np.eye(4)
    world_from_reference[:3, :3] = rotation
    world_from_reference[:3, 3] = -rotation @ contact - np.array([0.0, 0.0, ground_height])
    residual = ground_world[:, 2] if ground_world.size else np.zeros(1)
    return GroundFrame(
        world_from_reference=world_from_reference,
        ground_points=int(ground.size),
        ground_rms_m=float(np.sqrt(np.mean(residual**2))),
        tilt_from_ball_plane_deg=tilt_deg,
        on_ground=on_ground,
        ball_heights_m=tuple(float(height) for height in heights),
        trunk_xy_m=(float(trunk_xy[0]), float(trunk_xy[1])),
        trunk_points=trunk_points,
        trunk_radius_m=trunk_radius,
        ground_height_at_trunk_m=float(ground_height),
    )


def _heights_above_floor(
    points_m: np.ndarray,
    ball_centres_m: np.ndarray,
    above_plane_m: np.ndarray,
    up: np.ndarray,
    ball_radius_m: float,
    config: GroundConfig,
) -> np.ndarray:
    """Each ball centre's height above the floor right round it (along ``up``): the median height of the
    points in a ring from just outside the ball to ``_FLOOR_RING_M`` from its centre, within the search
    band of where the ball would touch the floor. The ball's own height above the floor it rests on, where
    a plane through metres of undulating floor is centimetres off under one ball; its height above the
    plane (``above_plane_m``) where the ring holds no point."""
    heights = []
    for centre, fallback in zip(ball_centres_m, above_plane_m, strict=True):
        offset = points_m - centre
        rise = offset @ up
        across = np.linalg.norm(offset - np.outer(rise, up), axis=1)
        ring = (across > 1.5 * ball_radius_m + 0.01) & (across < _FLOOR_RING_M)
        ring &= np.abs(rise + ball_radius_m) < config.search_band_m
        heights.append(-float(np.median(rise[ring])) if ring.any() else float(fallback))
    return np.array(heights)


def _ground_round_balls(
    points_m: np.ndarray, candidates: np.ndarray, config: GroundConfig
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The ground plane among the ``candidates`` round the balls (a point, its unit normal, the indices of
    its inliers), or None when fewer than 50 points support one."""
    if candidates.size < 50:
        return None
    inliers = candidates[_ransac_ground(points_m[candidates], config.inlier_tolerance_m)]
    if inliers.size < 50:
        return None
    plane_point, normal = _plane_fit(points_m[inliers])
    return plane_point, normal, inliers


def _world_rotation(up: np.ndarray, forward_hint: np.ndarray) -> np.ndarray:
    """Rows x (along the row), y (across, away from the camera), z (up) in reference coordinates."""
    across = forward_hint - (forward_hint @ up) * up
    across /= np.linalg.norm(across)
    along = np.cross(across, up)
    return np.stack([along, across, up])


def _trunk_position(
    points_m: np.ndarray, contact: np.ndarray, rotation: np.ndarray, crown_radius_m: float
) -> tuple[np.ndarray, int, float | None]:
    """Horizontal position of the trunk (the frame's with its origin at ``contact``), the points it was found
    from, and its radius where found on its bark: the centre of the circle of a trunk's size that the most
    points of a low slice near the balls' centroid lie on with nothing inside it (:func:`_bark_support`; seen
    from above, a trunk's bark is an arc or a ring, grass and weeds are scattered dots). The median of the
    slice, which grass and weeds pull aside, and no radius, when no such circle is found. A circle apart
    from that one with enough of its bark is taken instead when it stands clearly nearer the middle of
    what stands above the trunk's height within ``crown_radius_m`` (:func:`_over_by_crown`): the crown
    stands over the trunk."""
    world = (points_m - contact) @ rotation.T
    low, high = TRUNK_SLICE_M
    in_slice = (world[:, 2] > low) & (world[:, 2] < high)
    in_slice &= np.linalg.norm(world[:, :2], axis=1) < _TRUNK_SEARCH_RADIUS_M
    if np.count_nonzero(in_slice) < _TRUNK_MIN_POINTS:
        return np.zeros(2), 0, None
    xy = world[in_slice, :2]
    over = (world[:, 2] > _CROWN_ABOVE_M) & (np.linalg.norm(world[:, :2], axis=1) < crown_radius_m)
    found = _bark_circle(xy, above_xy=world[over, :2])
    if found is None:
        return np.median(xy, axis=0), int(xy.shape[0]), None
    centre, radius, on_arc = found
    return centre, on_arc, radius


def view_trunk_foot(
    points_m: np.ndarray, ground: GroundPlane, near_m: np.ndarray, reach_m: float
) -> np.ndarray | None:
    """Where the trunk's axis meets one view's ground plane, in its camera frame, before the views are
    registered: the circle of a trunk's size in the view's low slice (``TRUNK_SLICE_M`` above ``ground``)
    within ``reach_m`` of ``near_m`` (a ball: the crew lays them round the trunk) that the most bark points
    lie on with nothing inside (:func:`_bark_support`). One view sees an arc of the trunk, which fixes its
    circle as well as a ring does. None when the slice holds too few points or no trunk-sized circle."""
    xy, axes = _trunk_slice(points_m, ground, near_m, reach_m)
    if xy.shape[0] < _TRUNK_MIN_POINTS:
        return None
    found = _bark_circle(xy)
    if found is None or found[2] < _TRUNK_MIN_POINTS:
        return None
    return ground.point_m + axes @ found[0]


def sees_trunk_near(points_m: np.ndarray, ground: GroundPlane, centre_m: np.ndarray, within_m: float) -> bool:
    """Whether one view's points hold a trunk standing within ``within_m`` of ``centre_m`` (its camera
    frame, horizontally): a circle of a trunk's size through its low-slice points (tried as
    :func:`view_trunk_foot` tries them) centred there, with ``_TRUNK_MIN_POINTS`` bark points or more and
    nothing inside (:func:`_bark_support`). A view's best circle may be a trellis post, or a clump of
    suckers beside a trunk that weeds half hide; this asks whether it also sees a trunk where another view
    puts one."""
    xy, axes = _trunk_slice(points_m, ground, centre_m, within_m + TRUNK_RADIUS_RANGE_M[1])
    if xy.shape[0] < _TRUNK_MIN_POINTS:
        return False
    xy -= (centre_m - ground.point_m) @ axes
    centres, radii = _trunk_circles(xy, np.random.default_rng(0))
    close = np.linalg.norm(centres, axis=1) < within_m
    return bool(np.any(_bark_support(xy, centres[close], radii[close]) >= _TRUNK_MIN_POINTS))


def _trunk_slice(
    points_m: np.ndarray, ground: GroundPlane, near_m: np.ndarray, reach_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """One view's points of the trunk's low slice (``TRUNK_SLICE_M`` above ``ground``) within ``reach_m``
    of ``near_m`` horizontally, as ``(N, 2)`` coordinates on the ground plane from ``ground.point_m``, and
    the ``(3, 2)`` axes that carry such coordinates back into the camera frame."""
    up = ground.normal / np.linalg.norm(ground.normal)
    height = (points_m - ground.point_m) @ up
    low, high = TRUNK_SLICE_M
    in_slice = (height > low) & (height < high)
    in_slice &= horizontal_distance(points_m, near_m, up) < reach_m
    axis_u = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    axis_u /= np.linalg.norm(axis_u)
    axes = np.column_stack([axis_u, np.cross(up, axis_u)])
    return (points_m[in_slice] - ground.point_m) @ axes, axes


def _bark_circle(
    xy: np.ndarray, *, above_xy: np.ndarray | None = None
) -> tuple[np.ndarray, float, int] | None:
    """The centre and radius of the trunk-sized circle that the most of ``(N, 2)`` slice points lie on with
    nothing inside it, refitted on its arc, and how many points lie on that arc; None when no three nearby
    points make a circle of a trunk's size. With ``above_xy`` (where the points above the trunk's height
    stand), a rival circle with enough bark clearly nearer their middle is taken instead
    (:func:`_over_by_crown`)."""
    rng = np.random.default_rng(0)
    scored = xy[rng.permutation(xy.shape[0])[:_TRUNK_SCORED_POINTS]]
    centres, radii = _trunk_circles(scored, rng)
    if centres.shape[0] == 0:
        return None
    support = _bark_support(scored, centres, radii)
    best = int(np.argmax(support))
    apart = np.linalg.norm(centres - centres[best], axis=1) > 2 * TRUNK_RADIUS_RANGE_M[1]
    rivals = np.flatnonzero(apart & (support >= max(_RIVAL_SHARE * support[best], _TRUNK_MIN_POINTS)))
    if above_xy is not None and rivals.size:
        best = _over_by_crown(best, rivals, centres, support, above_xy)
    on_arc = xy[np.abs(np.linalg.norm(xy - centres[best], axis=1) - radii[best]) < _TRUNK_TOLERANCE_M]
    return *fit_circle(on_arc), int(on_arc.shape[0])


def _over_by_crown(
    best: int, rivals: np.ndarray, centres: np.ndarray, support: np.ndarray, above_xy: np.ndarray
) -> int:
    """Of the best-supported circle and its ``rivals`` (indices into ``centres`` and their bark
    ``support``), the one the crown stands over: the best, unless rivals stand clearly nearer the middle of
    ``above_xy`` (:func:`crown_middle`) than it does (less than ``CLEARLY_NEARER`` of its distance), each
    showing at least that same share of the best's bark as its distance is of the best's; then the one of
    them with the most bark. Bark and crown both witness the trunk: the more clearly the crown stands over
    a rival, the less of its bark it need show (a rival a third as far needs a third of the bark, one
    right under the crown's middle only ``_RIVAL_SHARE``), and of several under the crown the trunk is the
    best seen, not the nearest the middle: a crown's middle stands decimetres off its trunk (lopsided, or
    pulled by a post beyond the search), where a tuft of weeds may make a circle (tuning near posts
    2115038)."""
    middle = crown_middle(above_xy, np.vstack([centres[best], centres[rivals]]))
    if middle is None:
        return best
    distance = np.linalg.norm(centres[rivals] - middle, axis=1)
    best_distance = float(np.linalg.norm(centres[best] - middle))
    # Shares compared as products: the best may stand right at the middle.
    taken = (distance < CLEARLY_NEARER * best_distance) & (
        support[rivals] * best_distance >= distance * support[best]
    )
    if not taken.any():
        return best
    return int(rivals[taken][np.argmax(support[rivals][taken])])


def crown_middle(above_xy: np.ndarray, uprights_xy: np.ndarray, *, min_points: int = 1) -> np.ndarray | None:
    """The middle of where the ``(N, 2)`` points above the trunk's height stand, without those within
    ``UPRIGHT_CLEARANCE_M`` of any of the ``(K, 2)`` uprights that may be the trunk: halfway between the
    5th and 95th percentiles along x and y, the middle of what they span. Not their mean or median: each
    view sees its near side of the crown more densely than the other's, and a vase crown is a hollow shell.
    None when fewer than ``min_points`` stand there."""
    distance, _ = NearestTree(uprights_xy).query(above_xy, distance_upper_bound=UPRIGHT_CLEARANCE_M)
    clear = above_xy[~np.isfinite(distance)]
    if clear.shape[0] < max(min_points, 1):
        return None
    low, high = np.percentile(clear, [5, 95], axis=0)
    return (low + high) / 2


def _trunk_circles(xy: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Circles of a trunk's size through three nearby points of the slice: the first at random, the other two
    within a trunk's diameter of it, so that all three lie on the trunk often even amid grass.

    The firsts' neighbours are found a batch at a time (about ``_BATCH_ELEMENTS`` pairs of a first and a
    point, hundreds within reach of each first), and only the two drawn from each are looked up."""
    reach_sq = (2.0 * TRUNK_RADIUS_RANGE_M[1]) ** 2
    firsts = rng.choice(xy.shape[0], size=min(_TRUNK_HYPOTHESES, xy.shape[0]), replace=False)
    triples: list[np.ndarray] = []  # (first, second, third) point indices, a batch at a time
    batch = max(1, _BATCH_ELEMENTS // xy.shape[0])
    for start in range(0, firsts.size, batch):
        first = firsts[start : start + batch]
        near = (xy[None, :, 0] - xy[first, None, 0]) ** 2 + (
            xy[None, :, 1] - xy[first, None, 1]
        ) ** 2 <= reach_sq
        rank = np.cumsum(near, axis=1, dtype=np.int64)  # a point's rank among the first's neighbours, from 1
        count = rank[:, -1]
        rows = np.flatnonzero(count >= 3)
        if not rows.size:
            continue
        drawn = np.array([rng.choice(int(count[row]), size=2, replace=False) for row in rows])
        # The neighbour drawn k-th is the first point of rank k + 1; each row's ranks lifted above the
        # last row's, the rows searched as one sorted array.
        lift = np.arange(rows.size)[:, None] * (xy.shape[0] + 1)
        found = np.searchsorted((rank[rows] + lift).ravel(), drawn + 1 + lift)
        triples.append(np.column_stack([first[rows], found - np.arange(rows.size)[:, None] * xy.shape[0]]))
    if not triples:
        return np.zeros((0, 2)), np.zeros(0)
    centres, radii = _circumcircles(xy[np.concatenate(triples)])
    plausible = np.isfinite(radii) & (radii > TRUNK_RADIUS_RANGE_M[0]) & (radii < TRUNK_RADIUS_RANGE_M[1])
    return centres[plausible], radii[plausible]


def _bark_support(points_m: np.ndarray, centres: np.ndarray, radii_m: np.ndarray) -> np.ndarray:
    """For each of ``(K, 2)`` circle centres and ``(K,)`` radii, how many of the ``(N, 2)`` points lie on the
    circle where nothing lies inside it, in stretches of ``_TRUNK_TOLERANCE_M`` along it: a trunk is solid,
    the views see its surface and nothing within. A circle through a clump of grass, however many points
    its stems have, has other stems inside.

    The circles are judged a batch at a time (``_BATCH_ELEMENTS``), each stretch a column of a table of
    which stretches hold a point inside: one pass over the points for a batch of circles."""
    counts = np.zeros(centres.shape[0], dtype=np.int64)
    # A stretch's number lies within ±pi r / tol, r below the largest trunk radius (as every circle tried):
    # shifted by that bound, it indexes the table.
    shift = int(np.ceil(np.pi * TRUNK_RADIUS_RANGE_M[1] / _TRUNK_TOLERANCE_M)) + 1
    batch = max(1, _BATCH_ELEMENTS // max(points_m.shape[0], 1))
    for start in range(0, centres.shape[0], batch):
        centre, radius = centres[start : start + batch], radii_m[start : start + batch]
        offset_x = points_m[None, :, 0] - centre[:, None, 0]
        offset_y = points_m[None, :, 1] - centre[:, None, 1]
        distance = np.sqrt(offset_x**2 + offset_y**2)
        stretch = np.floor(np.arctan2(offset_y, offset_x) * radius[:, None] / _TRUNK_TOLERANCE_M)
        stretch = (stretch + shift).astype(np.int64)
        on_circle = np.abs(distance - radius[:, None]) < _TRUNK_TOLERANCE_M
        inside = distance < radius[:, None] - _TRUNK_TOLERANCE_M
        circle = np.broadcast_to(np.arange(centre.shape[0])[:, None], stretch.shape)
        shadowed = np.zeros((centre.shape[0], 2 * shift + 1), dtype=bool)
        shadowed[circle[inside], stretch[inside]] = True
        counts[start : start + centre.shape[0]] = np.count_nonzero(
            on_circle & ~shadowed[circle, stretch], axis=1
        )
    return counts


def _circumcircles(triples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centres ``(K, 2)`` and radii ``(K,)`` of the circles through each of ``(K, 3, 2)`` point triples
    (radius inf or nan for three points in a line)."""
    a, b, c = triples[:, 0], triples[:, 1], triples[:, 2]
    d = 2 * (a[:, 0] * (b[:, 1] - c[:, 1]) + b[:, 0] * (c[:, 1] - a[:, 1]) + c[:, 0] * (a[:, 1] - b[:, 1]))
    na, nb, nc = (a**2).sum(1), (b**2).sum(1), (c**2).sum(1)
    with np.errstate(divide="ignore", invalid="ignore"):
        ux = (na * (b[:, 1] - c[:, 1]) + nb * (c[:, 1] - a[:, 1]) + nc * (a[:, 1] - b[:, 1])) / d
        uy = (na * (c[:, 0] - b[:, 0]) + nb * (a[:, 0] - c[:, 0]) + nc * (b[:, 0] - a[:, 0])) / d
    centres = np.column_stack([ux, uy])
    return centres, np.linalg.norm(a - centres, axis=1)


def fit_circle(xy: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre and radius of the least-squares circle through ``(N, 2)`` points (x² + y² = 2ax + 2by + c,
    linear in a, b and c; the radius is √(c + a² + b²))."""
    design = np.column_stack([xy, np.ones(xy.shape[0])])
    solution, *_ = np.linalg.lstsq(design, (xy**2).sum(axis=1), rcond=None)
    centre = solution[:2] / 2.0
    return centre, float(np.sqrt(max(solution[2] + centre @ centre, 0.0)))


def _local_ground_height(ground_world: np.ndarray, trunk_xy: np.ndarray, radius_m: float) -> float:
    """Ground height at the trunk: a quadratic surface through the ground around it, read at its centre.

    A plane would carry the curvature of a bump or a ridge under the trunk into the height (about a
    centimetre for a 3 cm bump); a quadratic follows it.
    """
    offset = ground_world[:, :2] - trunk_xy
    distance = np.linalg.norm(offset, axis=1)
    near = (distance > _TRUNK_EXCLUSION_M) & (distance < radius_m)
    if np.count_nonzero(near) < 50:
        return float(np.median(ground_world[:, 2])) if ground_world.size else 0.0
    x, y = offset[near, 0], offset[near, 1]
    design = np.column_stack([np.ones_like(x), x, y, x * x, x * y, y * y])
    coefficients, *_ = np.linalg.lstsq(design, ground_world[near, 2], rcond=None)
    return float(coefficients[0])


@dataclass(frozen=True)
class GroundHeightMap:
    """The ground's height on a square grid of cells in the world frame, for heights above local ground.

    Orchard floors undulate by more than the few centimetres that separate grass from the lowest twigs; a
    single plane would leave a rise at the edge of the region of interest above the tree's clearance.
    """

    origin_xy_m: np.ndarray
    cell_m: float
    heights_m: np.ndarray

    def height_at(self, xy_m: np.ndarray) -> np.ndarray:
        """Ground height below each ``(N, 2)`` horizontal position (nearest cell; edges extend outwards)."""
        index = np.floor((xy_m - self.origin_xy_m) / self.cell_m).astype(np.int64)
        rows = np.clip(index[:, 0], 0, self.heights_m.shape[0] - 1)
        cols = np.clip(index[:, 1], 0, self.heights_m.shape[1] - 1)
        return self.heights_m[rows, cols]

    def height_above(self, points_m: np.ndarray) -> np.ndarray:
        """Each world point's height above the ground below it."""
        return points_m[:, 2] - self.height_at(points_m[:, :2])


def ground_height_map(
    points_m: np.ndarray, *, radius_m: float, cell_m: float = 0.2, band_m: float = 0.2, quantile: float = 0.2
) -> GroundHeightMap:
    """Estimate the ground's height per cell from world points (z = 0 at the trunk's foot).

    Each cell takes a low quantile of its points within ``band_m`` of z = 0 (grass, stones and the trunk's
    foot stand above the ground, rarely below); cells where no ground was seen (under the crown, behind the
    trunk) take the nearest seen cell's height, and with no ground seen at all the map is flat at 0.
    """
    size = int(np.ceil(2 * radius_m / cell_m))
    origin = np.array([-radius_m, -radius_m])
    low = points_m[np.abs(points_m[:, 2]) < band_m]
    index = np.floor((low[:, :2] - origin) / cell_m).astype(np.int64)
    inside = (index >= 0).all(axis=1) & (index < size).all(axis=1)
    low, index = low[inside], index[inside]
    heights = np.zeros((size, size))
    if low.shape[0] == 0:
        return GroundHeightMap(origin_xy_m=origin, cell_m=cell_m, heights_m=heights)
    cell = index[:, 0] * size + index[:, 1]
    order = np.lexsort((low[:, 2], cell))
    cell, z = cell[order], low[order, 2]
    starts = np.flatnonzero(np.r_[True, cell[1:] != cell[:-1]])
    counts = np.diff(np.r_[starts, cell.size])
    picked = z[starts + np.floor(quantile * (counts - 1)).astype(np.int64)]
    seen = np.zeros(size * size, dtype=bool)
    seen[cell[starts]] = True
    heights.ravel()[cell[starts]] = picked
    seen_cells = np.column_stack(np.nonzero(seen.reshape(size, size)))
    all_cells = np.indices((size, size)).reshape(2, -1).T
    _, nearest = NearestTree(seen_cells).query(all_cells)
    filled = heights[seen_cells[nearest, 0], seen_cells[nearest, 1]].reshape(size, size)
    return GroundHeightMap(origin_xy_m=origin, cell_m=cell_m, heights_m=filled)
