"""The whole pipeline on captures where look-alikes of the balls (apples, straw, fragments of clutter) could
be chosen: refused by the ground, the trunk and the surfaces, and the balls chosen again or the capture
refused naming the view (cases the accuracy benchmark found)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from canopy_core.alignment import align_views, check_trunk_agreement
from canopy_core.ball_selection import balls_off_trunk, far_ball
from canopy_core.capture import load_capture
from canopy_core.errors import RegistrationFailed
from canopy_core.measure import config_for, measure, view_evidence
from canopy_core.simulate import simulate_capture
from tests.core.measured import assert_balls_true, assert_within_5_percent, ball_error_m, truth_of


def test_a_triangle_closed_on_the_trunk_fails_instead_of_measuring_a_wrong_tree(tmp_path: Path) -> None:
    """Mixed seed 2031025, found by the accuracy benchmark: the yellow ball is hidden in the second view,
    and the trunk, fitted as a sphere at a different height in each view, made a triangle of the right sides
    with the red and blue balls. Registered on it, the views met 33 degrees apart, and H, W and D came out
    14-34 % off with no error. The ground and trunk, which the views share, contradict that pose: the
    registration fails naming the view, or (should the yellow ball be found) the tree is measured right."""
    capture = simulate_capture(tmp_path / "tree", seed=2031025, n_views=2, scenario="mixed")
    truth = truth_of(capture)
    try:
        merged = measure(capture).merged
    except RegistrationFailed as failure:
        assert failure.view == "views/2" and "line up only" in failure.message
        return
    assert_within_5_percent(merged, truth)


def test_an_apple_both_views_take_for_a_ball_is_dropped_and_the_ball_sought_where_placed(
    tmp_path: Path,
) -> None:
    """Mixed seed 2032000, found by the accuracy benchmark: the red ball is hidden in tall grass in the
    first view, and a red apple lying on the ground 1.95 m from the trunk, which both views see, agrees with
    itself across views. Centred on that triangle, the region of interest cut the crown: W came out 10 %
    short with no error. The crew lays the balls 0.3-0.8 m from the trunk, so the apple is dropped and the
    red ball sought where the other balls place it: the tree is measured right."""
    capture = simulate_capture(tmp_path / "tree", seed=2032000, n_views=2, scenario="mixed")
    truth = truth_of(capture)
    result = measure(capture)
    assert "red" in result.views[0].balls_found_by_position
    assert_within_5_percent(result.merged, truth)


def test_a_heap_of_apples_far_from_the_trunk_is_dropped_whole_and_the_true_ball_chosen(
    tmp_path: Path,
) -> None:
    """Mixed seed 2040027, found by the accuracy benchmark: red apples lie on the ground 2.4 m from the
    trunk, and both views fit spheres to them several times (an apple, its neighbour, the two together);
    each pair agrees with itself across views. Dropping only the sphere chosen left the next fit of the same
    heap to be chosen, and the capture failed though the red ball lay in plain view of both cameras. Every
    sphere as far from the trunk is dropped now, and the true red ball is chosen in both views."""
    capture = simulate_capture(tmp_path / "tree", seed=2040027, n_views=2, scenario="mixed")
    truth = truth_of(capture)
    result = measure(capture)
    assert_balls_true(result, truth, ("red",))
    assert_within_5_percent(result.merged, truth)


def test_balls_chosen_again_away_from_a_post_that_a_look_alike_made_the_trunk(tmp_path: Path) -> None:
    """Mixed seed 2122047, found by the accuracy benchmark: each view took a bump of brown soil 2.4 m from
    the trunk for the red ball, found where the other's put it, and the triangles agreed. Round those balls
    the trellis post 1.8 m from the tree stood nearer their centre than the trunk and was taken for it; the
    true balls lay 1.1-1.9 m from the post, so choosing again among the spheres round it found none and
    the capture failed, though both views show the red ball (one whole, one in part behind the trunk).
    When no choice round the trunk holds, each ball's sphere is now ruled out in turn with the spheres
    anywhere kept (the ball named, blue, a true one, last): the true balls are chosen, round the true
    trunk, and the tree is measured right."""
    capture = simulate_capture(tmp_path / "tree", seed=2122047, n_views=2, scenario="mixed")
    truth = truth_of(capture)
    result = measure(capture)
    assert_balls_true(result, truth)
    assert_within_5_percent(result.merged, truth)


def test_a_ball_far_from_the_trunk_is_named_with_every_ball_s_distance() -> None:
    centres = np.array([[2.0, 0.1, 0.05], [0.5, 0.2, 0.05], [-0.3, -0.4, 0.05]])
    colors = ["red", "yellow", "blue"]
    assert far_ball(centres[1:], np.zeros(2), colors[1:], 1.2) is None
    assert far_ball(centres, np.zeros(2), colors, 1.2) == "red"
    failure = balls_off_trunk(centres, np.zeros(2), colors, "red")
    assert failure.field == "balls.max_trunk_distance_m"
    assert "red ball was found 2.00 m from the trunk (yellow 0.54 m, blue 0.50 m)" in failure.message


def test_a_ball_placed_unseen_among_look_alikes_fails_where_the_surfaces_do_not_confirm_it(
    tmp_path: Path,
) -> None:
    """Mixed seed 2051009, found on a held-out run of the accuracy benchmark: views/1 took a yellow
    look-alike, views/2 a blue fragment 2 m off where that placed it, and views/1's red ball was placed
    unseen 1.2 m off: the triangles closed, ICP wanted 3.1 degrees more than such a pose leaves open, and
    W came out 75 % wide with no error. A pose resting on a ball placed unseen must be confirmed by the
    surfaces; chosen again (views/2's red ball placed unseen), ICP moves the balls 24 mm and turns the view
    2.3 degrees, more than the two fitted balls 1.26 m apart leave open: the capture fails naming the view."""
    capture = simulate_capture(tmp_path / "tree", seed=2051009, n_views=2, scenario="mixed")
    with pytest.raises(RegistrationFailed, match="not seen in this view") as info:
        measure(capture)
    assert info.value.view == "views/1"


def test_a_pose_resting_on_fragments_fails_where_the_surfaces_do_not_confirm_it(tmp_path: Path) -> None:
    """Mixed seed 2053020, found on a held-out run of the accuracy benchmark, where the views share only the
    blue ball fitted as a sphere in both: each view took one look-alike and a fragment where the other's
    triangle put it; ICP wanted 5.1 degrees, W 5 % off. Held by one ball both views fit, like a view with a
    ball placed unseen, the pose must be confirmed by the surfaces, and here it is not."""
    capture = simulate_capture(tmp_path / "tree", seed=2053020, n_views=2, scenario="mixed")
    with pytest.raises(RegistrationFailed, match="both fit only the blue ball") as info:
        measure(capture)
    assert info.value.view == "views/2"


def test_a_choice_made_again_that_makes_the_trunks_coincide_stands_though_icp_moves_its_balls(
    tmp_path: Path,
) -> None:
    """Mixed seed 2054014, found on a held-out run of the accuracy benchmark: views/1 took a yellow
    look-alike, and views/2's red and yellow balls were taken as fragments 1.2-1.8 m off where that
    triangle put them; W came out 12 % wide, and from 2026-11-27 the capture failed (the pose, held by the
    blue ball alone, was not confirmed by the surfaces). With that yellow ruled out the true balls are
    chosen (views/2's red placed unseen where views/1's balls put it): ICP moves them 12 mm and turns the
    view 1.5 degrees, beyond what a pose resting on a ball placed unseen may, so that choice did not stand;
    but the trunk each view finds on its own stands at one place under it, and it is taken."""
    capture = simulate_capture(tmp_path / "tree", seed=2054014, n_views=2, scenario="mixed")
    truth = truth_of(capture)
    result = measure(capture)
    assert result.views[1].balls_placed_unseen == ("red",)
    assert_balls_true(result, truth, within_m=0.03)  # the ball placed unseen: 2 cm
    assert_within_5_percent(result.merged, truth)


def test_a_look_alike_both_views_see_loses_to_the_ball_for_what_it_shows_behind_it(tmp_path: Path) -> None:
    """Mixed seed 2118004 (a tuning set): both views show the red ball whole and, 0.2 m from the blue ball,
    a fallen red apple 85 mm across, fitted with a radius of 48-52 mm; both views see it, so its triangle
    agrees too. The ball, fitted at 45-46 mm (mixed pixels at a far ball's rim shrink it), led in views/1
    and lost in views/2 on its radius, 0.018 behind in the total score; the apple's sphere shows what lies
    behind it through its outline (coverage 0.90 and 0.64 against the ball's 0.96 and 0.85), and with
    coverage in the score the ball is chosen in both views (the apple, 105 cm off, before; ICP had measured
    the tree right regardless)."""
    capture = simulate_capture(tmp_path / "tree", seed=2118004, n_views=2, scenario="mixed")
    truth = truth_of(capture)
    result = measure(capture)
    assert_balls_true(result, truth)
    assert_within_5_percent(result.merged, truth)


def test_balls_resting_on_a_hollow_floor_are_kept_though_their_plane_tilts(tmp_path: Path) -> None:
    """Mixed seed 2045008, found by the accuracy benchmark: the blue ball lies in a hollow 8 cm below the
    others, so the balls' plane tilts 15-17 degrees from the ground round them, past the limit that tells a
    fallen apple taken for a ball; the true red ball was refused as lying off the ground and an apple 64 cm
    away taken instead (green: the registration failed). Each ball stands one radius above the floor right
    round it, so the balls are kept and the frame stands on the ground."""
    capture = simulate_capture(tmp_path / "tree", seed=2045008, n_views=2, scenario="mixed")
    truth = truth_of(capture)
    result = measure(capture)
    assert result.ground.on_ground and result.ground.tilt_from_ball_plane_deg > 15.0
    assert_balls_true(result, truth)
    assert_within_5_percent(result.merged, truth)


def test_a_ball_in_deep_shade_is_found_by_its_shape(tmp_path: Path) -> None:
    """Mixed seed 2033034, found by the accuracy benchmark: in views/2 the yellow ball lies whole in view in
    the crown's shadow, read as RGB 16, 14, 2: its hue is the ball's, its brightness too low for its colour
    range, so none of its points voted for a sphere. Dark points of its hue in the floor's band vote too:
    the ball is found as a sphere of its own, and the capture, which failed, is measured on the right
    balls."""
    capture = simulate_capture(tmp_path / "tree", seed=2033034, n_views=2, scenario="mixed")
    truth = truth_of(capture)
    result = measure(capture)
    assert "yellow" not in result.views[1].balls_found_by_position
    assert_balls_true(result, truth)
    assert_within_5_percent(result.merged, truth)


def test_balls_chosen_again_when_the_first_choice_lies_off_the_ground(tmp_path: Path) -> None:
    """Mixed seed 2036042, found by the accuracy benchmark: each view misses a different ball and took a
    fragment where the other view's look-alike placed it; one, fitted at ground level, tilted the balls'
    plane. Chosen
    again without it, the views register on spheres both see, and the tree is measured right (it came out
    with D 161 % off)."""
    capture = simulate_capture(tmp_path / "tree", seed=2036042, n_views=2, scenario="mixed")
    assert_within_5_percent(measure(capture).merged, truth_of(capture))


def test_balls_nearly_in_a_line_that_the_surfaces_turn_by_degrees_are_sought_again_about_the_shared_ball(
    tmp_path: Path,
) -> None:
    """Mixed seed 2037022, found by the accuracy benchmark: views/1 took two fragments of clutter for the
    red and yellow balls, and views/2 a look-alike for the yellow one in line with its other two; the
    triangles agreed, ICP would turn views/2 by 15 degrees (moving its balls only 35 mm), and W came out
    74 % wide with no error; from 2026-11-25 the registration failed, naming the view. Since 2026-11-27
    (seventh) the surfaces' refusal makes the balls be sought again about the blue ball both views show:
    at one turn about it, views/1's red ball and, in views/2, the yellow sphere 23 cm from the yellow ball
    that views/1 took for it too (a look-alike both views see at one place, a fixed point) are found
    together, and that choice passes the bounds of a sound registration: the tree is measured right."""
    capture = simulate_capture(tmp_path / "tree", seed=2037022, n_views=2, scenario="mixed")
    truth = truth_of(capture)
    result = measure(capture)
    assert result.views[0].balls_found_by_position == ("red",)
    assert result.views[1].balls_found_by_position == ("yellow",)
    assert ball_error_m(result, truth, "views/1", "red") < 0.02
    assert ball_error_m(result, truth, "views/2", "blue") < 0.02
    assert_within_5_percent(result.merged, truth)


def test_a_look_alike_the_surfaces_contradict_is_ruled_out_and_the_balls_chosen_again(tmp_path: Path) -> None:
    """Mixed seed 2042018, found by the accuracy benchmark: both views took red apples 55-59 cm from the red
    ball for it, whose triangles agreed with the yellow and blue balls; the views' ground and trunk line
    up only with views/2's balls moved by 97 mm and the view turned 22 degrees, and the capture failed,
    though both views show the red ball. Each of views/2's balls is ruled out in turn and the balls chosen
    again: without the apple, the true red ball is chosen in both views and the tree is measured right."""
    capture = simulate_capture(tmp_path / "tree", seed=2042018, n_views=2, scenario="mixed")
    truth = truth_of(capture)
    result = measure(capture)
    assert_balls_true(result, truth, ("red",))
    assert_within_5_percent(result.merged, truth)


def test_look_alikes_in_both_views_that_agree_by_chance_are_refused_and_the_balls_both_fit_hold_the_views(
    tmp_path: Path,
) -> None:
    """Weeds seed 2066007, found on a held-out run of the accuracy benchmark: each view took fragments round
    weeds and straw for all three balls, the triangles agreed by chance, and the views were registered 35
    degrees and 4 m apart. ICP, lining up flat ground, moved the balls by 13 mm and passed it, and W came
    out 72 % wide with no error. The trunk's agreement refuses that choice; then every choice made again
    failed ICP's bounds, one resting on views/2's red ball placed unseen among them, and the capture failed
    naming views/2. That choice holds views/2 by the yellow and blue balls both views fit as spheres, which
    ICP moves 5 mm and turns 0.5 degrees, within what two balls 1.2 m apart leave open: it is taken, and
    the tree is measured right, though views/1's red sphere is a look-alike a third of a metre from its ball
    (a ball placed unseen holds no view in ICP, and the one it pairs with holds none either)."""
    capture = simulate_capture(tmp_path / "tree", seed=2066007, n_views=2, scenario="weeds")
    truth = truth_of(capture)
    result = measure(capture)
    assert result.views[1].balls_placed_unseen == ("red",)
    assert_balls_true(result, truth, ("yellow", "blue"))
    assert_within_5_percent(result.merged, truth)


def test_a_registration_that_leaves_the_views_round_different_trunks_fails_naming_the_view(
    tmp_path: Path,
) -> None:
    """The trunk's agreement, on its own: a sound registration passes it; the same with views/2 carried
    1 m along the row (its trunk's foot 1 m from views/1's, and no trunk at views/1's foot) fails naming
    views/2, as a registration on look-alikes that ICP cannot see through does."""
    capture = load_capture(simulate_capture(tmp_path / "tree", seed=1, n_views=2))
    config = config_for(capture.manifest, None)
    evidence = view_evidence(capture.views, config)
    clouds, grounds = [view.cloud for view in evidence], [view.ground for view in evidence]
    candidates = [view.balls for view in evidence]
    alignment = align_views(
        [view.name for view in capture.views],
        clouds,
        [view.camera.depth.fx for view in capture.views],
        candidates,
        grounds,
        config,
    )
    check_trunk_agreement(alignment, clouds, grounds, config)
    along_row = np.eye(4)
    along_row[0, 3] = 1.0
    moved = replace(
        alignment, world_from_view=[alignment.world_from_view[0], along_row @ alignment.world_from_view[1]]
    )
    with pytest.raises(
        RegistrationFailed, match=r"sees the trunk (0\.9\d|1\.0\d) m from where views/1 sees it"
    ) as info:
        check_trunk_agreement(moved, clouds, grounds, config)
    assert info.value.field == "icp.max_trunk_mismatch_m"
    assert info.value.view == "views/2"


def test_views_whose_best_trunk_circles_differ_register_when_each_sees_a_trunk_at_the_other_s(
    tmp_path: Path,
) -> None:
    """Mixed seed 2067013, a tuning tree of the trunk agreement: on a sound registration the trunk circle
    views/2 finds best stands 0.73 m from views/1's (one of them is not the trunk), so the first rule,
    comparing only those, refused the true balls and a retry took a red look-alike 1.4 m off. Each view
    holds a trunk's circle at the other's foot: the true balls are kept."""
    capture = simulate_capture(tmp_path / "tree", seed=2067013, n_views=2, scenario="mixed")
    truth = truth_of(capture)
    result = measure(capture)
    assert_balls_true(result, truth)
    assert_within_5_percent(result.merged, truth)


def test_a_first_choice_whose_trunks_stand_apart_gives_way_to_balls_the_surfaces_confirm_better(
    tmp_path: Path,
) -> None:
    """Mixed seed 2126017, found on a held-out run of the accuracy benchmark: only the blue ball was right in
    both views, the red and yellow look-alikes 0.6-1.7 m off whose triangles agreed; ICP moved the balls
    16 mm (within bounds) and the trunk each view found stood 0.70 m from the other's, each view holding a
    tuft within 0.4 m of the other's foot, so every check passed and W came out 27 % narrow, the views
    registered 52 degrees from their true poses. Trunks apart, the first choice is weighed against those
    made with each ball ruled out: with a red look-alike ruled out, the true red and blue balls are found
    (the yellow a look-alike 1.2 m off that both views agree on), ICP moves them 2 mm, and they are
    taken."""
    capture = simulate_capture(tmp_path / "tree", seed=2126017, n_views=2, scenario="mixed")
    truth = truth_of(capture)
    result = measure(capture)
    assert_balls_true(result, truth, ("red", "blue"))
    assert_within_5_percent(result.merged, truth)


def test_look_alikes_beside_a_post_give_way_to_the_true_balls_whose_trunks_coincide(tmp_path: Path) -> None:
    """Near-posts seed 2125048, found on a held-out run of the accuracy benchmark: views/1 took look-alikes
    for the red and yellow balls, the views met 147 degrees from their true poses, ICP moved the balls
    47 mm (inside the 50 mm a first choice may), and each view held a trunk-sized circle (a post, weeds)
    within 0.4 m of the other's foot, the feet 0.84 m apart: W came out 40 % wide with no error. With
    either look-alike ruled out the true balls are found (views/1's red placed unseen where views/2's put
    it), the trunks 4 mm apart; ICP moves them 25 mm, short of a first choice's bound though beyond what a
    pose resting on a ball placed unseen may, and the surfaces contradict them half as much: they are
    taken."""
    capture = simulate_capture(tmp_path / "tree", seed=2125048, n_views=2, scenario="mixed", near_posts=True)
    truth = truth_of(capture)
    result = measure(capture)
    assert result.views[0].balls_placed_unseen == ("red",)
    assert_balls_true(result, truth, within_m=0.04)  # the ball placed unseen: 3.3 cm
    assert_within_5_percent(result.merged, truth)
