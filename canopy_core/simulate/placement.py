"""Where the balls and the cameras go: every camera frames the whole tree and every camera sees every ball.

The balls are laid on the ground 0.35-0.8 m from the trunk; each camera stands 2.6-4.0 m from the trunk,
0.8-1.6 m above the ground, looks at the trunk (a few degrees of yaw and roll jitter) and is pitched so
that the whole main tree lies inside the depth image and the balls inside both images (or, for a crew
that does not aim at the tree, held at a given pitch that shows the balls, the tree as it falls: the
tree may run out of the image). A layout is kept
only if every ball keeps to the crew's rule in every depth image, with everything else of the scene in place
(weeds and wires in the mesh, apples in the crown, and the objects laid beside the balls, such as fallen
apples): at least :data:`MIN_BALL_PIXELS` of its pixels, and at least :data:`MIN_CLEAN_SHARE` of its disc
in pixels that see nothing but the ball (all of a pixel's rays hit it). A pixel shared with a grass blade
or a leaf in front reads a blend of their depths, not the ball's: a ball behind a veil of grass shows its
colour to the crew but no depth to the sensor. Otherwise the balls and cameras are drawn again.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull

from canopy_core.capture import Intrinsics
from canopy_core.simulate.camera import CameraPose, KinectRig, camera_pose, project
from canopy_core.simulate.raycast import SceneRaycaster, Sphere
from canopy_core.simulate.scene import Orchard, resting_balls
from canopy_core.simulate.sensor import DEPTH_SUBPIXEL_OFFSETS

__all__ = [
    "MIN_BALL_PIXELS",
    "MIN_CLEAN_SHARE",
    "Layout",
    "NoLayout",
    "ball_visibility",
    "place_balls_and_cameras",
    "view_azimuths",
]

MIN_BALL_PIXELS = 30
"""Fewest depth pixels of each ball each view must have (pixel centres on the ball, before sensor dropout)."""
MIN_CLEAN_SHARE = 1.0 / 3.0
"""Least share of each ball's disc (its projected area in pixels) that must lie in pixels seeing only the
ball, in each view: the crew lays the balls where every camera sees at least a third of each, with no grass
in front of it."""


class NoLayout(RuntimeError):
    """No placement of the balls and cameras frames the tree and shows every ball to every view: the crown,
    weeds or fallen fruit hide some ball from some view at every try. Rare, among clutter, with three views
    or a coarser sensor (mixed 2099: one tree of 30 with three Kinect v2 views, one with two binned Azure
    Kinect views); the seed gives no capture."""


_CENTRE_RAY = int(np.flatnonzero((DEPTH_SUBPIXEL_OFFSETS == 0.0).all(axis=1))[0])
_BALL_DISTANCE_M = (0.35, 0.8)
_MIN_BALL_SEPARATION_RAD = np.radians(60.0)
_CAMERA_DISTANCE_M = (2.6, 4.0)
_CAMERA_HEIGHT_M = (0.8, 1.6)
_AZIMUTH_JITTER_RAD = np.radians(6.0)
_YAW_JITTER_RAD = np.radians(4.0)
_ROLL_JITTER_RAD = np.radians(2.0)
_PITCH_JITTER_RAD = np.radians(1.0)
_SIDE_SPREAD_RAD = np.radians(35.0)
_MARGIN_PX = 4.0
_LAYOUT_ATTEMPTS = 300
_POSE_ATTEMPTS = 40


@dataclass(frozen=True, eq=False)
class Layout:
    """The balls (red, yellow, blue) and the depth cameras' poses; per view, each ball's pixel count and
    the share of its disc in pixels that see only the ball; the spheres laid beside the balls (see
    :func:`place_balls_and_cameras`)."""

    balls: tuple[Sphere, ...]
    poses: tuple[CameraPose, ...]
    ball_pixels: tuple[tuple[int, ...], ...]
    ball_clean_shares: tuple[tuple[float, ...], ...]
    tree_framed: tuple[bool, ...]
    """Per view, whether the whole main tree falls inside its depth image, 4 px from its edges (always,
    unless the cameras are held at a given pitch)."""
    beside_balls: tuple[Sphere, ...] = ()


def view_azimuths(rng: np.random.Generator, n_views: int) -> np.ndarray:
    """Azimuths (radians, of the camera as seen from the trunk) of ``n_views`` views.

    Views alternate between the two sides of the row (-y first), so that two views face each other across
    it; several views on one side spread over +-35 degrees, never looking along the row into a neighbour.
    """
    sides = np.where(np.arange(n_views) % 2 == 0, -np.pi / 2, np.pi / 2)
    azimuths = np.empty(n_views)
    for side in (-np.pi / 2, np.pi / 2):
        on_side = np.flatnonzero(sides == side)
        spread = np.linspace(-_SIDE_SPREAD_RAD, _SIDE_SPREAD_RAD, len(on_side)) if len(on_side) > 1 else 0.0
        azimuths[on_side] = side + spread
    return azimuths + rng.uniform(-_AZIMUTH_JITTER_RAD, _AZIMUTH_JITTER_RAD, n_views)


def _ball_positions(rng: np.random.Generator) -> np.ndarray:
    """Three (x, y) positions around the trunk, at least 60 degrees apart as seen from it."""
    while True:
        azimuths = rng.uniform(0.0, 2 * np.pi, 3)
        gaps = np.abs((azimuths[:, None] - azimuths[None, :] + np.pi) % (2 * np.pi) - np.pi)
        if gaps[np.triu_indices(3, 1)].min() >= _MIN_BALL_SEPARATION_RAD:
            distances = rng.uniform(*_BALL_DISTANCE_M, 3)
            return np.column_stack([distances * np.cos(azimuths), distances * np.sin(azimuths)])


def _elevations(points: np.ndarray, position: np.ndarray, yaw_rad: float) -> np.ndarray | None:
    """Elevation angles of points seen from ``position`` in the vertical plane of ``yaw_rad``; None when some
    point is not well in front of the camera."""
    relative = points - position
    forward = relative[:, 0] * np.cos(yaw_rad) + relative[:, 1] * np.sin(yaw_rad)
    if forward.min() < 0.3:
        return None
    return np.arctan2(relative[:, 2], forward)


def _pitch_range(elevations: np.ndarray, intrinsics: Intrinsics) -> tuple[float, float]:
    """Pitches that put every elevation inside the image's rows (with margin), as (lowest, highest).

    A point at elevation a appears at row cy - fy * tan(a - pitch), independently of its lateral offset.
    """
    above = np.arctan((intrinsics.cy - _MARGIN_PX) / intrinsics.fy)
    below = np.arctan((intrinsics.height - 1 - _MARGIN_PX - intrinsics.cy) / intrinsics.fy)
    return float(elevations.max() - above), float(elevations.min() + below)


def _inside(pose: CameraPose, intrinsics: Intrinsics, points: np.ndarray) -> bool:
    pixels, depth = project(pose, intrinsics, points)
    return bool(
        (depth > 0).all()
        and (pixels[:, 0] >= _MARGIN_PX).all()
        and (pixels[:, 0] <= intrinsics.width - 1 - _MARGIN_PX).all()
        and (pixels[:, 1] >= _MARGIN_PX).all()
        and (pixels[:, 1] <= intrinsics.height - 1 - _MARGIN_PX).all()
    )


def _framed_pose(
    rng: np.random.Generator,
    orchard: Orchard,
    rig: KinectRig,
    azimuth: float,
    tree_points: np.ndarray,
    ball_points: np.ndarray,
    *,
    native_color: bool,
    pitch_rad: float | None,
) -> CameraPose | None:
    """A camera pose on ``azimuth`` that frames the tree and the balls, or None if none was found; with
    ``pitch_rad``, a pose at that pitch (and the usual jitter) that frames the balls, the tree as it
    falls."""
    for _ in range(_POSE_ATTEMPTS):
        distance = rng.uniform(*_CAMERA_DISTANCE_M)
        x, y = distance * np.cos(azimuth), distance * np.sin(azimuth)
        position = np.array([x, y, float(orchard.ground.height_at(x, y)) + rng.uniform(*_CAMERA_HEIGHT_M)])
        yaw = azimuth + np.pi + rng.uniform(-_YAW_JITTER_RAD, _YAW_JITTER_RAD)
        tree_elevations = _elevations(tree_points, position, yaw)
        ball_elevations = _elevations(ball_points, position, yaw)
        if tree_elevations is None or ball_elevations is None:
            continue
        ranges = [_pitch_range(ball_elevations, rig.depth)]
        if pitch_rad is None:
            ranges.append(_pitch_range(tree_elevations, rig.depth))
        if native_color:
            ranges.append(_pitch_range(ball_elevations, rig.color))
        lowest, highest = max(r[0] for r in ranges), min(r[1] for r in ranges)
        if lowest > highest:
            continue
        aim = (tree_elevations.min() + tree_elevations.max()) / 2 if pitch_rad is None else pitch_rad
        pitch = aim + rng.uniform(-_PITCH_JITTER_RAD, _PITCH_JITTER_RAD)
        if pitch_rad is not None and not lowest <= pitch <= highest:
            continue
        pose = camera_pose(
            position,
            yaw_rad=yaw,
            pitch_rad=float(np.clip(pitch, lowest, highest)),
            roll_rad=rng.uniform(-_ROLL_JITTER_RAD, _ROLL_JITTER_RAD),
        )
        framed = _inside(pose, rig.depth, ball_points) and (
            pitch_rad is not None or _inside(pose, rig.depth, tree_points)
        )
        if framed and (
            not native_color or _inside(pose.moved_by(rig.depth_to_color), rig.color, ball_points)
        ):
            return pose
    return None


def ball_visibility(
    raycaster: SceneRaycaster, pose: CameraPose, intrinsics: Intrinsics, balls: tuple[Sphere, ...]
) -> tuple[tuple[int, ...], tuple[float, ...]]:
    """Per ball (the first spheres of ``raycaster``) in a depth camera: its pixels (centre rays on it) and
    the share of its disc (pi (f r / z)^2 pixels, z its centre's depth) in pixels all of whose rays hit it.

    Only the pixels around each ball are cast: a crop of the image is a camera with the same focal lengths
    and the principal point moved by the crop's corner.
    """
    pixels, shares = [], []
    for index, ball in enumerate(balls):
        corners, depths = project(pose, intrinsics, ball.box_corners())
        if (depths <= 0).any():
            pixels.append(0)
            shares.append(0.0)
            continue
        low = np.clip(np.floor(corners.min(axis=0)).astype(int) - 1, 0, [intrinsics.width, intrinsics.height])
        high = np.clip(np.ceil(corners.max(axis=0)).astype(int) + 2, 0, [intrinsics.width, intrinsics.height])
        crop = dataclasses.replace(
            intrinsics,
            width=int(high[0] - low[0]),
            height=int(high[1] - low[1]),
            cx=intrinsics.cx - low[0],
            cy=intrinsics.cy - low[1],
        )
        if crop.width <= 0 or crop.height <= 0:
            pixels.append(0)
            shares.append(0.0)
            continue
        surface = raycaster.cast_camera(pose, crop, subpixel_offsets=DEPTH_SUBPIXEL_OFFSETS).surface
        on_ball = surface == raycaster.sphere_surface(index)
        depth = float(pose.to_camera(ball.centre[None, :])[0, 2])
        disc = np.pi * intrinsics.fx * intrinsics.fy * (ball.radius_m / depth) ** 2
        pixels.append(int(on_ball[..., _CENTRE_RAY].sum()))
        shares.append(float(on_ball.all(axis=-1).sum() / disc))
    return tuple(pixels), tuple(shares)


def place_balls_and_cameras(
    rng: np.random.Generator,
    orchard: Orchard,
    raycaster: SceneRaycaster,
    rig: KinectRig,
    *,
    n_views: int,
    native_color: bool,
    beside_balls: Callable[[tuple[Sphere, ...]], tuple[Sphere, ...]] | None = None,
    pitch_deg: float | None = None,
) -> Layout:
    """Draw balls and camera poses until every view frames the tree and sees every ball; with
    ``pitch_deg``, until every view held at that pitch (degrees up from level) sees every ball, the tree
    framed or not (a crew that does not aim the camera at the tree).

    Parameters
    ----------
    rng
        Source of every random draw.
    orchard
        The scene; ``raycaster`` must hold its mesh and any spheres that belong to it (apples in the crown).
    rig
        The sensor's intrinsics (the colour image must hold the balls too when ``native_color``).
    n_views
        Number of views.
    beside_balls
        Given the balls just drawn, the spheres to lay beside them (fallen apples); they are in the scene
        when the balls' visibility is checked. None: nothing.
    pitch_deg
        Every camera's pitch, up from level, within 1 degree; None: each camera is aimed to frame the tree.

    Raises
    ------
    NoLayout
        When no layout was found in ``_LAYOUT_ATTEMPTS`` tries (rare: see :class:`NoLayout`).
    """
    vertices = orchard.main_tree.mesh.vertices
    tree_points = vertices[ConvexHull(vertices).vertices]
    for _ in range(_LAYOUT_ATTEMPTS):
        balls = resting_balls(orchard.ground, _ball_positions(rng))
        ball_points = np.concatenate([ball.box_corners() for ball in balls])
        poses: list[CameraPose] = []
        for azimuth in view_azimuths(rng, n_views):
            pose = _framed_pose(
                rng,
                orchard,
                rig,
                azimuth,
                tree_points,
                ball_points,
                native_color=native_color,
                pitch_rad=None if pitch_deg is None else float(np.radians(pitch_deg)),
            )
            if pose is None:
                break
            poses.append(pose)
        if len(poses) < n_views:
            continue
        beside = () if beside_balls is None else beside_balls(balls)
        with_balls = raycaster.with_spheres((*balls, *raycaster.spheres, *beside))
        seen = [ball_visibility(with_balls, pose, rig.depth, balls) for pose in poses]
        counts = tuple(pixels for pixels, _ in seen)
        shares = tuple(clean for _, clean in seen)
        if min(map(min, counts)) >= MIN_BALL_PIXELS and min(map(min, shares)) >= MIN_CLEAN_SHARE:
            return Layout(
                balls=balls,
                poses=tuple(poses),
                ball_pixels=counts,
                ball_clean_shares=shares,
                beside_balls=beside,
                tree_framed=tuple(_inside(pose, rig.depth, tree_points) for pose in poses),
            )
    raise NoLayout(
        f"no layout in {_LAYOUT_ATTEMPTS} attempts frames the tree and shows every ball to every view"
    )
