"""The world frame: up from the ground, not from balls resting on bumps; z = 0 at the trunk's foot."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from canopy_core.ball_selection import ball_off_ground, balls_off_ground, no_trunk_round_balls
from canopy_core.config import GroundConfig
from canopy_core.ground import GroundFrame, fit_ground_frame, view_ground_plane, view_trunk_foot
from canopy_core.register import apply, invert


def _bumpy_ground(xy: np.ndarray) -> np.ndarray:
    """Height of an uneven orchard floor, 0 at the trunk (origin): a slight slope and bumps of ~3 cm."""
    x, y = xy[:, 0], xy[:, 1]
    return 0.03 * np.sin(3.1 * x + 0.4) * np.cos(2.3 * y) - 0.03 * np.sin(0.4) + 0.005 * x


def _scene(
    rng: np.random.Generator,
    *,
    floor: Callable[[np.ndarray], np.ndarray] = _bumpy_ground,
    ball_xy: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ground, trunk and crown points in a world frame with the trunk at (0.2, -0.1), and ball centres
    (at ``ball_xy``, else round the trunk) resting on the ``floor``."""
    ground_xy = rng.uniform(-2.5, 2.5, size=(40000, 2))
    ground = np.column_stack([ground_xy, floor(ground_xy)])
    trunk_xy = np.array([0.2, -0.1])
    angle = rng.uniform(0, 2 * np.pi, 3000)
    trunk = np.column_stack(
        [trunk_xy[0] + 0.07 * np.cos(angle), trunk_xy[1] + 0.07 * np.sin(angle), rng.uniform(0, 0.8, 3000)]
    )
    crown = rng.normal([0.2, -0.1, 1.8], [0.5, 0.5, 0.4], size=(20000, 3))
    if ball_xy is None:
        ball_xy = trunk_xy + 0.6 * np.column_stack([np.cos([0.3, 2.4, 4.4]), np.sin([0.3, 2.4, 4.4])])
    balls = np.column_stack([ball_xy, floor(ball_xy) + 0.05])
    ground_height_at_trunk = floor(trunk_xy[None, :])[0]
    ground[:, 2] -= ground_height_at_trunk
    balls[:, 2] -= ground_height_at_trunk
    return np.vstack([ground, trunk, crown]), balls, trunk_xy


def _camera_from_world() -> np.ndarray:
    """A level camera 1.2 m high, 3 m from the trunk on the -y side, looking along +y (OpenCV axes)."""
    world_from_camera = np.eye(4)
    world_from_camera[:3, :3] = np.column_stack([[1, 0, 0], [0, 0, -1], [0, 1, 0]])
    world_from_camera[:3, :3] = (
        Rotation.from_euler("x", 4, degrees=True).as_matrix() @ world_from_camera[:3, :3]
    )
    world_from_camera[:3, 3] = [0.1, -3.0, 1.2]
    return invert(world_from_camera)


def _fitted_frame(points_world: np.ndarray, balls_world: np.ndarray) -> tuple[GroundFrame, np.ndarray]:
    """The world frame fitted to the scene as the camera of :func:`_camera_from_world` sees it, and the
    transform from the scene's world to the one recovered."""
    camera_from_world = _camera_from_world()
    frame = fit_ground_frame(
        apply(camera_from_world, points_world),
        apply(camera_from_world, balls_world),
        ball_radius_m=0.05,
        up_hint=np.array([0.0, -1.0, 0.0]),
        forward_hint=np.array([0.0, 0.0, 1.0]),
        search_radius_m=1.5,
        config=GroundConfig(),
    )
    return frame, frame.world_from_reference @ camera_from_world


def test_world_frame_is_level_with_the_ground_and_zero_at_the_trunk_foot() -> None:
    points_world, balls_world, trunk_xy = _scene(np.random.default_rng(0))
    frame, recovered_from_world = _fitted_frame(points_world, balls_world)
    up_error_deg = np.degrees(np.arccos(recovered_from_world[2, 2]))
    assert up_error_deg < 0.3  # the ground's slope is 0.3°: the balls' plane alone is ~3° off
    assert frame.tilt_from_ball_plane_deg > 1.0
    trunk_foot = apply(recovered_from_world, np.array([[trunk_xy[0], trunk_xy[1], 0.0]]))[0]
    assert abs(trunk_foot[2]) < 0.01
    assert np.linalg.norm(np.array(frame.trunk_xy_m) - trunk_foot[:2]) < 0.03
    assert recovered_from_world[1, 1] > 0.99  # y across the row, away from the camera


def test_the_tree_is_measured_in_a_frame_whose_origin_is_its_trunk_foot() -> None:
    # The balls lie to one side of the trunk, their centroid 0.4 m from it (below it, the frame's origin):
    # the frame round the trunk puts the trunk's foot at the origin, level and on the ground as before, so
    # the region of interest, the cylinder round the origin, is the tree's.
    offsets = np.array([[0.7, 0.2], [0.1, 0.6], [0.5, -0.3]])
    points_world, balls_world, trunk_xy = _scene(
        np.random.default_rng(0), ball_xy=np.array([0.2, -0.1]) + offsets
    )
    frame, recovered_from_world = _fitted_frame(points_world, balls_world)
    assert frame.trunk_on_bark and not frame.origin_at_trunk
    assert frame.trunk_radius_m == pytest.approx(0.07, abs=0.005)  # the scene's trunk, seen by one camera
    assert np.linalg.norm(frame.trunk_xy_m) > 0.1

    round_trunk = frame.round_trunk()

    assert round_trunk.origin_at_trunk and round_trunk.trunk_xy_m == (0.0, 0.0)
    trunk_from_world = round_trunk.world_from_reference @ np.linalg.inv(frame.world_from_reference)
    trunk_foot = apply(trunk_from_world @ recovered_from_world, np.array([[*trunk_xy, 0.0]]))[0]
    assert np.linalg.norm(trunk_foot) < 0.03
    np.testing.assert_allclose(trunk_from_world[:3, :3], np.eye(3), atol=1e-12)  # moved, not turned
    assert round_trunk.round_trunk() is round_trunk


def test_the_trunk_is_found_on_its_bark_among_tall_grass_and_weeds() -> None:
    """One view's arc of a 7 cm trunk among clumps of leaning grass stems up to 45 cm tall, most of them on
    one side: the median of the low slice, which the trunk used to be, lies several centimetres off it."""
    rng = np.random.default_rng(1)
    points_world, balls_world, trunk_xy = _scene(rng)
    front = points_world[:, 1] < trunk_xy[1] + 0.07 * np.sin(np.pi / 8)  # the bark the camera sees
    on_trunk = np.abs(np.linalg.norm(points_world[:, :2] - trunk_xy, axis=1) - 0.07) < 1e-9
    stems = []
    for centre in trunk_xy + rng.uniform([-0.1, 0.15], [0.5, 0.6], size=(14, 2)):
        for foot in centre + rng.normal(0.0, 0.04, size=(20, 2)):
            z = np.arange(0.0, rng.uniform(0.25, 0.45), 0.007)
            lean = rng.normal(0.0, 0.2, size=2)  # metres aside per metre up
            stems.append(np.column_stack([foot + z[:, None] * lean, z]))
    grass = np.vstack(stems) + rng.normal(0.0, 0.003, size=(sum(map(len, stems)), 3))
    scene = np.vstack([points_world[~on_trunk | front], grass])
    frame, recovered_from_world = _fitted_frame(scene, balls_world)
    trunk_foot = apply(recovered_from_world, np.array([[trunk_xy[0], trunk_xy[1], 0.0]]))[0]
    assert np.linalg.norm(np.array(frame.trunk_xy_m) - trunk_foot[:2]) < 0.01


def test_one_view_finds_its_trunk_on_the_arc_it_sees_before_any_registration() -> None:
    """The trunk's foot in one camera's own frame, sought round one ball on that view's ground plane alone:
    the arc of bark the camera sees fixes the circle, and the ground's bumps and a tall crown do not move
    it. What places a ball two views do not share (the trunk fixes the turn about the shared ball)."""
    points_world, balls_world, trunk_xy = _scene(np.random.default_rng(2))
    front = points_world[:, 1] < trunk_xy[1] + 0.07 * np.sin(np.pi / 8)
    on_trunk = np.abs(np.linalg.norm(points_world[:, :2] - trunk_xy, axis=1) - 0.07) < 1e-9
    camera_from_world = _camera_from_world()
    seen = apply(camera_from_world, points_world[~on_trunk | front])
    ground = view_ground_plane(seen, up_hint=np.array([0.0, -1.0, 0.0]), tolerance_m=0.03)
    assert ground is not None
    ball = apply(camera_from_world, balls_world[:1])[0]
    foot = view_trunk_foot(seen, ground, ball, reach_m=1.2)
    assert foot is not None
    actual = apply(camera_from_world, np.array([[trunk_xy[0], trunk_xy[1], 0.0]]))[0]
    offset = foot - actual
    horizontal = offset - (offset @ ground.normal) * ground.normal
    assert np.linalg.norm(horizontal) < 0.015
    assert view_trunk_foot(seen, ground, ball + 3.0 * np.array([1.0, 0.0, 0.0]), reach_m=1.2) is None


def test_balls_resting_on_the_ground_stand_one_radius_above_the_ground_found() -> None:
    points_world, balls_world, _ = _scene(np.random.default_rng(0))
    frame, _ = _fitted_frame(points_world, balls_world)
    assert frame.on_ground
    assert np.allclose(frame.ball_heights_m, 0.05, atol=0.03)  # bumps of ~3 cm under a fitted plane
    assert ball_off_ground(frame, ("red", "yellow", "blue"), 0.05) is None


def test_balls_on_an_uneven_floor_rest_on_it_though_their_plane_tilts_beyond_the_limit() -> None:
    """As in mixed and green seed 2045008: the blue ball lies in a hollow 8-12 cm below the others, a third of
    a metre from the line through them, so the balls' plane tilts more than 15 degrees from the ground round
    them (the registration failed naming the red ball, or took an apple for it). Each ball still stands one
    radius above the floor right round it (the ring round the blue ball climbs the hollow's side, 2 cm),
    so they rest on the ground and the frame stands on it."""
    trunk_xy = np.array([0.2, -0.1])
    ball_xy = trunk_xy + np.array([[-0.45, -0.15], [-0.9, 0.45], [0.15, -0.45]])

    def floor(xy: np.ndarray) -> np.ndarray:
        return _bumpy_ground(xy) - 0.12 * np.exp(-((xy - ball_xy[2]) ** 2).sum(axis=1) / (2 * 0.3**2))

    points_world, balls_world, _ = _scene(np.random.default_rng(3), floor=floor, ball_xy=ball_xy)
    frame, recovered_from_world = _fitted_frame(points_world, balls_world)
    assert frame.tilt_from_ball_plane_deg > 15.0
    assert frame.on_ground
    assert np.allclose(frame.ball_heights_m, 0.05, atol=0.02)
    assert ball_off_ground(frame, ("red", "yellow", "blue"), 0.05) is None
    assert np.degrees(np.arccos(recovered_from_world[2, 2])) < 3.0  # the frame stands on the floor


def test_a_sphere_lying_lower_than_a_ball_tilts_the_balls_plane_and_is_named() -> None:
    """A fallen apple's fragment 12 cm from the yellow ball, its fitted centre at ground level, taken for
    the blue ball: the plane through the three centres tilts by tens of degrees from the ground round them."""
    points_world, balls_world, _ = _scene(np.random.default_rng(0))
    apple = balls_world[1] + np.array([0.12 * np.cos(0.4), 0.12 * np.sin(0.4), -0.05])
    frame, _ = _fitted_frame(points_world, np.vstack([balls_world[:2], apple]))
    assert not frame.on_ground
    assert frame.tilt_from_ball_plane_deg > 15.0
    assert ball_off_ground(frame, ("red", "yellow", "blue"), 0.05) == "blue"
    assert abs(frame.ball_heights_m[2]) < 0.02
    failure = balls_off_ground(frame, ("red", "yellow", "blue"), 0.05, "blue")
    assert "the blue ball's centre stands" in failure.message
    assert "where a ball's stands 0.05 m" in failure.message and "blue" in (failure.hint or "")


def test_balls_laid_out_in_the_open_away_from_any_trunk_find_no_trunk_and_are_refused() -> None:
    """Three spheres resting on open ground 2 m from the tree, as look-alikes that every view of a
    low-resolution camera saw (2080010): nothing stands at a trunk's height round them, so their centre,
    which stands in for the trunk, is no trunk, and the choice is refused; round the trunk it stands."""
    rng = np.random.default_rng(2)
    away = np.array([-1.6, -1.2]) + 0.5 * np.column_stack([np.cos([0.3, 2.4, 4.4]), np.sin([0.3, 2.4, 4.4])])
    points_world, balls_world, _ = _scene(rng, ball_xy=away)
    frame, _ = _fitted_frame(points_world, balls_world)
    assert frame.trunk_points == 0
    failure = no_trunk_round_balls(frame)
    assert failure is not None and failure.field == "balls.max_trunk_distance_m"
    assert "no trunk stands round the spheres taken for the balls" in failure.message

    points_world, balls_world, _ = _scene(rng)
    frame, _ = _fitted_frame(points_world, balls_world)
    assert frame.trunk_points > 0 and no_trunk_round_balls(frame) is None


def _trunk_beside_a_post(
    *, post_dx_m: float, shown_from_deg: float, crown_towards_post_m: float = 0.0
) -> tuple[GroundFrame, np.ndarray]:
    """The frame fitted to the scene with a trellis post ``post_dx_m`` along x from the trunk, 2.8 m tall and
    seen all round, the trunk showing the camera only its bark in front of ``shown_from_deg`` (the angle
    from its side to the front), the crown moved ``crown_towards_post_m`` towards the post; and where the
    trunk's foot stands in the recovered frame (x, y)."""
    rng = np.random.default_rng(2)
    points_world, balls_world, trunk_xy = _scene(rng)
    in_crown = points_world[:, 2] > 1.0
    points_world[in_crown, 0] += np.sign(post_dx_m) * crown_towards_post_m
    on_trunk = np.abs(np.linalg.norm(points_world[:, :2] - trunk_xy, axis=1) - 0.07) < 1e-9
    front = points_world[:, 1] < trunk_xy[1] - 0.07 * np.sin(np.radians(shown_from_deg))
    post_xy = trunk_xy + np.array([post_dx_m, 0.0])
    angle = rng.uniform(0, 2 * np.pi, 6000)
    post = np.column_stack(
        [post_xy[0] + 0.05 * np.cos(angle), post_xy[1] + 0.05 * np.sin(angle), rng.uniform(0, 2.8, 6000)]
    )
    frame, recovered_from_world = _fitted_frame(
        np.vstack([points_world[~on_trunk | front], post]), balls_world
    )
    return frame, apply(recovered_from_world, np.array([[trunk_xy[0], trunk_xy[1], 0.0]]))[0, :2]


@pytest.mark.parametrize("crown_towards_post_m", [0.0, 0.2])
def test_the_trunk_is_the_upright_the_crown_stands_over_not_a_better_seen_post_beside_it(
    crown_towards_post_m: float,
) -> None:
    """A trellis post 0.55 m from the trunk, 2.8 m tall, inside the search round the balls, seen all round
    where the trunk shows the camera only its front: the post's circle holds more bark, but the crown
    stands over the trunk, even grown lopsided towards the post."""
    frame, trunk_foot = _trunk_beside_a_post(
        post_dx_m=-0.55, shown_from_deg=30.0, crown_towards_post_m=crown_towards_post_m
    )
    assert frame.trunk_radius_m == pytest.approx(0.07, abs=0.01)
    assert np.linalg.norm(np.array(frame.trunk_xy_m) - trunk_foot) < 0.02


def test_a_trunk_showing_under_half_a_post_s_bark_is_still_the_upright_the_crown_stands_over() -> None:
    """Held-out near posts 2120034: weeds at the trunk's foot left it 43 % of the bark a post 0.63 m from
    it showed in the trunk's slice, under the half once asked of a rival; the post was taken for the
    trunk (H +0.41 m). The crown stands right over the trunk: it needs less bark the more clearly it does."""
    frame, trunk_foot = _trunk_beside_a_post(post_dx_m=-0.6, shown_from_deg=42.0)  # 43 % of the post's bark
    assert np.linalg.norm(np.array(frame.trunk_xy_m) - trunk_foot) < 0.02
