"""Where the tree runs out of the cameras' images (``canopy_core.framing``), on cameras built by hand."""

from __future__ import annotations

import numpy as np
import pytest

from canopy_core.capture import Intrinsics
from canopy_core.framing import FrameCut, ViewFrame, cut_metrics, frame_cuts

KINECT = Intrinsics(width=512, height=424, fx=365.0, fy=365.0, cx=256.0, cy=212.0)


def _camera_on(
    side: float, *, height_m: float = 1.2, distance_m: float = 3.0, pitch_deg: float = 0.0
) -> np.ndarray:
    """A level camera's world_from_view (OpenCV axes: x right, y down, z forward) standing ``distance_m``
    from the trunk on the side ``side`` (-1: -y, 1: +y), looking at it, pitched up by ``pitch_deg``."""
    forward = np.array([0.0, -side, 0.0])
    right = np.cross(forward, [0.0, 0.0, 1.0])
    pitch = np.radians(pitch_deg)
    forward_pitched = np.cos(pitch) * forward + np.sin(pitch) * np.array([0.0, 0.0, 1.0])
    down = np.cross(forward_pitched, right)
    pose = np.eye(4)
    pose[:3, :3] = np.column_stack([right, down, forward_pitched])
    pose[:3, 3] = [0.0, side * distance_m, height_m]
    return pose


def _frame(name: str, side: float, **placement: float) -> ViewFrame:
    return ViewFrame(name, KINECT, _camera_on(side, **placement), max_depth_m=8.0)


def _crown(top_m: float, *, seed: int = 0) -> np.ndarray:
    """A ball of crown points 1.5 m across whose top stands at ``top_m``."""
    rng = np.random.default_rng(seed)
    directions = rng.normal(size=(4000, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return directions * 0.75 + [0.0, 0.0, top_m - 0.75]


def _seen_by(points: np.ndarray, frame: ViewFrame) -> np.ndarray:
    """The points inside the frame's image (what the view shows of them)."""
    camera = (points - frame.world_from_view[:3, 3]) @ frame.world_from_view[:3, :3]
    u = KINECT.fx * camera[:, 0] / camera[:, 2] + KINECT.cx
    v = KINECT.fy * camera[:, 1] / camera[:, 2] + KINECT.cy
    inside = (camera[:, 2] > 0) & (u >= 0) & (u <= KINECT.width - 1) & (v >= 0) & (v <= KINECT.height - 1)
    return points[inside]


def test_a_crown_inside_every_frame_is_not_cut() -> None:
    frames = [_frame("views/1", -1.0), _frame("views/2", 1.0)]
    crown = _crown(2.4)
    cuts = frame_cuts([_seen_by(crown, f) for f in frames], frames, margin_px=3.0, min_points=5)
    assert cuts == ()


def test_a_crown_above_both_frames_is_cut_at_their_top_edges() -> None:
    # A level camera 1.2 m up and 2.5 m away sees up to 1.2 + 2.5 tan(30 deg) = 2.6 m above the ground
    # in the crown's near half: a 3.6 m tree runs out of both images at the top.
    frames = [_frame("views/1", -1.0, distance_m=2.5), _frame("views/2", 1.0, distance_m=2.5)]
    crown = _crown(3.6)
    cuts = frame_cuts([_seen_by(crown, f) for f in frames], frames, margin_px=3.0, min_points=5)
    assert {(cut.view, cut.edge) for cut in cuts} == {("views/1", "top"), ("views/2", "top")}
    assert "height_m" in cut_metrics(cuts) and "width_m" not in cut_metrics(cuts)


def test_a_view_that_looks_beyond_where_another_is_cut_leaves_no_cut() -> None:
    # views/1 stands close and level: the crown runs out of its image at the top. views/2 stands far and
    # pitched up: it frames the whole crown, and so looks beyond views/1's top edge wherever the crown
    # meets it.
    cut_view = _frame("views/1", -1.0, distance_m=2.5)
    framing_view = _frame("views/2", 1.0, distance_m=4.5, pitch_deg=12.0)
    crown = _crown(3.6)
    alone = frame_cuts([_seen_by(crown, cut_view)], [cut_view], margin_px=3.0, min_points=5)
    assert [(cut.view, cut.edge) for cut in alone] == [("views/1", "top")]
    together = frame_cuts(
        [_seen_by(crown, cut_view), _seen_by(crown, framing_view)],
        [cut_view, framing_view],
        margin_px=3.0,
        min_points=5,
    )
    assert together == ()


def test_a_second_view_cut_as_low_does_not_excuse_the_first() -> None:
    frames = [_frame("views/1", -1.0, distance_m=2.5), _frame("views/2", 1.0, distance_m=2.6)]
    crown = _crown(3.6)
    cuts = frame_cuts([_seen_by(crown, f) for f in frames], frames, margin_px=3.0, min_points=5)
    assert {cut.view for cut in cuts} == {"views/1", "views/2"}


def test_a_few_specks_at_the_edge_are_not_a_cut() -> None:
    frame = _frame("views/1", -1.0)
    crown = _seen_by(_crown(2.4), frame)
    # Four points exactly on the image's top edge, in front of the crown: flying pixels, not the tree.
    top_ray = np.array([0.0, -KINECT.cy / KINECT.fy, 1.0])
    specks = np.array(
        [
            frame.world_from_view[:3, :3] @ (top_ray * depth) + frame.world_from_view[:3, 3]
            for depth in (2.0, 2.1, 2.2, 2.3)
        ]
    )
    assert frame_cuts([np.vstack([crown, specks])], [frame], margin_px=3.0, min_points=5) == ()
    assert frame_cuts([np.vstack([crown, specks])], [frame], margin_px=3.0, min_points=4) == (
        FrameCut("views/1", "top", 4),
    )


def test_a_trunk_cut_at_the_bottom_edge_is_judged_on_the_crown_alone() -> None:
    # A camera pitched up 25 degrees: its bottom edge cuts the trunk below 0.5 m, not the crown.
    frame = _frame("views/1", -1.0, distance_m=3.0, pitch_deg=25.0)
    crown = _crown(3.0)
    trunk = np.column_stack([np.zeros(300), np.zeros(300), np.linspace(0.0, 1.0, 300)])
    seen_trunk, seen_crown = _seen_by(trunk, frame), _seen_by(crown, frame)
    both = np.vstack([seen_trunk, seen_crown])
    assert [cut.edge for cut in frame_cuts([both], [frame], margin_px=3.0, min_points=5)] == ["bottom"]
    assert frame_cuts([both], [frame], margin_px=3.0, min_points=5, bottom_points_by_view=[seen_crown]) == ()


def test_a_point_beyond_the_depth_range_is_not_looked_at() -> None:
    # The framing view stands farther than it reads: it cannot excuse the other view's cut.
    cut_view = _frame("views/1", -1.0, distance_m=2.5)
    far_view = ViewFrame("views/2", KINECT, _camera_on(1.0, distance_m=4.5, pitch_deg=12.0), max_depth_m=3.0)
    crown = _crown(3.6)
    cuts = frame_cuts(
        [_seen_by(crown, cut_view), _seen_by(crown, far_view)],
        [cut_view, far_view],
        margin_px=3.0,
        min_points=5,
    )
    assert ("views/1", "top") in {(cut.view, cut.edge) for cut in cuts}


@pytest.mark.parametrize("edge", ["left", "right"])
def test_a_crown_wider_than_the_frame_is_cut_at_its_sides(edge: str) -> None:
    # 1.2 m away, a Kinect v2 sees 1.7 m across: a crown 1.5 m across, 0.6 m off centre, leaves one side.
    frame = _frame("views/1", -1.0, distance_m=1.6)
    shift = 0.6 if edge == "right" else -0.6
    crown = _crown(2.0) * [1.0, 1.0, 0.5] + [shift, 0.0, 0.5]
    cuts = frame_cuts([_seen_by(crown, frame)], [frame], margin_px=3.0, min_points=5)
    assert [cut.edge for cut in cuts] == [edge]
    assert "width_m" in cut_metrics(cuts) and "height_m" not in cut_metrics(cuts)
