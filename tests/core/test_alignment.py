"""When the surfaces confirm a choice of balls made again that rests on a ball placed unseen
(``alignment._confirms_choice_made_again``), on hand-made choices and ICP reports: each clause of the rule
alone decides, so that none of them can be dropped unnoticed."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from canopy_core.alignment import Alignment, _confirms_choice_made_again
from canopy_core.ball_selection import BallChoice
from canopy_core.balls import BallCandidate
from canopy_core.config import IcpConfig
from canopy_core.ground import GroundFrame
from canopy_core.refine import AlignmentQuality, IcpRefinement
from canopy_core.spheres import SphereFit

CONFIG = IcpConfig()  # max_ball_shift_m 10 mm, max_rotation_deg 0.5, found by position 3.0 degrees
# Two balls 0.6 m apart in views/2 and a third beside them: at half their spacing, 10 mm is 1.91 degrees.
CENTRES = {"red": (0.0, 1.2, 3.0), "yellow": (0.6, 1.2, 3.0), "blue": (0.3, 1.2, 3.5)}


def _choice(view: str, *, unseen: tuple[str, ...] = (), by_position: tuple[str, ...] = ()) -> BallChoice:
    """A view's balls at ``CENTRES``, those of ``unseen`` placed unseen and ``by_position`` fragments."""
    chosen = {
        color: BallCandidate(
            fit=SphereFit(
                center_m=np.array(centre),
                radius_m=0.05,
                points=0 if color in unseen else 120,
                rms_m=0.002,
                coverage=0.95,
            ),
            expected_points=120.0,
            color_scores={color: 1.0},
            unseen=color in unseen,
        )
        for color, centre in CENTRES.items()
    }
    return BallChoice(
        view=view, chosen=chosen, rejected={}, found_by_position=by_position, placed_unseen=unseen
    )


def _report(view: str, *, shift_m: float, turn_deg: float) -> IcpRefinement:
    quality = AlignmentQuality(fitness=0.7, inlier_rmse_m=0.015, distance_p50_m=0.015, distance_p90_m=0.025)
    return IcpRefinement(
        view=view,
        accepted=True,
        reason="improved the median correspondence distance",
        before=quality,
        after=quality,
        translation_change_m=shift_m,
        rotation_change_deg=turn_deg,
        ball_shift_m=shift_m,
        ball_slide_m=shift_m,
        yaw_change_deg=turn_deg,
    )


def _alignment(choices: list[BallChoice], icp: list[IcpRefinement | None]) -> Alignment:
    ground = GroundFrame(
        world_from_reference=np.eye(4),
        ground_points=1000,
        ground_rms_m=0.01,
        tilt_from_ball_plane_deg=0.0,
        on_ground=True,
        ball_heights_m=(0.05, 0.05, 0.05),
        trunk_xy_m=(0.0, 0.0),
        trunk_points=100,
        ground_height_at_trunk_m=0.0,
        trunk_radius_m=0.06,
    )
    n = len(choices)
    return Alignment(
        choices=choices,
        view_to_reference=[np.eye(4)] * n,
        ground=ground,
        world_from_view=[np.eye(4)] * n,
        roi_points_m=[np.zeros((0, 3))] * n,
        roi_colors_rgb=[np.zeros((0, 3), dtype=np.uint8)] * n,
        stray_points_removed=[0] * n,
        icp=icp,
    )


def _two_views(
    report: IcpRefinement | None, *, by_position: tuple[str, ...] = (), unseen: tuple[str, ...] = ("blue",)
) -> Alignment:
    return _alignment(
        [_choice("views/1"), _choice("views/2", unseen=unseen, by_position=by_position)], [None, report]
    )


def test_a_ball_placed_unseen_is_confirmed_when_icp_keeps_the_two_shared_balls_within_their_fits() -> None:
    assert _confirms_choice_made_again(_two_views(_report("views/2", shift_m=0.006, turn_deg=1.8)), CONFIG)


@pytest.mark.parametrize(
    ("shift_m", "turn_deg"),
    [(0.012, 0.2), (0.004, 2.0)],
    ids=["balls moved beyond their fits", "turned beyond 10 mm at half their spacing"],
)
def test_a_ball_placed_unseen_is_refused_when_icp_moves_or_turns_the_view_beyond_the_two_balls(
    shift_m: float, turn_deg: float
) -> None:
    assert not _confirms_choice_made_again(
        _two_views(_report("views/2", shift_m=shift_m, turn_deg=turn_deg)), CONFIG
    )


def test_balls_close_together_leave_no_more_turn_open_than_a_fragment_s_pose() -> None:
    """Two balls 0.2 m apart would leave 5.7 degrees open at 10 mm: the turn stays within 3 degrees."""
    close = _two_views(_report("views/2", shift_m=0.002, turn_deg=3.5))
    near = {"red": np.array([0.0, 1.2, 3.0]), "yellow": np.array([0.2, 1.2, 3.0])}
    for choice in close.choices:
        for color, centre in near.items():
            choice.chosen[color] = replace(
                choice.chosen[color], fit=replace(choice.chosen[color].fit, center_m=centre)
            )
    assert not _confirms_choice_made_again(close, CONFIG)
    assert _confirms_choice_made_again(
        replace(close, icp=[None, _report("views/2", shift_m=0.002, turn_deg=2.9)]), CONFIG
    )


def test_a_ball_placed_unseen_is_refused_beside_a_fragment_with_one_shared_ball_or_without_icp() -> None:
    sound = _report("views/2", shift_m=0.002, turn_deg=0.2)
    assert not _confirms_choice_made_again(_two_views(sound, by_position=("red",)), CONFIG)
    one_shared = _alignment(
        [_choice("views/1", unseen=("red",)), _choice("views/2", unseen=("blue",))], [None, sound]
    )
    assert not _confirms_choice_made_again(one_shared, CONFIG)
    assert not _confirms_choice_made_again(_two_views(None), CONFIG)


def test_a_ball_placed_unseen_is_refused_when_another_view_rests_on_a_fragment() -> None:
    """views/2 places its blue ball unseen and shares red and yellow; views/3 shares them too, but holds
    its blue ball only as a fragment: however closely ICP confirms both, the choice is refused."""
    choices = [
        _choice("views/1"),
        _choice("views/2", unseen=("blue",)),
        _choice("views/3", by_position=("blue",)),
    ]
    sound = [
        None,
        _report("views/2", shift_m=0.002, turn_deg=0.2),
        _report("views/3", shift_m=0.002, turn_deg=0.2),
    ]
    assert not _confirms_choice_made_again(_alignment(choices, sound), CONFIG)
    assert _confirms_choice_made_again(_alignment([*choices[:2], _choice("views/3")], sound), CONFIG)


def test_a_view_whose_reference_places_a_ball_unseen_may_turn_as_far_as_their_shared_pair_leaves_open() -> (
    None
):
    """The reference view places its blue ball unseen; views/2 fits all three, but only red and yellow hold
    it to the reference: 1.0 degree is within the 1.9 degrees those two leave open."""
    choices = [_choice("views/1", unseen=("blue",)), _choice("views/2")]
    assert _confirms_choice_made_again(
        _alignment(choices, [None, _report("views/2", shift_m=0.004, turn_deg=1.0)]), CONFIG
    )


def test_a_third_view_sharing_every_ball_keeps_a_sound_registration_s_turn() -> None:
    """views/2 places its blue ball unseen; views/3 fits all three, as the reference does: it may turn
    0.5 degrees, not the 1.9 degrees views/2's pair leaves open."""
    choices = [_choice("views/1"), _choice("views/2", unseen=("blue",)), _choice("views/3")]
    held = _report("views/2", shift_m=0.004, turn_deg=1.0)
    assert _confirms_choice_made_again(
        _alignment(choices, [None, held, _report("views/3", shift_m=0.004, turn_deg=0.4)]), CONFIG
    )
    assert not _confirms_choice_made_again(
        _alignment(choices, [None, held, _report("views/3", shift_m=0.004, turn_deg=1.0)]), CONFIG
    )


def test_a_choice_of_balls_every_view_shows_keeps_a_sound_registration_s_bounds() -> None:
    """Without a ball placed unseen the rule is the old one: 0.5 degrees, not the pair's 1.9."""
    assert not _confirms_choice_made_again(
        _two_views(_report("views/2", shift_m=0.004, turn_deg=1.0), unseen=()), CONFIG
    )
