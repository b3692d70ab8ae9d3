"""The whole pipeline on simulated captures: metrics against ground truth, modes, stages, failures."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from canopy_core.alignment import align_views, check_trunk_agreement
from canopy_core.backproject import ViewCloud
from canopy_core.ball_selection import balls_off_trunk, far_ball
from canopy_core.capture import load_capture
from canopy_core.config import MeasureConfig
from canopy_core.errors import BallNotFound, MeasurementError, RegistrationFailed
from canopy_core.measure import (
    STAGES,
    Measurement,
    _beyond_roi_points,
    ball_evidence,
    config_for,
    filtered_cloud,
    measure,
)
from canopy_core.metrics import CanopyMetrics
from canopy_core.register import apply, invert
from canopy_core.simulate import simulate_capture
from tests.core.edits import crop_depth_top, paint_blue_grey, take_away_blue_ball, turn_to_portrait


def _truth(capture: Path) -> dict:
    return json.loads((capture / "ground_truth.json").read_text())


def _assert_within_5_percent(merged: CanopyMetrics, truth: dict) -> None:
    """H, W and D each within 5 % of the simulator's truth: measured right, not merely measured."""
    for key in ("height_m", "width_m", "thickness_m"):
        assert getattr(merged, key) == pytest.approx(truth[key], rel=0.05), key


@pytest.fixture(scope="module")
def native_capture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return simulate_capture(tmp_path_factory.mktemp("native") / "tree", seed=11, n_views=2, native_color=True)


@pytest.fixture(scope="module")
def native_result(native_capture: Path) -> Measurement:
    return measure(native_capture)


def test_merged_height_width_thickness_match_ground_truth(
    native_capture: Path, native_result: Measurement
) -> None:
    truth = _truth(native_capture)
    merged = native_result.merged
    assert merged.height_m == pytest.approx(truth["height_m"], rel=0.02)
    assert merged.width_m == pytest.approx(truth["width_m"], rel=0.03)
    assert merged.thickness_m == pytest.approx(truth["thickness_m"], rel=0.03)


def test_every_view_and_the_merged_views_are_measured(native_result: Measurement) -> None:
    assert list(native_result.modes) == ["views/1", "views/2", "merged"]
    merged, single = native_result.modes["merged"], native_result.modes["views/1"]
    assert merged.points > single.points
    assert merged.width_m >= single.width_m - 0.01


def test_ball_registration_agrees_between_views(native_result: Measurement) -> None:
    for view in native_result.views:
        assert set(view.balls) == {"red", "yellow", "blue"}
        assert view.ball_residual_m < 0.01


def test_icp_is_reported_with_correspondence_percentiles(native_result: Measurement) -> None:
    icp = native_result.views[1].icp
    bounds = native_result.config.icp
    assert icp is not None and native_result.views[0].icp is None
    assert 0 < icp.before.fitness <= 1 and icp.before.distance_p50_m <= icp.before.distance_p90_m
    assert icp.accepted == (
        icp.after.distance_p50_m < icp.before.distance_p50_m
        and icp.ball_slide_m <= bounds.max_ball_shift_m
        and icp.yaw_change_deg <= bounds.max_rotation_deg
    ), icp.reason


def test_progress_names_every_stage_in_order(native_capture: Path) -> None:
    seen: list[tuple[str, float]] = []
    measure(native_capture, progress=lambda stage, fraction: seen.append((stage, fraction)))
    assert [stage for stage, _ in seen] == list(STAGES)
    fractions = [fraction for _, fraction in seen]
    assert fractions == sorted(fractions) and fractions[0] == 0.0 and fractions[-1] == 1.0


def test_result_document_echoes_the_config_and_is_json(native_result: Measurement) -> None:
    document = json.loads(json.dumps(native_result.to_dict()))
    assert {"height_m", "width_m", "thickness_m", "modes", "registration", "config"} <= set(document)
    assert document["config"]["balls"]["diameter_m"] == 0.10
    assert set(document["registration"]["views"]) == {"views/1", "views/2"}


def test_registered_colour_capture_is_measured_too(tmp_path: Path) -> None:
    capture = simulate_capture(tmp_path / "tree", seed=12, n_views=2, native_color=False)
    result = measure(capture)
    assert result.merged.height_m == pytest.approx(_truth(capture)["height_m"], rel=0.03)


def test_three_views_are_registered_together(tmp_path: Path) -> None:
    capture = simulate_capture(tmp_path / "tree", seed=13, n_views=3)
    result = measure(capture)
    assert list(result.modes) == ["views/1", "views/2", "views/3", "merged"]
    assert all(view.icp is not None for view in result.views[1:])
    assert result.merged.width_m == pytest.approx(_truth(capture)["width_m"], rel=0.04)


def test_ball_taken_away_in_one_view_fails_naming_view_and_colour(
    native_capture: Path, tmp_path: Path
) -> None:
    import shutil

    broken = Path(shutil.copytree(native_capture, tmp_path / "broken"))
    take_away_blue_ball(broken, "views/2")
    with pytest.raises(BallNotFound) as info:
        measure(broken)
    assert info.value.view == "views/2" and info.value.color == "blue"


def test_ball_painted_grey_in_one_view_is_found_where_the_other_views_place_it(
    native_capture: Path, native_result: Measurement, tmp_path: Path
) -> None:
    import shutil

    grey = Path(shutil.copytree(native_capture, tmp_path / "grey"))
    paint_blue_grey(grey, "views/2")
    result = measure(grey)
    second = result.views[1]
    assert second.balls_found_by_position == ("blue",)
    assert (
        np.linalg.norm(second.balls["blue"].center_m - native_result.views[1].balls["blue"].center_m) < 0.003
    )


def test_one_view_capture_is_measured_in_its_own_ground_frame(tmp_path: Path) -> None:
    capture = simulate_capture(tmp_path / "tree", seed=21, n_views=1)
    result = measure(capture)
    assert list(result.modes) == ["views/1", "merged"]
    assert result.merged.height_m == pytest.approx(_truth(capture)["height_m"], rel=0.03)


def test_invalid_override_is_a_config_error_naming_the_setting(native_capture: Path) -> None:
    from canopy_core.errors import ConfigError

    with pytest.raises(ConfigError) as info:
        measure(native_capture, overrides={"filters": {"min_depth_m": 9.0}})
    assert info.value.field == "filters" and "max_depth_m" in info.value.message
    with pytest.raises(ConfigError, match="teal"):
        measure(native_capture, overrides={"balls": {"colors": ["red", "yellow", "teal"]}})


def test_depth_scale_off_by_a_thousand_names_the_depth_file(native_capture: Path, tmp_path: Path) -> None:
    import shutil

    from canopy_core.errors import CaptureError

    broken = Path(shutil.copytree(native_capture, tmp_path / "scale"))
    camera_file = broken / "views/1/camera.json"
    camera = json.loads(camera_file.read_text())
    camera["depth_scale"] = 1.0  # millimetre PNG declared as metres: every reading is hundreds of metres
    camera_file.write_text(json.dumps(camera))
    with pytest.raises(CaptureError) as info:
        measure(broken)
    assert info.value.file == "views/1/depth.png" and "no depth reading" in info.value.message


def test_ball_4_6_m_away_in_sun_is_still_found(tmp_path: Path) -> None:
    """Depth noise there is twice the near-range inlier tolerance; the fit's tolerance grows with range²."""
    from canopy_core.simulate import simulate_captures

    (capture,) = simulate_captures(tmp_path, seed=1, count=1)
    result = measure(capture)
    assert result.merged.height_m == pytest.approx(_truth(capture)["height_m"], rel=0.03)


def test_a_triangle_closed_on_the_trunk_fails_instead_of_measuring_a_wrong_tree(tmp_path: Path) -> None:
    """Mixed seed 2031025, found by the accuracy benchmark: the yellow ball is hidden in the second view,
    and the trunk, fitted as a sphere at a different height in each view, made a triangle of the right sides
    with the red and blue balls. Registered on it, the views met 33 degrees apart, and H, W and D came out
    14-34 % off with no error. The ground and trunk, which the views share, contradict that pose: the
    registration fails naming the view, or (should the yellow ball be found) the tree is measured right."""
    capture = simulate_capture(tmp_path / "tree", seed=2031025, n_views=2, scenario="mixed")
    truth = _truth(capture)
    try:
        merged = measure(capture).merged
    except RegistrationFailed as failure:
        assert failure.view == "views/2" and "line up only" in failure.message
        return
    _assert_within_5_percent(merged, truth)


def test_an_apple_both_views_take_for_a_ball_is_dropped_and_the_ball_sought_where_placed(
    tmp_path: Path,
) -> None:
    """Mixed seed 2032000, found by the accuracy benchmark: the red ball is hidden in tall grass in the
    first view, and a red apple lying on the ground 1.95 m from the trunk, which both views see, agrees with
    itself across views. Centred on that triangle, the region of interest cut the crown: W came out 10 %
    short with no error. The crew lays the balls 0.3-0.8 m from the trunk, so the apple is dropped and the
    red ball sought where the other balls place it: the tree is measured right."""
    capture = simulate_capture(tmp_path / "tree", seed=2032000, n_views=2, scenario="mixed")
    truth = _truth(capture)
    result = measure(capture)
    assert "red" in result.views[0].balls_found_by_position
    _assert_within_5_percent(result.merged, truth)


def test_a_heap_of_apples_far_from_the_trunk_is_dropped_whole_and_the_true_ball_chosen(
    tmp_path: Path,
) -> None:
    """Mixed seed 2040027, found by the accuracy benchmark: red apples lie on the ground 2.4 m from the
    trunk, and both views fit spheres to them several times (an apple, its neighbour, the two together);
    each pair agrees with itself across views. Dropping only the sphere chosen left the next fit of the same
    heap to be chosen, and the capture failed though the red ball lay in plain view of both cameras. Every
    sphere as far from the trunk is dropped now, and the true red ball is chosen in both views."""
    capture = simulate_capture(tmp_path / "tree", seed=2040027, n_views=2, scenario="mixed")
    truth = _truth(capture)
    result = measure(capture)
    for view in ("views/1", "views/2"):
        assert _ball_error_m(result, truth, view, "red") < 0.02, view
    _assert_within_5_percent(result.merged, truth)


def test_a_ball_far_from_the_trunk_is_named_with_every_ball_s_distance() -> None:
    centres = np.array([[2.0, 0.1, 0.05], [0.5, 0.2, 0.05], [-0.3, -0.4, 0.05]])
    colors = ["red", "yellow", "blue"]
    assert far_ball(centres[1:], np.zeros(2), colors[1:], 1.2) is None
    assert far_ball(centres, np.zeros(2), colors, 1.2) == "red"
    failure = balls_off_trunk(centres, np.zeros(2), colors, "red")
    assert failure.field == "balls.max_trunk_distance_m"
    assert "red ball was found 2.00 m from the trunk (yellow 0.54 m, blue 0.50 m)" in failure.message


def test_a_far_ball_mostly_hidden_is_found_where_the_other_view_places_it(tmp_path: Path) -> None:
    """Mixed seed 2031004: views/1 sees the blue ball 4.5 m away with two thirds of it hidden, a dozen
    points whose free radius runs to twice the ball's. Judged on a sphere of that radius, its outline took
    in the ground behind and the ball was refused (38 % coverage), so the capture failed; judged on the
    known ball's outline where the other view places it, it is found, and the tree is measured."""
    capture = simulate_capture(tmp_path / "tree", seed=2031004, n_views=2, scenario="mixed")
    truth = _truth(capture)
    result = measure(capture)
    assert "blue" in result.views[0].balls_found_by_position
    _assert_within_5_percent(result.merged, truth)


def _ball_error_m(result: Measurement, truth: dict, view: str, color: str) -> float:
    """How far the ball chosen for ``color`` in ``view`` lies from the simulator's ball, in that view."""
    chosen = next(v for v in result.views if v.view == view).balls[color].center_m
    view_from_world = np.linalg.inv(np.array(truth["views"][view]["camera_to_world"]))
    actual = view_from_world @ np.append(truth["balls"][color]["center_m"], 1.0)
    return float(np.linalg.norm(chosen - actual[:3]))


def _assert_placed_and_measured(tmp_path: Path, *, seed: int, view: str, color: str) -> None:
    """The mixed capture of ``seed`` is measured right, with its ``color`` ball in ``view`` found where the
    other view places it, within 2 cm of the true ball."""
    capture = simulate_capture(tmp_path / "tree", seed=seed, n_views=2, scenario="mixed")
    truth = _truth(capture)
    result = measure(capture)
    assert color in next(v for v in result.views if v.view == view).balls_found_by_position
    assert _ball_error_m(result, truth, view, color) < 0.02
    _assert_within_5_percent(result.merged, truth)


def test_each_view_missing_another_ball_finds_it_round_the_one_both_see(tmp_path: Path) -> None:
    """Mixed seed 2033035, found by the accuracy benchmark: views/1 shows its yellow ball in deep shade and
    views/2 half its red ball, neither as a sphere of its own; each view's likeliest spheres of those
    colours are apples and straw. Only the blue ball is found in both, so no view has a whole triangle to
    place the others. Each missing ball is sought on the circle round the blue ball at the distance the
    other view shows, even where look-alikes of its colour were found: the capture failed, now it is
    measured on the right balls."""
    capture = simulate_capture(tmp_path / "tree", seed=2033035, n_views=2, scenario="mixed")
    truth = _truth(capture)
    result = measure(capture)
    assert "yellow" in result.views[0].balls_found_by_position
    assert "red" in result.views[1].balls_found_by_position
    for view in ("views/1", "views/2"):
        for color in ("red", "yellow", "blue"):
            assert _ball_error_m(result, truth, view, color) < 0.02, (view, color)
    _assert_within_5_percent(result.merged, truth)


def test_views_sharing_one_ball_place_the_others_round_it_by_the_trunk(tmp_path: Path) -> None:
    """Mixed seed 2036035, found by the accuracy benchmark: views/1 sees its red and yellow balls well,
    views/2 its red and blue; each view's third ball is a third clear 3.7-4.3 m away, where grass and leaves
    outscore it all along the circle round the red ball, and the capture failed naming views/1's blue ball.
    The red ball, the ground and the trunk each view sees fix views/2's yellow ball to one place, where its
    fragment is found; the triangle then places views/1's blue."""
    _assert_placed_and_measured(tmp_path, seed=2036035, view="views/2", color="yellow")


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


def test_a_ball_hidden_in_one_view_is_placed_unseen_when_the_balls_are_chosen_again(tmp_path: Path) -> None:
    """Mixed seed 2090041, found on a held-out run of the accuracy benchmark: views/2's blue ball lies
    4.6 m away, two thirds hidden; three fragments of clutter closed a triangle at views/1's distances, and
    the ground and trunk refused it (the balls moved 92 mm). Chosen again without one of them, views/2's red
    and yellow balls are fitted as spheres and the blue placed unseen where views/1's triangle puts it;
    ICP moves the two balls 6 mm and turns the view 0.8 degrees, within what balls 0.59 m apart leave open.
    The capture failed, refusing every choice made again that rests on a ball placed unseen; now it is
    measured on the right balls."""
    capture = simulate_capture(tmp_path / "tree", seed=2090041, n_views=2, scenario="mixed")
    truth = _truth(capture)
    result = measure(capture)
    assert result.views[1].balls_placed_unseen == ("blue",)
    for color in ("red", "yellow"):
        assert _ball_error_m(result, truth, "views/2", color) < 0.02, color
    _assert_within_5_percent(result.merged, truth)


@pytest.mark.parametrize("seed", [2054014, 2053020])
def test_a_pose_resting_on_fragments_fails_where_the_surfaces_do_not_confirm_it(
    tmp_path: Path, seed: int
) -> None:
    """Mixed seeds found on held-out runs of the accuracy benchmark, where the views share only the blue ball
    fitted as a sphere in both. 2054014: views/1 took a yellow look-alike, and views/2's red and yellow
    balls were taken as fragments 1.2-1.8 m off where that triangle put them (fitted radii 74 and 80 mm);
    ICP wanted 3.5 degrees, more than such a pose leaves open but short of a certain failure, so the ball
    pose was kept and W came out 12 % wide with no error. 2053020: each view took one look-alike and a
    fragment where the other's triangle put it; ICP wanted 5.1 degrees, W 5 % off. Held by one ball both
    views fit, like a view with a ball placed unseen, the pose must be confirmed by the surfaces, and here
    it is not."""
    capture = simulate_capture(tmp_path / "tree", seed=seed, n_views=2, scenario="mixed")
    with pytest.raises(RegistrationFailed, match="both fit only the blue ball") as info:
        measure(capture)
    assert info.value.view == "views/2"


def test_a_ball_is_carried_round_the_trunk_from_every_likely_sphere_of_the_shared_colour(
    tmp_path: Path,
) -> None:
    """Mixed seed 2048017, found by the accuracy benchmark: the views share only the yellow ball, and in
    each a look-alike outscores it; the trunk circle found round views/1's look-alike lay 27 cm from the
    trunk, so the balls' distances from it disagreed, nothing was carried and the capture failed naming
    views/1's blue ball. Every likely yellow sphere is tried in both views: the true pair places views/2's
    red fragment and views/1's blue."""
    capture = simulate_capture(tmp_path / "tree", seed=2048017, n_views=2, scenario="mixed")
    truth = _truth(capture)
    result = measure(capture)
    assert result.views[0].balls_found_by_position == ("blue",)
    assert result.views[1].balls_found_by_position == ("red",)
    for view in ("views/1", "views/2"):
        for color in ("red", "yellow", "blue"):
            assert _ball_error_m(result, truth, view, color) < 0.02, (view, color)
    _assert_within_5_percent(result.merged, truth)


def test_a_ball_no_view_holds_a_sphere_of_is_found_where_both_views_fragments_meet(tmp_path: Path) -> None:
    """Mixed seed 2045012, found by the accuracy benchmark: each view sees about 40 % of the blue ball, 4 m
    away, and neither holds a sphere of it (views/1's red ball, outranked by apples, is found on the circle
    round its yellow one); with no triangle anywhere the capture failed naming views/1's blue ball. Each
    place views/1's blue points gather is carried onto views/2 by the red and yellow balls both show and
    the ground's up, and a sphere is found at both ends."""
    capture = simulate_capture(tmp_path / "tree", seed=2045012, n_views=2, scenario="mixed")
    truth = _truth(capture)
    result = measure(capture)
    for view in result.views:
        assert "blue" in view.balls_found_by_position, view.view
        assert _ball_error_m(result, truth, view.view, "blue") < 0.03, view.view
    _assert_within_5_percent(result.merged, truth)


def test_balls_resting_on_a_hollow_floor_are_kept_though_their_plane_tilts(tmp_path: Path) -> None:
    """Mixed seed 2045008, found by the accuracy benchmark: the blue ball lies in a hollow 8 cm below the
    others, so the balls' plane tilts 15-17 degrees from the ground round them, past the limit that tells a
    fallen apple taken for a ball; the true red ball was refused as lying off the ground and an apple 64 cm
    away taken instead (green: the registration failed). Each ball stands one radius above the floor right
    round it, so the balls are kept and the frame stands on the ground."""
    capture = simulate_capture(tmp_path / "tree", seed=2045008, n_views=2, scenario="mixed")
    truth = _truth(capture)
    result = measure(capture)
    assert result.ground.on_ground and result.ground.tilt_from_ball_plane_deg > 15.0
    for view in ("views/1", "views/2"):
        for color in ("red", "yellow", "blue"):
            assert _ball_error_m(result, truth, view, color) < 0.02, (view, color)
    _assert_within_5_percent(result.merged, truth)


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


def test_a_ball_in_deep_shade_is_found_by_its_shape(tmp_path: Path) -> None:
    """Mixed seed 2033034, found by the accuracy benchmark: in views/2 the yellow ball lies whole in view in
    the crown's shadow, read as RGB 16, 14, 2: its hue is the ball's, its brightness too low for its colour
    range, so none of its points voted for a sphere. Dark points of its hue in the floor's band vote too:
    the ball is found as a sphere of its own, and the capture, which failed, is measured on the right
    balls."""
    capture = simulate_capture(tmp_path / "tree", seed=2033034, n_views=2, scenario="mixed")
    truth = _truth(capture)
    result = measure(capture)
    assert "yellow" not in result.views[1].balls_found_by_position
    for view in ("views/1", "views/2"):
        for color in ("red", "yellow", "blue"):
            assert _ball_error_m(result, truth, view, color) < 0.02, (view, color)
    _assert_within_5_percent(result.merged, truth)


def test_a_wire_the_crown_hides_but_for_a_span_each_side_does_not_widen_the_tree(tmp_path: Path) -> None:
    """Mixed seed 2033032, found by the accuracy benchmark: the lower of two trellis wires runs through the
    crown at the cameras' height and shows only 20 cm beyond the crown on one side and a few centimetres
    on the other; leaves at the crown's edge form longer lines by chance, so the search for wires parallel
    to the upper one never tried it, and W came out 17.7 % wide with no error. A straight, level chain of
    thin-line points parallel to the wire found is tried as a wire too."""
    capture = simulate_capture(tmp_path / "tree", seed=2033032, n_views=2, scenario="mixed")
    truth = _truth(capture)
    result = measure(capture)
    _assert_within_5_percent(result.merged, truth)


def test_the_trellis_direction_comes_from_each_view_s_line_of_a_wire_not_both_at_once(tmp_path: Path) -> None:
    """Mixed seed 2035025, found by the accuracy benchmark: views/2 sees the lowest of three trellis wires as
    a line 7 cm behind it (its mixed pixels, against the crown), views/1 on the wire. Fitted through both
    views' pieces on one side of the crown, the wire turned 4 degrees off the row, the other two wires,
    sought parallel to it, were missed, and W came out 96 % wide with no error. Each view's line is
    followed on its own: the three wires are found along the row and the tree is measured right."""
    capture = simulate_capture(tmp_path / "tree", seed=2035025, n_views=2, scenario="mixed")
    truth = _truth(capture)
    result = measure(capture)
    _assert_within_5_percent(result.merged, truth)


def test_a_top_wire_seen_only_beside_the_crown_is_not_claimed_by_a_line_of_leaves(tmp_path: Path) -> None:
    """Mixed seed 2049045, found on a held-out run of the accuracy benchmark: the fourth trellis wire runs
    2.16 m high through the crown's top and shows a thin stretch of 27 cm beside it. A line of leaves 7 cm
    above it, parallel to the lower wires, was found first by the search through sparse cells and claimed
    that stretch, which then fell short of the 30 cm a wire must be seen over; the wire's pieces beyond the
    crown stayed with it and W came out 12 % wide with no error. Thin stretches parallel to the first wire
    are tried first, judged over the length a thin stretch needs; the tree is measured right."""
    capture = simulate_capture(tmp_path / "tree", seed=2049045, n_views=2, scenario="mixed")
    _assert_within_5_percent(measure(capture).merged, _truth(capture))


def test_mixed_pixels_behind_a_wire_one_view_shows_and_the_other_sees_past_are_no_crown(
    tmp_path: Path,
) -> None:
    """Mixed seed 2035044, found by the accuracy benchmark: a trellis wire 0.83 m high runs through the
    crown's foot, and views/1 shows it only by its mixed pixels, specks in mid-air 0.5 m behind it, beside
    the crown. Five voxels of them passed for a piece of the crown, and W came out 16.7 % wide with no
    error. views/2 looks at that place and sees past it, to the far ground out of its range: the specks
    are no crown, and the tree is measured right."""
    capture = simulate_capture(tmp_path / "tree", seed=2035044, n_views=2, scenario="mixed")
    truth = _truth(capture)
    _assert_within_5_percent(measure(capture).merged, truth)


def test_a_ball_one_view_does_not_show_is_placed_by_the_two_it_shows_and_the_ground(tmp_path: Path) -> None:
    """Mixed seed 2036059, found by the accuracy benchmark: the red ball is hidden in views/2, and both
    views took a fallen apple 12 cm from the yellow ball for it. The triangles agreed (it is one object),
    but the balls' plane tilted 34 degrees from the ground and W came out 23.5 % narrow with no error;
    refusing the apple then failed the capture, as no other red sphere rests on the ground. views/2's
    yellow and blue balls and its ground's up carry views/1's triangle onto it: the red ball is placed
    there, unseen (views/2 does not see through that place), within 2 cm, and the tree is measured right."""
    capture = simulate_capture(tmp_path / "tree", seed=2036059, n_views=2, scenario="mixed")
    truth = _truth(capture)
    result = measure(capture)
    second = next(v for v in result.views if v.view == "views/2")
    assert second.balls_placed_unseen == ("red",) and second.balls["red"].points == 0
    for view in ("views/1", "views/2"):
        for color in ("red", "yellow", "blue"):
            assert _ball_error_m(result, truth, view, color) < 0.02, (view, color)
    _assert_within_5_percent(result.merged, truth)


def test_balls_chosen_again_when_the_first_choice_lies_off_the_ground(tmp_path: Path) -> None:
    """Mixed seed 2036042, found by the accuracy benchmark: each view misses a different ball and took a
    fragment where the other view's look-alike placed it; one, fitted at ground level, tilted the balls'
    plane. Chosen
    again without it, the views register on spheres both see, and the tree is measured right (it came out
    with D 161 % off)."""
    capture = simulate_capture(tmp_path / "tree", seed=2036042, n_views=2, scenario="mixed")
    _assert_within_5_percent(measure(capture).merged, _truth(capture))


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
    truth = _truth(capture)
    result = measure(capture)
    assert result.views[0].balls_found_by_position == ("red",)
    assert result.views[1].balls_found_by_position == ("yellow",)
    assert _ball_error_m(result, truth, "views/1", "red") < 0.02
    assert _ball_error_m(result, truth, "views/2", "blue") < 0.02
    _assert_within_5_percent(result.merged, truth)


def test_a_look_alike_the_surfaces_contradict_is_ruled_out_and_the_balls_chosen_again(tmp_path: Path) -> None:
    """Mixed seed 2042018, found by the accuracy benchmark: both views took red apples 55-59 cm from the red
    ball for it, whose triangles agreed with the yellow and blue balls; the views' ground and trunk line
    up only with views/2's balls moved by 97 mm and the view turned 22 degrees, and the capture failed,
    though both views show the red ball. Each of views/2's balls is ruled out in turn and the balls chosen
    again: without the apple, the true red ball is chosen in both views and the tree is measured right."""
    capture = simulate_capture(tmp_path / "tree", seed=2042018, n_views=2, scenario="mixed")
    truth = _truth(capture)
    result = measure(capture)
    for view in ("views/1", "views/2"):
        assert _ball_error_m(result, truth, view, "red") < 0.02, view
    _assert_within_5_percent(result.merged, truth)


def test_a_wire_no_search_finds_is_no_crown_where_the_other_view_sees_past_it(tmp_path: Path) -> None:
    """Mixed seed 2038036, found by the accuracy benchmark (held out): a trellis wire at 2.17 m through the
    crown shows 2 points in views/1 and 12 in views/2, too few for any wire search. Its points and mixed
    pixels chained the crown out along it to the edge of the region of interest, and W came out 31 % wide
    with no error. A wire is thinner than a pixel: where one view shows it, the other sees past it. Points
    another view saw through are no crown, the chain breaks, and W is right."""
    capture = simulate_capture(tmp_path / "tree", seed=2038036, n_views=2, scenario="mixed")
    _assert_within_5_percent(measure(capture).merged, _truth(capture))


def test_a_first_wire_fitted_askew_is_turned_onto_the_views_lines_before_it_is_judged(tmp_path: Path) -> None:
    """Mixed seed 2066008, found on a held-out run of the accuracy benchmark: three trellis wires, the top one
    along the crown's top, seen thin at one wall and 2.4 m along it. Mixed pixels and leaves pulled its
    fit 3.8 degrees askew, so the line missed its own far stretch, covered 70 % of its chord (80 % needed)
    and was refused; no other line passed as a first wire, no wire was found, and W came out 24 % wide
    with no error. A first line seen along half its chord that fails is turned to where the views' lines
    run and judged again: the three wires are found and the tree is measured right."""
    capture = simulate_capture(tmp_path / "tree", seed=2066008, n_views=2, scenario="mixed")
    _assert_within_5_percent(measure(capture).merged, _truth(capture))


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
    truth = _truth(capture)
    result = measure(capture)
    assert result.views[1].balls_placed_unseen == ("red",)
    for view in ("views/1", "views/2"):
        for color in ("yellow", "blue"):
            assert _ball_error_m(result, truth, view, color) < 0.02, (view, color)
    _assert_within_5_percent(result.merged, truth)


def test_a_registration_that_leaves_the_views_round_different_trunks_fails_naming_the_view(
    tmp_path: Path,
) -> None:
    """The trunk's agreement, on its own: a sound registration passes it; the same with views/2 carried
    1 m along the row (its trunk's foot 1 m from views/1's, and no trunk at views/1's foot) fails naming
    views/2, as a registration on look-alikes that ICP cannot see through does."""
    capture = load_capture(simulate_capture(tmp_path / "tree", seed=1, n_views=2))
    config = config_for(capture.manifest, None)
    clouds = [filtered_cloud(view, config.filters) for view in capture.views]
    candidates, grounds = ball_evidence(clouds, config)
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
    truth = _truth(capture)
    result = measure(capture)
    for view in ("views/1", "views/2"):
        for color in ("red", "yellow", "blue"):
            assert _ball_error_m(result, truth, view, color) < 0.02, (view, color)
    _assert_within_5_percent(result.merged, truth)


def test_a_capture_of_an_azure_kinect_binned_depth_mode_is_measured_right(tmp_path: Path) -> None:
    """Another sensor than the one the detector was built on: an Azure Kinect's narrow depth mode binned
    2 x 2 (320 x 288, 252 px focal length: 0.69 times the Kinect v2's pixels per degree, a ball at 3.5 m
    on about 40 pixels) with a 1280 x 720 colour camera, on a mixed scene (seed 2080005, straw, fallen
    leaves): the capture loads at its own sizes and is measured within 5 % of the truth."""
    capture = simulate_capture(
        tmp_path / "tree", seed=2080005, n_views=2, scenario="mixed", sensor="azure-kinect-nfov-binned"
    )
    loaded = load_capture(capture)
    assert loaded.manifest.sensor == "simulated-azure-kinect-nfov-binned"
    assert loaded.views[0].depth_raw.shape == (288, 320) and loaded.views[0].color_rgb.shape == (720, 1280, 3)
    result = measure(capture)
    _assert_within_5_percent(result.merged, _truth(capture))


def test_an_unknown_sensor_is_refused_naming_the_known_ones(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="unknown sensor 'kinect-v3': expected one of kinect-v2, "):
        simulate_capture(tmp_path / "tree", seed=1, sensor="kinect-v3")


def test_the_wire_search_beyond_the_roi_gets_what_stands_clear_of_the_floor_out_to_its_reach() -> None:
    """The points passed on to seek wires beyond the cylinder: past its wall, no farther from the trunk than
    ``wires.scene_radius_m``, higher than ``wires.scene_min_height_m`` (the floor's scan lines are level
    lines too) and lower than the region of interest's top; in the world frame."""
    config = MeasureConfig()
    points = np.array(
        [
            [1.0, 0.0, 1.5],  # inside the cylinder
            [2.0, 0.5, 1.5],  # beyond its wall: kept
            [0.0, -2.9, 0.9],  # beyond, near the reach: kept
            [2.0, 0.0, 0.0],  # the floor beyond the wall
            [3.5, 0.0, 1.5],  # past the reach
            [2.0, 0.0, 5.5],  # above the top
        ]
    )
    cloud = ViewCloud(
        view="views/1",
        points_m=points,
        colors_rgb=np.zeros((6, 3), dtype=np.uint8),
        has_color=np.ones(6, dtype=bool),
        pixels=np.zeros((6, 2), dtype=np.int64),
    )
    world_from_view = np.eye(4)
    world_from_view[:3, 3] = [0.0, 0.0, 0.2]  # the view's frame 20 cm under the world's

    beyond = _beyond_roi_points(cloud, world_from_view, config)

    np.testing.assert_allclose(beyond, [[2.0, 0.5, 1.7], [0.0, -2.9, 1.1]])


def test_a_stake_standing_above_the_crown_fails_clearly_instead_of_raising_h(tmp_path: Path) -> None:
    """Seed 3's stake stands 0.39 m above its crown: measured, H would be its top."""
    capture = simulate_capture(tmp_path / "staked", seed=3, stake=True)
    truth = json.loads((capture / "ground_truth.json").read_text())
    assert truth["stake"]["top_m"] > truth["height_m"] + 0.3
    with pytest.raises(MeasurementError, match="thin as a pole") as refused:
        measure(capture)
    assert refused.value.field == "metrics.max_thin_top_m"
    assert refused.value.view is None  # judged on the views together, not on one alone
    allowed = measure(capture, overrides={"metrics": {"max_thin_top_m": 1.0}})
    assert allowed.modes["merged"].height_m > truth["height_m"] + 0.25  # what it measured before


@pytest.mark.parametrize(
    ("seed", "was"),
    [
        (2112018, "posts 0.62 m and 1.12 m from the trunk, their tops above the crown: H +0.57 m, D +34 %"),
        (2112003, "a post better seen than the trunk taken for it, the other post's top for H: +0.60 m"),
        (2113039, "refused at the region's wall; this change's first version: H +4.7 %, D +9.9 %"),
    ],
)
def test_trellis_posts_the_crown_has_grown_round_are_not_measured_as_tree(
    tmp_path: Path, seed: int, was: str
) -> None:
    capture = simulate_capture(tmp_path / "tree", seed=seed, scenario="mixed", near_posts=True)
    truth = json.loads((capture / "ground_truth.json").read_text())
    assert sum(np.hypot(x, y) < 1.5 for x, y, _ in truth["posts"]) == 2  # both inside the region

    merged = measure(capture).modes["merged"]

    for name in ("height_m", "width_m", "thickness_m"):
        assert getattr(merged, name) == pytest.approx(truth[name], rel=0.03), f"{name}; before: {was}"


def _row_of_top(capture: Path, result: Measurement, view: int) -> int:
    """The depth-image row of a view in which the measured tree's top lies."""
    depth = load_capture(capture).views[view].camera.depth
    _, y, z = apply(invert(result.views[view].world_from_view), np.array([result.merged.marks.top_m]))[0]
    return int(depth.fy * y / z + depth.cy)


def test_a_tree_whose_top_runs_out_of_every_view_is_refused_not_measured_short(
    native_capture: Path, native_result: Measurement, tmp_path: Path
) -> None:
    # Both cameras see 40 rows less above: the tree's top is out of both images. Before the frame was
    # judged, H came out short by what was cut, without an error.
    capture = tmp_path / "tree"
    shutil.copytree(native_capture, capture)
    for index, view in enumerate(("views/1", "views/2")):
        crop_depth_top(capture, view, _row_of_top(native_capture, native_result, index) + 40)
    with pytest.raises(MeasurementError, match="top edge") as raised:
        measure(capture)
    assert "height_m" in raised.value.message and "step back" in (raised.value.hint or "")


def test_a_view_cut_at_its_top_is_marked_and_the_other_view_carries_the_merged_height(
    native_capture: Path, native_result: Measurement, tmp_path: Path
) -> None:
    capture = tmp_path / "tree"
    shutil.copytree(native_capture, capture)
    crop_depth_top(capture, "views/2", _row_of_top(native_capture, native_result, 1) + 40)
    result = measure(capture)
    assert "height_m" in result.modes["views/2"].cut_by_frame
    assert result.modes["views/1"].cut_by_frame == () and result.merged.cut_by_frame == ()
    assert result.modes["views/2"].height_m < result.merged.height_m - 0.05
    _assert_within_5_percent(result.merged, _truth(capture))
    assert result.merged.height_m == pytest.approx(_truth(capture)["height_m"], rel=0.02)


def test_a_tree_taller_than_the_region_of_interest_is_refused_naming_the_setting(
    native_capture: Path,
) -> None:
    # The region of interest's top cuts the tree as a frame would: H would read its height, not the tree's.
    height = _truth(native_capture)["height_m"]
    with pytest.raises(MeasurementError, match="region of interest's top") as raised:
        measure(native_capture, overrides={"roi": {"max_height_m": round(height - 0.3, 2)}})
    assert raised.value.field == "roi.max_height_m"
    assert measure(
        native_capture, overrides={"roi": {"max_height_m": round(height + 0.2, 2)}}
    ).merged.height_m == (pytest.approx(height, rel=0.02))


def test_a_crown_wider_than_the_region_of_interest_is_refused_naming_the_setting(
    native_capture: Path,
) -> None:
    # This crown is 1.39 m across: a region 0.7 m round its trunk cuts it at its wall, where W would read
    # the region's width; one of 0.9 m holds it.
    with pytest.raises(MeasurementError, match="region of interest's wall") as raised:
        measure(native_capture, overrides={"roi": {"radius_m": 0.7}})
    assert raised.value.field == "roi.radius_m"
    width = _truth(native_capture)["width_m"]
    assert measure(native_capture, overrides={"roi": {"radius_m": 0.9}}).merged.width_m == pytest.approx(
        width, rel=0.02
    )


def test_cameras_held_in_portrait_measure_the_same_tree(native_capture: Path, tmp_path: Path) -> None:
    # A crew may turn the camera a quarter turn to fit a tall tree: up is then along the image's rows.
    capture = tmp_path / "tree"
    shutil.copytree(native_capture, capture)
    turn_to_portrait(capture)
    result = measure(capture)
    _assert_within_5_percent(result.merged, _truth(capture))
    assert result.merged.height_m == pytest.approx(_truth(capture)["height_m"], rel=0.02)
    assert all(mode.cut_by_frame == () for mode in result.modes.values())
