"""The whole pipeline on captures with trellis wires, posts and stakes in or beside the crown: not measured
as tree (cases the accuracy benchmark found)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from canopy_core.backproject import ViewCloud
from canopy_core.config import MeasureConfig
from canopy_core.errors import MeasurementError
from canopy_core.measure import _beyond_roi_points, measure
from canopy_core.simulate import simulate_capture
from tests.core.measured import assert_within_5_percent, truth_of


def test_a_wire_the_crown_hides_but_for_a_span_each_side_does_not_widen_the_tree(tmp_path: Path) -> None:
    """Mixed seed 2033032, found by the accuracy benchmark: the lower of two trellis wires runs through the
    crown at the cameras' height and shows only 20 cm beyond the crown on one side and a few centimetres
    on the other; leaves at the crown's edge form longer lines by chance, so the search for wires parallel
    to the upper one never tried it, and W came out 17.7 % wide with no error. A straight, level chain of
    thin-line points parallel to the wire found is tried as a wire too."""
    capture = simulate_capture(tmp_path / "tree", seed=2033032, n_views=2, scenario="mixed")
    truth = truth_of(capture)
    result = measure(capture)
    assert_within_5_percent(result.merged, truth)


def test_the_trellis_direction_comes_from_each_view_s_line_of_a_wire_not_both_at_once(tmp_path: Path) -> None:
    """Mixed seed 2035025, found by the accuracy benchmark: views/2 sees the lowest of three trellis wires as
    a line 7 cm behind it (its mixed pixels, against the crown), views/1 on the wire. Fitted through both
    views' pieces on one side of the crown, the wire turned 4 degrees off the row, the other two wires,
    sought parallel to it, were missed, and W came out 96 % wide with no error. Each view's line is
    followed on its own: the three wires are found along the row and the tree is measured right."""
    capture = simulate_capture(tmp_path / "tree", seed=2035025, n_views=2, scenario="mixed")
    truth = truth_of(capture)
    result = measure(capture)
    assert_within_5_percent(result.merged, truth)


def test_a_top_wire_seen_only_beside_the_crown_is_not_claimed_by_a_line_of_leaves(tmp_path: Path) -> None:
    """Mixed seed 2049045, found on a held-out run of the accuracy benchmark: the fourth trellis wire runs
    2.16 m high through the crown's top and shows a thin stretch of 27 cm beside it. A line of leaves 7 cm
    above it, parallel to the lower wires, was found first by the search through sparse cells and claimed
    that stretch, which then fell short of the 30 cm a wire must be seen over; the wire's pieces beyond the
    crown stayed with it and W came out 12 % wide with no error. Thin stretches parallel to the first wire
    are tried first, judged over the length a thin stretch needs; the tree is measured right."""
    capture = simulate_capture(tmp_path / "tree", seed=2049045, n_views=2, scenario="mixed")
    assert_within_5_percent(measure(capture).merged, truth_of(capture))


def test_mixed_pixels_behind_a_wire_one_view_shows_and_the_other_sees_past_are_no_crown(
    tmp_path: Path,
) -> None:
    """Mixed seed 2035044, found by the accuracy benchmark: a trellis wire 0.83 m high runs through the
    crown's foot, and views/1 shows it only by its mixed pixels, specks in mid-air 0.5 m behind it, beside
    the crown. Five voxels of them passed for a piece of the crown, and W came out 16.7 % wide with no
    error. views/2 looks at that place and sees past it, to the far ground out of its range: the specks
    are no crown, and the tree is measured right."""
    capture = simulate_capture(tmp_path / "tree", seed=2035044, n_views=2, scenario="mixed")
    truth = truth_of(capture)
    assert_within_5_percent(measure(capture).merged, truth)


def test_a_wire_no_search_finds_is_no_crown_where_the_other_view_sees_past_it(tmp_path: Path) -> None:
    """Mixed seed 2038036, found by the accuracy benchmark (held out): a trellis wire at 2.17 m through the
    crown shows 2 points in views/1 and 12 in views/2, too few for any wire search. Its points and mixed
    pixels chained the crown out along it to the edge of the region of interest, and W came out 31 % wide
    with no error. A wire is thinner than a pixel: where one view shows it, the other sees past it. Points
    another view saw through are no crown, the chain breaks, and W is right."""
    capture = simulate_capture(tmp_path / "tree", seed=2038036, n_views=2, scenario="mixed")
    assert_within_5_percent(measure(capture).merged, truth_of(capture))


def test_a_first_wire_fitted_askew_is_turned_onto_the_views_lines_before_it_is_judged(tmp_path: Path) -> None:
    """Mixed seed 2066008, found on a held-out run of the accuracy benchmark: three trellis wires, the top one
    along the crown's top, seen thin at one wall and 2.4 m along it. Mixed pixels and leaves pulled its
    fit 3.8 degrees askew, so the line missed its own far stretch, covered 70 % of its chord (80 % needed)
    and was refused; no other line passed as a first wire, no wire was found, and W came out 24 % wide
    with no error. A first line seen along half its chord that fails is turned to where the views' lines
    run and judged again: the three wires are found and the tree is measured right."""
    capture = simulate_capture(tmp_path / "tree", seed=2066008, n_views=2, scenario="mixed")
    assert_within_5_percent(measure(capture).merged, truth_of(capture))


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
        (2115021, "a post's top seen from one side, off the line of its short stretch by its foot: H +8 %"),
        (2117045, "a post left in the tree, the crown's middle pulled off by the other post: refused"),
        (2119029, "a post seen from one side higher up, its stretch there not one line: H +1.09 m"),
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
