"""The whole pipeline on simulated captures: metrics against ground truth, modes, stages, failures, the
frame and the region of interest."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from canopy_core.capture import load_capture
from canopy_core.errors import BallNotFound, MeasurementError
from canopy_core.measure import STAGES, Measurement, measure
from canopy_core.register import apply, invert
from canopy_core.simulate import simulate_capture
from tests.core.edits import crop_depth_top, paint_blue_grey, take_away_blue_ball, turn_to_portrait
from tests.core.measured import assert_within_5_percent, truth_of


@pytest.fixture(scope="module")
def native_capture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return simulate_capture(tmp_path_factory.mktemp("native") / "tree", seed=11, n_views=2, native_color=True)


@pytest.fixture(scope="module")
def native_result(native_capture: Path) -> Measurement:
    return measure(native_capture, processes=2)  # the views searched at once, as on any laptop


def test_merged_height_width_thickness_match_ground_truth(
    native_capture: Path, native_result: Measurement
) -> None:
    truth = truth_of(native_capture)
    merged = native_result.merged
    assert merged.height_m == pytest.approx(truth["height_m"], rel=0.02)
    assert merged.width_m == pytest.approx(truth["width_m"], rel=0.03)
    assert merged.thickness_m == pytest.approx(truth["thickness_m"], rel=0.03)


def test_views_searched_one_at_a_time_measure_exactly_the_same(
    native_capture: Path, native_result: Measurement
) -> None:
    one_at_a_time = measure(native_capture, processes=1).to_dict()
    at_once = native_result.to_dict()
    one_at_a_time.pop("timings_s"), at_once.pop("timings_s")
    assert json.dumps(one_at_a_time, default=np.ndarray.tolist) == json.dumps(
        at_once, default=np.ndarray.tolist
    )


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
    assert result.merged.height_m == pytest.approx(truth_of(capture)["height_m"], rel=0.03)


def test_three_views_are_registered_together(tmp_path: Path) -> None:
    capture = simulate_capture(tmp_path / "tree", seed=13, n_views=3)
    result = measure(capture)
    assert list(result.modes) == ["views/1", "views/2", "views/3", "merged"]
    assert all(view.icp is not None for view in result.views[1:])
    assert result.merged.width_m == pytest.approx(truth_of(capture)["width_m"], rel=0.04)


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
    assert result.merged.height_m == pytest.approx(truth_of(capture)["height_m"], rel=0.03)


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
    assert result.merged.height_m == pytest.approx(truth_of(capture)["height_m"], rel=0.03)


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
    assert_within_5_percent(result.merged, truth_of(capture))


def test_an_unknown_sensor_is_refused_naming_the_known_ones(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="unknown sensor 'kinect-v3': expected one of kinect-v2, "):
        simulate_capture(tmp_path / "tree", seed=1, sensor="kinect-v3")


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
    assert_within_5_percent(result.merged, truth_of(capture))
    assert result.merged.height_m == pytest.approx(truth_of(capture)["height_m"], rel=0.02)


def test_a_tree_taller_than_the_region_of_interest_is_refused_naming_the_setting(
    native_capture: Path,
) -> None:
    # The region of interest's top cuts the tree as a frame would: H would read its height, not the tree's.
    height = truth_of(native_capture)["height_m"]
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
    width = truth_of(native_capture)["width_m"]
    assert measure(native_capture, overrides={"roi": {"radius_m": 0.9}}).merged.width_m == pytest.approx(
        width, rel=0.02
    )


def test_cameras_held_in_portrait_measure_the_same_tree(native_capture: Path, tmp_path: Path) -> None:
    # A crew may turn the camera a quarter turn to fit a tall tree: up is then along the image's rows.
    capture = tmp_path / "tree"
    shutil.copytree(native_capture, capture)
    turn_to_portrait(capture)
    result = measure(capture)
    assert_within_5_percent(result.merged, truth_of(capture))
    assert result.merged.height_m == pytest.approx(truth_of(capture)["height_m"], rel=0.02)
    assert all(mode.cut_by_frame == () for mode in result.modes.values())
