"""Canopy metrics on point sets whose answers are known exactly."""

from __future__ import annotations

import itertools
import re

import numpy as np
import pytest

from canopy_core.config import MetricsConfig
from canopy_core.errors import MeasurementError
from canopy_core.foliage import foliage_mask
from canopy_core.metrics import (
    CanopyMetrics,
    canopy_height,
    canopy_metrics,
    crown_base_geometric,
    crown_base_kde,
    crown_candidates,
    crown_mask,
    hull_volume,
    max_horizontal_distance,
    projected_area,
    thin_top_m,
    voxel_volume,
)
from canopy_core.trunk_axis import TrunkAxis


def _ellipsoid_crown(
    rng: np.random.Generator, *, centre_z: float, radii: tuple[float, float, float], n: int
) -> np.ndarray:
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    scale = rng.uniform(0.7, 1.0, size=(n, 1)) ** (1 / 3)
    return direction * scale * np.array(radii) + [0.0, 0.0, centre_z]


def _tree(rng: np.random.Generator) -> np.ndarray:
    trunk_z = rng.uniform(0.0, 1.0, size=800)
    angle = rng.uniform(0, 2 * np.pi, size=800)
    trunk = np.column_stack([0.06 * np.cos(angle), 0.06 * np.sin(angle), trunk_z])
    return np.vstack([trunk, _ellipsoid_crown(rng, centre_z=2.0, radii=(0.8, 0.6, 1.0), n=20000)])


def test_height_is_top_of_supported_points_above_ground() -> None:
    tree = _tree(np.random.default_rng(0))
    assert canopy_height(tree, ground_z_m=0.0) == pytest.approx(tree[:, 2].max(), abs=0.02)
    assert canopy_height(tree, ground_z_m=0.5) == pytest.approx(tree[:, 2].max() - 0.5, abs=0.02)


def test_height_ignores_a_lone_stray_point_above_the_crown() -> None:
    tree = _tree(np.random.default_rng(1))
    with_insect = np.vstack([tree, [[0.1, 0.0, 3.6]]])
    assert canopy_height(with_insect) == pytest.approx(canopy_height(tree))
    assert canopy_height(with_insect) < 3.1


def test_width_is_hull_diameter_of_horizontal_projection() -> None:
    rng = np.random.default_rng(2)
    points = rng.uniform(-1, 1, size=(400, 3)) * [1.0, 0.4, 2.0]
    brute = max(np.linalg.norm(a[:2] - b[:2]) for a, b in itertools.combinations(points, 2))
    assert max_horizontal_distance(points) == pytest.approx(brute, rel=1e-12)


def test_width_ignores_height() -> None:
    points = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 5.0], [0.0, 1.0, -3.0], [0.5, 0.5, 9.0]])
    assert max_horizontal_distance(points) == pytest.approx(np.sqrt(2.0))


def _sampled_hedge(phase_m: tuple[float, float], *, pitch_m: float, length_m: float) -> np.ndarray:
    """A crown from 1 m to 2 m high and length_m long along x, as a camera with pixels pitch_m apart reads
    it: the last sample inside each extreme lies anywhere up to a pitch short of it."""
    x = np.arange(phase_m[0] - length_m / 2, length_m / 2, pitch_m)
    z = np.arange(1.0 + phase_m[1], 2.0, pitch_m)
    return np.stack(np.meshgrid(x, [0.0], z, indexing="ij"), axis=-1).reshape(-1, 3)


def test_each_extreme_moves_out_half_a_pixel_so_w_h_and_d_are_unbiased_over_sampling_phases() -> None:
    pitch, length = 0.01, 1.6
    plain: list[CanopyMetrics] = []
    corrected: list[CanopyMetrics] = []
    for phase in np.random.default_rng(9).uniform(0.0, pitch, size=(60, 2)):
        hedge = _sampled_hedge((phase[0], phase[1]), pitch_m=pitch, length_m=length)
        everything = np.ones(hedge.shape[0], dtype=bool)
        for results, footprint in ((plain, None), (corrected, np.full(hedge.shape[0], pitch))):
            results.append(
                canopy_metrics(
                    hedge,
                    trunk=PLUMB,
                    crown=everything,
                    pixel_footprint_m=footprint,
                    config=MetricsConfig(),
                )
            )
    for results, short in ((plain, pitch / 2), (corrected, 0.0)):  # half a pitch short at each extreme
        assert np.mean([m.width_m for m in results]) == pytest.approx(length - 2 * short, abs=0.1 * pitch)
        assert np.mean([m.height_m for m in results]) == pytest.approx(2.0 - short, abs=0.1 * pitch)
        assert np.mean([m.crown_base_m for m in results]) == pytest.approx(1.0 + short, abs=0.1 * pitch)
        assert np.mean([m.thickness_m for m in results]) == pytest.approx(1.0 - 2 * short, abs=0.1 * pitch)
    assert max(m.width_m for m in corrected) <= length + pitch  # never more than half a pitch past an end


def test_kde_crown_base_finds_where_the_crown_starts_above_a_sparse_trunk() -> None:
    tree = _tree(np.random.default_rng(3))
    base = crown_base_kde(tree[:, 2], height_m=3.0, bandwidth_m=0.04, threshold=0.25)
    assert 0.96 <= base <= 1.12  # the crown's lowest points are at z = 1.0; h = 0.04 smooths by about h


def test_kde_threshold_is_unit_independent() -> None:
    z = _tree(np.random.default_rng(4))[:, 2]
    metres = crown_base_kde(z, height_m=3.0, bandwidth_m=0.04, threshold=0.25)
    millimetres = crown_base_kde(z * 1000, height_m=3000.0, bandwidth_m=40.0, threshold=0.25)
    assert millimetres / 1000 == pytest.approx(metres, abs=1e-3)


def test_geometric_crown_base_is_lowest_point_away_from_trunk() -> None:
    tree = _tree(np.random.default_rng(5))
    crown = _crown(tree, np.zeros(len(tree), dtype=bool))
    base = crown_base_geometric(tree, crown, support_radius_m=0.05, support_points=4)
    expected = tree[np.linalg.norm(tree[:, :2], axis=1) > 0.25, 2].min()
    assert base == pytest.approx(expected, abs=0.03)


def test_volumes_and_area_of_a_filled_box() -> None:
    grid = np.stack(np.meshgrid(*[np.linspace(0, 1, 21)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    box = grid * [2.0, 1.0, 0.5]
    assert hull_volume(box) == pytest.approx(1.0)
    assert projected_area(box) == pytest.approx(2.0)
    assert voxel_volume(box + 1e-6, voxel_m=0.25) == pytest.approx(9 * 5 * 3 * 0.25**3)


def test_canopy_metrics_reports_paper_and_extra_metrics_consistently() -> None:
    tree = _tree(np.random.default_rng(6))
    metrics = canopy_metrics(tree, trunk=PLUMB, config=MetricsConfig())
    assert metrics.height_m == pytest.approx(3.0, abs=0.02)
    assert metrics.width_m == pytest.approx(1.6, abs=0.03)
    assert metrics.thickness_m == pytest.approx(metrics.height_m - metrics.crown_base_m)
    assert metrics.diameter_along_row_m == pytest.approx(1.6, abs=0.03)
    assert metrics.diameter_across_row_m == pytest.approx(1.2, abs=0.03)
    assert metrics.volume_voxel_m3 > 0 and 0 < metrics.volume_hull_m3 < 4 / 3 * np.pi * 0.8 * 0.6 * 1.0
    assert metrics.points == tree.shape[0]


def test_the_marks_say_where_h_w_and_d_were_read() -> None:
    """The top's z is H, the crown base point's z the crown base, W's ends are W apart and lie, before their
    half-pitch move, on the farthest pair of the points' horizontal hull (found here by brute force)."""
    tree = _tree(np.random.default_rng(7))
    footprint = np.full(tree.shape[0], 0.008)
    metrics = canopy_metrics(tree, trunk=PLUMB, pixel_footprint_m=footprint, config=MetricsConfig())
    marks = metrics.marks
    assert marks.top_m[2] == metrics.height_m
    assert marks.crown_base_point_m[2] == metrics.crown_base_m
    ends = np.array(marks.width_ends_m)
    assert np.linalg.norm(ends[1] - ends[0]) == pytest.approx(metrics.width_m, abs=1e-9)
    xy = tree[:, :2]
    far = np.argsort(np.linalg.norm(xy, axis=1))[-400:]  # the farthest pair is among the outermost points
    gaps = np.linalg.norm(xy[far][:, None] - xy[far][None, :], axis=2)
    first, second = np.unravel_index(np.argmax(gaps), gaps.shape)
    pair = xy[far][[first, second]]
    inward = ends - 0.004 * np.array([-1.0, 1.0])[:, None] * (ends[1] - ends[0]) / np.linalg.norm(
        ends[1] - ends[0]
    )
    assert sorted(map(tuple, np.round(inward, 9))) == sorted(map(tuple, np.round(pair, 9)))


# What stands on the ground beside the tree: weeds, grass and suckers at the trunk's foot (green, joined to
# the trunk), fallen apples, flying pixels. A tree whose crown starts at 1.06 m above a bare trunk.

BARK, LEAF, WEED, APPLE = (95, 75, 55), (60, 125, 45), (80, 140, 50), (190, 40, 35)
CROWN_BASE_M = 1.06
CROWN_POINTS = 20000
PLUMB = TrunkAxis.vertical((0.0, 0.0))
"""The trunk of these trees: plumb above the origin."""


def _crown(points: np.ndarray, foliage: np.ndarray) -> np.ndarray:
    config = MetricsConfig()
    candidates = crown_candidates(points, PLUMB, foliage=foliage, min_radius_m=config.crown_base_min_radius_m)
    return crown_mask(
        points,
        PLUMB,
        candidates=candidates,
        config=config,
    )


def _blob(rng: np.random.Generator, centre: list[float], radii: list[float], n: int) -> np.ndarray:
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    return np.asarray(centre) + direction * np.asarray(radii) * rng.uniform(0, 1, (n, 1)) ** (1 / 3)


def _leafy_tree(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A 6 cm trunk up into the crown, then an ellipsoid crown of leaves from 1.06 m to 2.94 m (the last
    :data:`CROWN_POINTS` points)."""
    angle, z = rng.uniform(0, 2 * np.pi, 1500), rng.uniform(0.12, 1.3, 1500)
    trunk = np.column_stack([0.06 * np.cos(angle), 0.06 * np.sin(angle), z])
    crown = _blob(rng, [0.0, 0.0, CROWN_BASE_M + 0.94], [0.8, 0.6, 0.94], CROWN_POINTS)
    colors = np.vstack([np.tile(BARK, (len(trunk), 1)), np.tile(LEAF, (len(crown), 1))])
    return np.vstack([trunk, crown]), colors.astype(np.uint8)


def _lowest_leaf(tree: np.ndarray) -> float:
    return float(tree[-CROWN_POINTS:, 2].min())


def _with(
    points: np.ndarray, colors: np.ndarray, extra: np.ndarray, color: tuple[int, int, int]
) -> tuple[np.ndarray, np.ndarray]:
    return np.vstack([points, extra]), np.vstack([colors, np.tile(color, (len(extra), 1))]).astype(np.uint8)


def _metrics(points: np.ndarray, colors: np.ndarray) -> CanopyMetrics:
    return canopy_metrics(
        points, trunk=PLUMB, foliage=foliage_mask(colors, min_index=0.15), config=MetricsConfig()
    )


def _old_crown_base(points: np.ndarray, colors: np.ndarray) -> float:
    """The lowest supported point that is foliage or away from the trunk, as the crown base was until now."""
    candidates = crown_candidates(
        points, PLUMB, foliage=foliage_mask(colors, min_index=0.15), min_radius_m=0.25
    )
    return crown_base_geometric(points, candidates, support_radius_m=0.05, support_points=4)


def test_weeds_and_a_sucker_at_the_trunk_foot_leave_the_crown_base_and_width_alone() -> None:
    rng = np.random.default_rng(20)
    tree, colors = _leafy_tree(rng)
    weeds = np.vstack(
        [
            _blob(rng, [0.3 * np.cos(a), 0.3 * np.sin(a), 0.3], [0.12, 0.12, 0.18], 400)
            for a in (0.5, 2.6, 4.4)
        ]
        + [_blob(rng, [1.25, 0.4, 0.3], [0.15, 0.15, 0.18], 400)]  # farther out than the crown
    )
    angle = rng.uniform(0, 2 * np.pi, 500)
    sucker = np.column_stack([0.08 * np.cos(angle), 0.08 * np.sin(angle), rng.uniform(0.12, 0.6, 500)])
    points, point_colors = _with(*_with(tree, colors, weeds, WEED), sucker, WEED)
    assert _old_crown_base(points, point_colors) < 0.3  # what was wrong
    metrics, clean = _metrics(points, point_colors), _metrics(tree, colors)
    assert metrics.crown_base_m == pytest.approx(_lowest_leaf(tree), abs=0.02)
    assert metrics.width_m == pytest.approx(clean.width_m, abs=1e-9)
    assert metrics.height_m == pytest.approx(clean.height_m, abs=1e-9)
    assert metrics.thickness_m == pytest.approx(clean.thickness_m, abs=0.02)


def test_tall_grass_joined_to_the_lowest_leaves_by_a_few_mixed_pixels_is_not_the_crown() -> None:
    """Clumps of grass reaching 0.97 m, 15 cm below the leaves above them, and a thread of mixed pixels
    (leaf-coloured, between the grass tips and the leaves) that joins them into one body with the crown."""
    rng = np.random.default_rng(25)
    tree, colors = _leafy_tree(rng)
    grass = np.vstack(
        [
            _blob(rng, [0.35 * np.cos(a), 0.35 * np.sin(a), 0.545], [0.1, 0.1, 0.425], 600)
            for a in (0.0, 2.1, 4.2)
        ]
    )
    thread = np.column_stack([np.full(6, 0.35), np.zeros(6), np.linspace(0.99, 1.12, 6)])
    points, point_colors = _with(*_with(tree, colors, grass, WEED), thread, LEAF)
    assert _old_crown_base(points, point_colors) < 0.3  # what was wrong
    crown = _crown(points, foliage_mask(point_colors, min_index=0.15))
    assert not crown[len(tree) : len(tree) + len(grass)].any()
    metrics, clean = _metrics(points, point_colors), _metrics(tree, colors)
    assert metrics.crown_base_m == pytest.approx(clean.crown_base_m)
    assert metrics.width_m == pytest.approx(clean.width_m)


def test_fallen_apples_do_not_move_the_crown_base() -> None:
    rng = np.random.default_rng(21)
    tree, colors = _leafy_tree(rng)
    apples = np.vstack(
        [
            _blob(rng, [r * np.cos(a), r * np.sin(a), 0.16], [0.04, 0.04, 0.04], 150)
            for r, a in zip(rng.uniform(0.3, 1.2, 8), rng.uniform(0, 2 * np.pi, 8), strict=True)
        ]
    )  # on grass, above the 12 cm clearance
    points, point_colors = _with(tree, colors, apples, APPLE)
    assert _old_crown_base(points, point_colors) < 0.25
    assert _metrics(points, point_colors).crown_base_m == pytest.approx(_metrics(tree, colors).crown_base_m)


def test_flying_pixels_below_the_crown_do_not_lower_the_crown_base() -> None:
    rng = np.random.default_rng(22)
    tree, colors = _leafy_tree(rng)
    flying = _blob(rng, [0.3, -0.2, 0.5], [0.05, 0.05, 0.25], 60)  # mixed trunk and leaf colours
    points, point_colors = _with(tree, colors, flying, LEAF)
    assert _old_crown_base(points, point_colors) < 0.7
    assert _metrics(points, point_colors).crown_base_m == pytest.approx(_metrics(tree, colors).crown_base_m)


def test_green_bark_on_the_trunk_below_the_crown_is_not_its_base() -> None:
    """Bark that takes the colour of the leaves behind it, 10-20 cm below the crown, right on the trunk."""
    rng = np.random.default_rng(23)
    tree, colors = _leafy_tree(rng)
    green = (np.abs(tree[:, 2] - 0.9) < 0.05) & (np.linalg.norm(tree[:, :2], axis=1) < 0.07)
    colors[green] = LEAF
    assert _old_crown_base(tree, colors) < CROWN_BASE_M - 0.1
    assert _metrics(tree, colors).crown_base_m == pytest.approx(_lowest_leaf(tree), abs=0.02)


def test_crown_pieces_apart_from_the_rest_still_count_as_crown() -> None:
    """A cluster of leaves hanging 15 cm apart from the crown, at its height, and its lowest leaves close
    to the trunk, which join it."""
    rng = np.random.default_rng(24)
    tree, colors = _leafy_tree(rng)
    apart = _blob(rng, [1.0, 0.0, 1.6], [0.05, 0.05, 0.05], 200)
    near_trunk = _blob(rng, [0.08, 0.0, 1.02], [0.03, 0.03, 0.02], 100)
    points, point_colors = _with(*_with(tree, colors, apart, LEAF), near_trunk, LEAF)
    crown = _crown(points, foliage_mask(point_colors, min_index=0.15))
    assert crown[len(tree) :].all()
    assert _metrics(points, point_colors).width_m == pytest.approx(max_horizontal_distance(points), abs=1e-9)


def _wire_pieces(rng: np.random.Generator, z_m: float, pieces: list[tuple[float, float]]) -> np.ndarray:
    """Stretches (x from, x to) of a trellis wire at height ``z_m`` along the row, as a view sees it beside a
    crown: a line of points about a pixel (1 cm) apart, spread a few centimetres across by mixed pixels, level
    within 5 mm."""
    x = np.concatenate([rng.uniform(low, high, int((high - low) / 0.01)) for low, high in pieces])
    return np.column_stack([x, rng.normal(0.0, 0.02, x.size), z_m + rng.normal(0.0, 0.004, x.size)])


def test_pieces_of_a_wire_beside_the_crown_do_not_widen_it() -> None:
    """A wire through the crown at 2.4 m, hidden inside it, seen beside it in pieces 14-35 cm long with
    gaps wider than the link distance: pieces at crown height, apart from it, which it used to take in."""
    rng = np.random.default_rng(25)
    tree, colors = _leafy_tree(rng)
    wire = _wire_pieces(rng, 2.4, [(-1.35, -1.1), (-1.0, -0.86), (0.9, 1.25)])
    points, point_colors = _with(tree, colors, wire, (120, 120, 120))
    metrics = _metrics(points, point_colors)
    assert max_horizontal_distance(points) > _metrics(tree, colors).width_m + 0.5  # what was wrong
    assert metrics.width_m == pytest.approx(_metrics(tree, colors).width_m, abs=0.01)


def test_a_stray_pair_of_points_far_beside_the_crown_does_not_set_its_width() -> None:
    rng = np.random.default_rng(26)
    tree, colors = _leafy_tree(rng)
    stray = np.array([[1.3, 0.1, 2.0], [1.31, 0.1, 2.01]])  # flying pixels, each the other's only neighbour
    points, point_colors = _with(tree, colors, stray, LEAF)
    width = _metrics(points, point_colors).width_m
    assert max_horizontal_distance(points) > width + 0.3  # what was wrong
    assert width == pytest.approx(_metrics(tree, colors).width_m, abs=1e-9)


def test_a_speck_above_the_crown_apart_from_it_does_not_raise_the_top() -> None:
    """A glint of a wire 30 cm above the crown: a few points, two voxels, each with neighbours."""
    rng = np.random.default_rng(27)
    tree, colors = _leafy_tree(rng)
    speck = np.array([[0.3, 0.0, 3.25], [0.31, 0.0, 3.25], [0.33, 0.01, 3.25], [0.35, 0.0, 3.26]])
    points, point_colors = _with(tree, colors, speck, LEAF)
    assert canopy_height(points, support_points=2) > _metrics(tree, colors).height_m + 0.2  # what was wrong
    assert _metrics(points, point_colors).height_m == pytest.approx(_metrics(tree, colors).height_m, abs=1e-9)


def test_points_without_any_crown_fail_clearly_instead_of_measuring_nothing() -> None:
    rng = np.random.default_rng(30)
    weeds = rng.uniform([-0.5, -0.5, 0.15], [0.5, 0.5, 0.5], size=(200, 3))

    with pytest.raises(MeasurementError, match="no crown among the 200 tree points"):
        canopy_metrics(
            weeds,
            trunk=PLUMB,
            foliage=np.ones(200, dtype=bool),
            crown=np.zeros(200, dtype=bool),
            config=MetricsConfig(),
        )


def test_a_trellis_post_beside_the_crown_is_neither_crown_nor_height() -> None:
    """A 10 cm post 1.2 m from the trunk, standing 3.1 m tall beside a crown topping out at 2.94 m, apart
    from it once the wires are gone: a body at the crown's height, but one that rises from the ground."""
    rng = np.random.default_rng(30)
    tree, colors = _leafy_tree(rng)
    angle, z = rng.uniform(0, 2 * np.pi, 3000), rng.uniform(0.12, 3.1, 3000)
    post = np.column_stack([1.2 + 0.05 * np.cos(angle), 0.05 * np.sin(angle), z])
    points, point_colors = _with(tree, colors, post, (110, 95, 70))
    alone = _metrics(tree, colors)

    metrics = _metrics(points, point_colors)

    grounded = canopy_metrics(
        points,
        trunk=PLUMB,
        foliage=foliage_mask(point_colors, min_index=0.15),
        config=MetricsConfig(crown_piece_min_bottom_m=0.0),
    )
    assert grounded.height_m > alone.height_m + 0.1  # what was wrong: the post was a piece of the crown
    assert metrics.height_m == pytest.approx(alone.height_m, abs=0.005)
    assert metrics.width_m == pytest.approx(alone.width_m, abs=0.005)
    assert metrics.crown_base_m == pytest.approx(alone.crown_base_m, abs=0.005)


def _pole(
    rng: np.random.Generator, xy: tuple[float, float], top_m: float, radius_m: float = 0.01
) -> np.ndarray:
    """A stake's surface from the ground to ``top_m``, 200 points a metre."""
    count = int(200 * top_m)
    angle, z = rng.uniform(0, 2 * np.pi, count), rng.uniform(0.12, top_m, count)
    return np.column_stack([xy[0] + radius_m * np.cos(angle), xy[1] + radius_m * np.sin(angle), z])


def test_a_stake_standing_above_the_crown_is_refused_not_measured_as_its_top() -> None:
    rng = np.random.default_rng(40)
    tree, colors = _leafy_tree(rng)
    crown_top = float(tree[:, 2].max())
    stake = _pole(rng, (0.07, 0.0), crown_top + 0.3)
    points, point_colors = _with(tree, colors, stake, (150, 150, 150))
    assert canopy_height(points) > crown_top + 0.25  # what the top was: the stake's
    assert thin_top_m(points, top_z_m=float(points[:, 2].max()), slab_m=0.05, width_m=0.03) >= 0.25
    with pytest.raises(MeasurementError, match="thin as a pole") as refused:
        _metrics(points, point_colors)
    assert refused.value.field == "metrics.max_thin_top_m"
    # A leader whose bare tip stands out as far may be measured with the bound the hint names.
    named = re.search(r"metrics\.max_thin_top_m=([0-9.]+) ", refused.value.hint or "")
    assert named is not None, refused.value.hint
    allowed = canopy_metrics(
        points,
        trunk=PLUMB,
        foliage=foliage_mask(point_colors, min_index=0.15),
        config=MetricsConfig(max_thin_top_m=float(named.group(1))),
    )
    assert allowed.height_m > crown_top + 0.25


def test_a_bare_leader_tip_and_a_stake_inside_the_crown_are_measured() -> None:
    rng = np.random.default_rng(41)
    tree, colors = _leafy_tree(rng)
    crown_top = float(tree[:, 2].max())
    tip = _pole(rng, (0.0, 0.0), crown_top + 0.12, radius_m=0.006)
    tip = tip[tip[:, 2] > crown_top - 0.3]
    hidden = _pole(rng, (0.07, 0.0), crown_top - 0.4)
    points, point_colors = _with(tree, colors, np.vstack([tip, hidden]), (110, 95, 70))
    assert thin_top_m(points, top_z_m=float(points[:, 2].max()), slab_m=0.05, width_m=0.03) <= 0.15
    assert _metrics(points, point_colors).height_m > crown_top + 0.1
    assert thin_top_m(tree, top_z_m=crown_top, slab_m=0.05, width_m=0.03) == 0.0
