"""Where the tree runs out of the cameras' images (``canopy_core.framing``), on cameras built by hand."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from canopy_core.capture import Intrinsics
from canopy_core.framing import FrameCut, ViewFrame, cut_metrics, frame_cuts

KINECT = Intrinsics(width=512, height=424, fx=365.7, fy=365.4, cx=254.9, cy=205.4)


def _camera_on(
    side: float,
    *,
    height_m: float = 1.2,
    distance_m: float = 3.0,
    pitch_deg: float = 0.0,
    roll_deg: float = 0.0,
) -> np.ndarray:
    """A camera's world_from_view (OpenCV axes: x right, y down, z forward) standing ``distance_m`` from the
    trunk on the side ``side`` (-1: -y, 1: +y), looking at it, pitched up by ``pitch_deg`` and rolled
    clockwise (seen from behind) by ``roll_deg``."""
    forward = np.array([0.0, -side, 0.0])
    right = np.cross(forward, [0.0, 0.0, 1.0])
    pitch = np.radians(pitch_deg)
    forward_pitched = np.cos(pitch) * forward + np.sin(pitch) * np.array([0.0, 0.0, 1.0])
    down = np.cross(forward_pitched, right)
    roll = np.radians(roll_deg)
    right, down = np.cos(roll) * right + np.sin(roll) * down, np.cos(roll) * down - np.sin(roll) * right
    pose = np.eye(4)
    pose[:3, :3] = np.column_stack([right, down, forward_pitched])
    pose[:3, 3] = [0.0, side * distance_m, height_m]
    return pose


def _crown(top_m: float, *, count: int = 1_000_000, seed: int = 0) -> np.ndarray:
    """The surface of a ball of crown 1.5 m across whose top stands at ``top_m``, densely enough sampled
    that a camera 2-5 m away sees no hole in it."""
    rng = np.random.default_rng(seed)
    directions = rng.normal(size=(count, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return directions * 0.75 + [0.0, 0.0, top_m - 0.75]


def _column(
    bottom_m: float, top_m: float, radius_m: float, *, count: int = 100_000, seed: int = 1
) -> np.ndarray:
    """The surface of an upright cylinder round the trunk's axis: its wall and its top, densely sampled."""
    rng = np.random.default_rng(seed)
    wall_share = (top_m - bottom_m) / (top_m - bottom_m + radius_m / 2)
    on_wall = rng.random(count) < wall_share
    angle = rng.uniform(0.0, 2 * np.pi, count)
    radius = np.where(on_wall, radius_m, radius_m * np.sqrt(rng.random(count)))
    height = np.where(on_wall, rng.uniform(bottom_m, top_m, count), top_m)
    return np.column_stack([radius * np.cos(angle), radius * np.sin(angle), height])


def _view(
    scene: np.ndarray, name: str, side: float, *, max_depth_m: float = 8.0, **placement: float
) -> tuple[ViewFrame, np.ndarray]:
    """A view of the scene's points from ``side``: its frame, whose depth image reads at each pixel the
    nearest point's depth (0 where none), and the points it shows (each pixel's nearest: the rest are
    hidden or out of the image)."""
    pose = _camera_on(side, **placement)
    camera = (scene - pose[:3, 3]) @ pose[:3, :3]
    depth = camera[:, 2]
    ahead = depth > 0
    u = np.rint(KINECT.fx * camera[:, 0] / np.where(ahead, depth, 1.0) + KINECT.cx).astype(np.int64)
    v = np.rint(KINECT.fy * camera[:, 1] / np.where(ahead, depth, 1.0) + KINECT.cy).astype(np.int64)
    inside = np.flatnonzero(ahead & (u >= 0) & (u < KINECT.width) & (v >= 0) & (v < KINECT.height))
    pixel = v[inside] * KINECT.width + u[inside]
    order = np.lexsort((depth[inside], pixel))
    nearest = inside[order][np.r_[True, np.diff(pixel[order]) > 0]]
    image = np.zeros(KINECT.height * KINECT.width, dtype=np.float32)
    image[v[nearest] * KINECT.width + u[nearest]] = depth[nearest]
    frame = ViewFrame(
        name, KINECT, pose, max_depth_m=max_depth_m, depth_m=image.reshape(KINECT.height, KINECT.width)
    )
    return frame, scene[nearest]


def _cuts(views: list[tuple[ViewFrame, np.ndarray]], *, min_points: int = 5) -> set[tuple[str, str]]:
    found = frame_cuts(
        [points for _, points in views],
        [frame for frame, _ in views],
        margin_px=3.0,
        min_points=min_points,
        hidden_margin_m=0.1,
        up_within_deg=60.0,
    )
    return {(cut.view, cut.edge) for cut in found.across_views}


def test_a_crown_inside_every_frame_is_not_cut() -> None:
    crown = _crown(2.4)
    assert _cuts([_view(crown, "views/1", -1.0), _view(crown, "views/2", 1.0)]) == set()


def test_a_crown_above_both_frames_is_cut_at_their_top_edges() -> None:
    # A level camera 1.2 m up and 2.5 m away sees up to 1.2 + 2.5 tan(30 deg) = 2.6 m above the ground at
    # the trunk: a 3.6 m tree runs out of both images at the top.
    crown = _crown(3.6)
    views = [_view(crown, "views/1", -1.0, distance_m=2.5), _view(crown, "views/2", 1.0, distance_m=2.5)]
    assert _cuts(views) == {("views/1", "top"), ("views/2", "top")}
    found = frame_cuts(
        [points for _, points in views],
        [frame for frame, _ in views],
        margin_px=3.0,
        min_points=5,
        hidden_margin_m=0.1,
        up_within_deg=60.0,
    )
    assert "height_m" in cut_metrics(found.across_views) and "width_m" not in cut_metrics(found.across_views)


def test_a_view_that_frames_the_whole_tree_looks_beyond_where_another_is_cut() -> None:
    # views/1 stands close and level: the crown runs out of its image at the top. views/2 stands far and
    # pitched up: it frames the whole crown, so all of the crown's outline is in its image.
    crown = _crown(3.6)
    cut_view = _view(crown, "views/1", -1.0, distance_m=2.5)
    framing_view = _view(crown, "views/2", 1.0, distance_m=4.5, pitch_deg=12.0)
    assert _cuts([cut_view]) == {("views/1", "top")}
    assert _cuts([cut_view, framing_view]) == set()
    # Each view's own cuts, judged as if it were alone: views/1's top edge still cuts its own metrics.
    together = frame_cuts(
        [cut_view[1], framing_view[1]],
        [cut_view[0], framing_view[0]],
        margin_px=3.0,
        min_points=5,
        hidden_margin_m=0.1,
        up_within_deg=60.0,
    )
    assert [[(cut.edge, cut.facing) for cut in cuts] for cuts in together.by_view] == [[("top", "up")], []]


def test_two_views_cut_on_their_near_shoulders_do_not_excuse_each_other_behind_the_crown() -> None:
    # A flat-topped crown 1.5 m across up to 2.75 m, its leader on to 3.1 m; both cameras 3 m away and
    # 1.2 m up. Each image cuts the crown's near wall at about 2.5 m (its rim shows only at the sides),
    # and the wall hides the leader. Each view's image holds the other's cut wall (on its own far side,
    # lower in its view), but sees its own near wall in front of it there, not past it: the top is in
    # neither view, and the rim's 2.75 m would be read as H. Were the views reading nothing there (the open
    # sky), each would have looked beyond the other's cut.
    tree = np.vstack([_column(1.5, 2.75, 0.75, count=1_500_000), _column(2.75, 3.1, 0.03, count=5_000)])
    first, second = _view(tree, "views/1", -1.0), _view(tree, "views/2", 1.0)
    assert max(first[1][:, 2].max(), second[1][:, 2].max()) < 2.8
    assert _cuts([first, second]) == {("views/1", "top"), ("views/2", "top")}
    sky = [
        (replace(frame, depth_m=np.zeros_like(frame.depth_m)), points) for frame, points in (first, second)
    ]
    assert _cuts(sky) == set()


def test_a_second_view_cut_as_low_does_not_excuse_the_first() -> None:
    crown = _crown(3.6)
    views = [_view(crown, "views/1", -1.0, distance_m=2.5), _view(crown, "views/2", 1.0, distance_m=2.6)]
    assert {view for view, _ in _cuts(views)} == {"views/1", "views/2"}


def test_a_few_specks_at_the_edge_are_not_a_cut() -> None:
    frame, crown = _view(_crown(2.4), "views/1", -1.0)
    # Four points on the image's top edge, in front of the crown: flying pixels, not the tree.
    top_ray = np.array([0.0, -KINECT.cy / KINECT.fy, 1.0])
    specks = np.array(
        [
            frame.world_from_view[:3, :3] @ (top_ray * z) + frame.world_from_view[:3, 3]
            for z in (2.0, 2.1, 2.2, 2.3)
        ]
    )
    assert _cuts([(frame, np.vstack([crown, specks]))]) == set()
    assert frame_cuts(
        [np.vstack([crown, specks])],
        [frame],
        margin_px=3.0,
        min_points=4,
        hidden_margin_m=0.1,
        up_within_deg=60.0,
    ).across_views == (FrameCut("views/1", "top", "up", 4),)


def test_a_trunk_cut_at_the_bottom_edge_is_judged_on_the_crown_alone() -> None:
    # A camera pitched up 25 degrees: its bottom edge cuts the trunk below 0.9 m, not the crown.
    crown = _crown(3.0)
    trunk = _column(0.0, 1.0, 0.05, count=20_000)
    frame, seen = _view(np.vstack([trunk, crown]), "views/1", -1.0, distance_m=3.0, pitch_deg=25.0)
    crown_mask = seen[:, 2] > 1.0 + 1e-9
    assert _cuts([(frame, seen)]) == {("views/1", "bottom")}
    assert (
        frame_cuts(
            [seen],
            [frame],
            margin_px=3.0,
            min_points=5,
            hidden_margin_m=0.1,
            up_within_deg=60.0,
            bottom_masks=[crown_mask],
        ).across_views
        == ()
    )


def test_a_point_beyond_the_depth_range_is_not_looked_at() -> None:
    # The framing view stands farther than it reads: it cannot excuse the other view's cut.
    crown = _crown(3.6)
    cut_view = _view(crown, "views/1", -1.0, distance_m=2.5)
    far_view = _view(crown, "views/2", 1.0, distance_m=4.5, pitch_deg=12.0, max_depth_m=3.0)
    assert ("views/1", "top") in _cuts([cut_view, far_view])


@pytest.mark.parametrize("edge", ["left", "right"])
def test_a_crown_wider_than_the_frame_is_cut_at_its_sides(edge: str) -> None:
    # 1.6 m away, a Kinect v2 sees 2.2 m across at the trunk: a crown 1.5 m across, 0.6 m off centre,
    # leaves one side.
    shift = 0.6 if edge == "right" else -0.6
    crown = _crown(2.0) * [1.0, 1.0, 0.5] + [shift, 0.0, 0.5]
    view = _view(crown, "views/1", -1.0, distance_m=1.6)
    assert _cuts([view]) == {("views/1", edge)}
    found = frame_cuts(
        [view[1]], [view[0]], margin_px=3.0, min_points=5, hidden_margin_m=0.1, up_within_deg=60.0
    )
    assert "width_m" in cut_metrics(found.across_views) and "height_m" not in cut_metrics(found.across_views)


def test_a_camera_held_in_portrait_is_cut_at_the_image_side_that_faces_up() -> None:
    # Rolled a quarter turn, the image's left edge faces the sky: a tall tree runs out of it there, and
    # that cut makes H read short, not W.
    crown = _crown(3.6)
    view = _view(crown, "views/1", -1.0, distance_m=2.5, roll_deg=90.0)
    found = frame_cuts(
        [view[1]], [view[0]], margin_px=3.0, min_points=5, hidden_margin_m=0.1, up_within_deg=60.0
    )
    assert [(cut.edge, cut.facing) for cut in found.across_views] == [("left", "up")]
    assert "height_m" in cut_metrics(found.across_views) and "width_m" not in cut_metrics(found.across_views)


def test_two_views_cut_at_the_same_height_do_not_excuse_each_other_by_a_sliver() -> None:
    # Two level cameras 3 m away on either side see a 6 cm leader above a 2.4 m crown up to the same
    # height, 2.88 m, at the top edge of both images; its tip stands at 3.3 m. Moved beyond one view's edge,
    # the leader's points fall in the other's image only within its own edge band, where it too saw the
    # leader go on out of its image: no view looked beyond either cut. (A probe a sliver inside the other
    # image, read as its own leader within the hidden margin, let them excuse each other.)
    tree = np.vstack([_crown(2.4), _column(2.2, 3.3, 0.03, count=60_000)])
    views = [_view(tree, "views/1", -1.0), _view(tree, "views/2", 1.0)]
    assert max(points[:, 2].max() for _, points in views) < 2.9
    assert _cuts(views) == {("views/1", "top"), ("views/2", "top")}
