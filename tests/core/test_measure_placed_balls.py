"""The whole pipeline on captures where a view does not show a ball as a sphere of its own: the ball is
sought or placed where the other view's balls, the ground and the trunk put it (cases the accuracy
benchmark found)."""

from __future__ import annotations

from pathlib import Path

from canopy_core.measure import measure
from canopy_core.simulate import simulate_capture
from tests.core.measured import assert_balls_true, assert_within_5_percent, ball_error_m, truth_of


def test_a_far_ball_mostly_hidden_is_found_where_the_other_view_places_it(tmp_path: Path) -> None:
    """Mixed seed 2031004: views/1 sees the blue ball 4.5 m away with two thirds of it hidden, a dozen
    points whose free radius runs to twice the ball's. Judged on a sphere of that radius, its outline took
    in the ground behind and the ball was refused (38 % coverage), so the capture failed; judged on the
    known ball's outline where the other view places it, it is found, and the tree is measured."""
    capture = simulate_capture(tmp_path / "tree", seed=2031004, n_views=2, scenario="mixed")
    truth = truth_of(capture)
    result = measure(capture)
    assert "blue" in result.views[0].balls_found_by_position
    assert_within_5_percent(result.merged, truth)


def _assert_placed_and_measured(tmp_path: Path, *, seed: int, view: str, color: str) -> None:
    """The mixed capture of ``seed`` is measured right, with its ``color`` ball in ``view`` found where the
    other view places it, within 2 cm of the true ball."""
    capture = simulate_capture(tmp_path / "tree", seed=seed, n_views=2, scenario="mixed")
    truth = truth_of(capture)
    result = measure(capture)
    assert color in next(v for v in result.views if v.view == view).balls_found_by_position
    assert ball_error_m(result, truth, view, color) < 0.02
    assert_within_5_percent(result.merged, truth)


def test_each_view_missing_another_ball_finds_it_round_the_one_both_see(tmp_path: Path) -> None:
    """Mixed seed 2033035, found by the accuracy benchmark: views/1 shows its yellow ball in deep shade and
    views/2 half its red ball, neither as a sphere of its own; each view's likeliest spheres of those
    colours are apples and straw. Only the blue ball is found in both, so no view has a whole triangle to
    place the others. Each missing ball is sought on the circle round the blue ball at the distance the
    other view shows, even where look-alikes of its colour were found: the capture failed, now it is
    measured on the right balls."""
    capture = simulate_capture(tmp_path / "tree", seed=2033035, n_views=2, scenario="mixed")
    truth = truth_of(capture)
    result = measure(capture)
    assert "yellow" in result.views[0].balls_found_by_position
    assert "red" in result.views[1].balls_found_by_position
    assert_balls_true(result, truth)
    assert_within_5_percent(result.merged, truth)


def test_views_sharing_one_ball_place_the_others_round_it_by_the_trunk(tmp_path: Path) -> None:
    """Mixed seed 2036035, found by the accuracy benchmark: views/1 sees its red and yellow balls well,
    views/2 its red and blue; each view's third ball is a third clear 3.7-4.3 m away, where grass and leaves
    outscore it all along the circle round the red ball, and the capture failed naming views/1's blue ball.
    The red ball, the ground and the trunk each view sees fix views/2's yellow ball to one place, where its
    fragment is found; the triangle then places views/1's blue."""
    _assert_placed_and_measured(tmp_path, seed=2036035, view="views/2", color="yellow")


def test_a_ball_hidden_in_one_view_is_placed_unseen_when_the_balls_are_chosen_again(tmp_path: Path) -> None:
    """Mixed seed 2090041, found on a held-out run of the accuracy benchmark: views/2's blue ball lies
    4.6 m away, two thirds hidden; three fragments of clutter closed a triangle at views/1's distances, and
    the ground and trunk refused it (the balls moved 92 mm). Chosen again without one of them, views/2's red
    and yellow balls are fitted as spheres and the blue placed unseen where views/1's triangle puts it;
    ICP moves the two balls 6 mm and turns the view 0.8 degrees, within what balls 0.59 m apart leave open.
    The capture failed, refusing every choice made again that rests on a ball placed unseen; now it is
    measured on the right balls."""
    capture = simulate_capture(tmp_path / "tree", seed=2090041, n_views=2, scenario="mixed")
    truth = truth_of(capture)
    result = measure(capture)
    assert result.views[1].balls_placed_unseen == ("blue",)
    for color in ("red", "yellow"):
        assert ball_error_m(result, truth, "views/2", color) < 0.02, color
    assert_within_5_percent(result.merged, truth)


def test_a_ball_is_carried_round_the_trunk_from_every_likely_sphere_of_the_shared_colour(
    tmp_path: Path,
) -> None:
    """Mixed seed 2048017, found by the accuracy benchmark: the views share only the yellow ball, and in
    each a look-alike outscores it; the trunk circle found round views/1's look-alike lay 27 cm from the
    trunk, so the balls' distances from it disagreed, nothing was carried and the capture failed naming
    views/1's blue ball. Every likely yellow sphere is tried in both views: the true pair places views/2's
    red fragment and views/1's blue."""
    capture = simulate_capture(tmp_path / "tree", seed=2048017, n_views=2, scenario="mixed")
    truth = truth_of(capture)
    result = measure(capture)
    assert result.views[0].balls_found_by_position == ("blue",)
    assert result.views[1].balls_found_by_position == ("red",)
    assert_balls_true(result, truth)
    assert_within_5_percent(result.merged, truth)


def test_a_ball_no_view_holds_a_sphere_of_is_found_where_both_views_fragments_meet(tmp_path: Path) -> None:
    """Mixed seed 2045012, found by the accuracy benchmark: each view sees about 40 % of the blue ball, 4 m
    away, and neither holds a sphere of it (views/1's red ball, outranked by apples, is found on the circle
    round its yellow one); with no triangle anywhere the capture failed naming views/1's blue ball. Each
    place views/1's blue points gather is carried onto views/2 by the red and yellow balls both show and
    the ground's up, and a sphere is found at both ends."""
    capture = simulate_capture(tmp_path / "tree", seed=2045012, n_views=2, scenario="mixed")
    truth = truth_of(capture)
    result = measure(capture)
    for view in result.views:
        assert "blue" in view.balls_found_by_position, view.view
        assert ball_error_m(result, truth, view.view, "blue") < 0.03, view.view
    assert_within_5_percent(result.merged, truth)


def test_a_ball_is_placed_by_the_other_view_s_triangle_carried_onto_this_view_s_ground(
    tmp_path: Path,
) -> None:
    """Mixed seed 2029047, found by the accuracy benchmark: views/2 shows 15 points of its red ball. Placed
    by the other view's triangle at the height that view's ground gives it, the guess fell 7 cm off the
    ball and nothing was found there; a red apple on the ground that both views see was taken instead, 1.4 m
    from the trunk. Carried rigidly by the pair of balls and the ground's up, the triangle puts the ball
    within a centimetre or two, where its fragment is found."""
    _assert_placed_and_measured(tmp_path, seed=2029047, view="views/2", color="red")


def test_a_ball_is_placed_from_every_likely_pair_not_only_the_two_likeliest(tmp_path: Path) -> None:
    """Mixed seed 2033015, found by the accuracy benchmark: views/1 shows a third of its blue ball. The
    other view's triangle places it from this view's red and yellow balls, but two look-alikes of the
    yellow ball scored above the yellow ball itself, and only the two likeliest were paired."""
    _assert_placed_and_measured(tmp_path, seed=2033015, view="views/1", color="blue")


def test_a_ball_is_placed_by_every_triangle_of_the_other_view_not_only_its_likeliest(tmp_path: Path) -> None:
    """Mixed seed 2034000, found by the accuracy benchmark: views/2 sees its blue ball 4.3 m away and nearly
    black, no sphere of its own. views/1 has all three balls, but apples and straw scored above its red and
    yellow balls, so its two likeliest triangles each held a look-alike and placed the blue ball wrong;
    the capture failed naming views/2 and blue. Every triangle of views/1 places it now."""
    _assert_placed_and_measured(tmp_path, seed=2034000, view="views/2", color="blue")


def test_a_ball_one_view_does_not_show_is_placed_by_the_two_it_shows_and_the_ground(tmp_path: Path) -> None:
    """Mixed seed 2036059, found by the accuracy benchmark: the red ball is hidden in views/2, and both
    views took a fallen apple 12 cm from the yellow ball for it. The triangles agreed (it is one object),
    but the balls' plane tilted 34 degrees from the ground and W came out 23.5 % narrow with no error;
    refusing the apple then failed the capture, as no other red sphere rests on the ground. views/2's
    yellow and blue balls and its ground's up carry views/1's triangle onto it: the red ball is placed
    there, unseen (views/2 does not see through that place), within 2 cm, and the tree is measured right."""
    capture = simulate_capture(tmp_path / "tree", seed=2036059, n_views=2, scenario="mixed")
    truth = truth_of(capture)
    result = measure(capture)
    second = next(v for v in result.views if v.view == "views/2")
    assert second.balls_placed_unseen == ("red",) and second.balls["red"].points == 0
    assert_balls_true(result, truth)
    assert_within_5_percent(result.merged, truth)
