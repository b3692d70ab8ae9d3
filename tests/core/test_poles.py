"""Trellis posts beside the tree found by their shape, whatever the crown grown round them."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from canopy_core.config import MetricsConfig, PoleConfig
from canopy_core.metrics import canopy_metrics
from canopy_core.poles import Pole, _slab_groups, find_poles, pole_mask
from canopy_core.trunk_axis import TrunkAxis

TRUNK_RADIUS_M = 0.06
POST_XY_M = np.array([0.7, 0.02])
CROWN_BASE_M, CROWN_TOP_M = 1.0, 2.6
FOOT_BELOW_M = MetricsConfig().crown_piece_min_bottom_m
NOISE_M = 0.004
"""Each coordinate's noise on a surface point."""


def _cylinder(
    rng: np.random.Generator, xy: np.ndarray, radius_m: float, low_m: float, high_m: float, count: int
) -> np.ndarray:
    """Points on an upright cylinder's surface, seen all round (two views facing each other)."""
    z = rng.uniform(low_m, high_m, count)
    angle = rng.uniform(0.0, 2 * np.pi, count)
    surface = xy + radius_m * np.column_stack([np.cos(angle), np.sin(angle)])
    return np.column_stack([surface, z]) + rng.normal(0.0, NOISE_M, (count, 3))


def _crown(rng: np.random.Generator) -> np.ndarray:
    """Leaves filling an ellipsoid round the trunk's top, from ``CROWN_BASE_M`` to ``CROWN_TOP_M``, 0.9 m
    across along the row: a post 0.7 m from the trunk stands inside it."""
    direction = rng.normal(size=(25000, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    half = np.array([0.9, 0.6, (CROWN_TOP_M - CROWN_BASE_M) / 2])
    blob = direction * half * rng.uniform(0, 1, (25000, 1)) ** (1 / 3)
    return blob + np.array([0.0, 0.0, (CROWN_TOP_M + CROWN_BASE_M) / 2])


def _grass(rng: np.random.Generator, *, near_xy: np.ndarray, height_m: float, count: int) -> np.ndarray:
    """Stems of grass standing up to ``height_m`` scattered round ``near_xy``."""
    xy = near_xy + rng.uniform(-0.25, 0.25, (count, 2))
    return np.column_stack([xy, rng.uniform(0.12, height_m, count)])


def _tree(rng: np.random.Generator) -> dict[str, np.ndarray]:
    """The tree's parts: its trunk at the origin, its crown, and the leader's bare tip over the crown."""
    tip_z = np.arange(CROWN_TOP_M, CROWN_TOP_M + 0.2, 0.01)
    return {
        "trunk": _cylinder(rng, np.zeros(2), TRUNK_RADIUS_M, 0.12, CROWN_BASE_M + 0.3, 4000),
        "crown": _crown(rng),
        "tip": np.column_stack([np.full((tip_z.size, 2), 0.01), tip_z]),
    }


def _heights(points: np.ndarray) -> np.ndarray:
    """Height above a level ground at z = 0."""
    return points[:, 2].copy()


def _poles(points: np.ndarray, trunk_xy: tuple[float, float] = (0.0, 0.0)) -> tuple[Pole, ...]:
    """The poles among ``points``, the trunk's foot at ``trunk_xy``."""
    return find_poles(
        points,
        _heights(points),
        trunk_xy_m=np.asarray(trunk_xy),
        trunk_radius_m=TRUNK_RADIUS_M,
        foot_below_m=FOOT_BELOW_M,
        config=PoleConfig(),
    )


def _on(points: np.ndarray, poles: tuple[Pole, ...]) -> np.ndarray:
    """Mask of the points on any of the poles themselves (not along a view's sight of them)."""
    mask = np.zeros(points.shape[0], dtype=bool)
    for pole in poles:
        mask |= pole.contains(points)
    return mask


def test_a_post_the_crown_has_grown_round_is_found_from_the_ground_to_its_top_above_the_crown() -> None:
    rng = np.random.default_rng(0)
    parts = _tree(rng)
    post = _cylinder(rng, POST_XY_M, 0.05, 0.12, CROWN_TOP_M + 0.5, 8000)
    points = np.vstack([*parts.values(), post])

    poles = _poles(points)

    assert len(poles) == 1
    on_post = _on(post, poles)
    assert on_post.all()  # below the crown, through it and above it
    assert not _on(parts["trunk"], poles).any()
    assert not _on(parts["tip"], poles).any()
    # The leaves touching the post, no more: within its 5 cm radius, the noise (the widest of a slab's
    # hundred-odd points, at most 4 sigma) and the tolerance.
    assert poles[0].radius_m < 0.05 + 4 * NOISE_M + PoleConfig().tolerance_m
    taken = parts["crown"][_on(parts["crown"], poles)]
    assert (np.linalg.norm(taken[:, :2] - POST_XY_M, axis=1) < poles[0].radius_m + 0.01).all()


def test_the_tree_is_measured_to_its_own_top_not_the_post_s() -> None:
    rng = np.random.default_rng(1)
    parts = _tree(rng)
    post = _cylinder(rng, POST_XY_M, 0.05, 0.12, CROWN_TOP_M + 0.5, 8000)
    points = np.vstack([*parts.values(), post])
    config = MetricsConfig(edge_px=0.0)
    trunk = TrunkAxis.vertical((0.0, 0.0))

    with_post = canopy_metrics(points, trunk=trunk, config=config)
    without = canopy_metrics(points[~_on(points, _poles(points))], trunk=trunk, config=config)

    assert with_post.height_m > CROWN_TOP_M + 0.4  # the post's top, as before
    assert abs(without.height_m - (CROWN_TOP_M + 0.19)) < 0.02  # the leader's tip
    assert without.crown_base_m == with_post.crown_base_m  # the lowest leaves, which the post did not touch
    assert without.width_m == with_post.width_m  # the post stands inside the crown's outline


def test_a_post_whose_foot_tall_grass_hides_is_found_from_above_the_grass() -> None:
    rng = np.random.default_rng(2)
    parts = _tree(rng)
    post = _cylinder(rng, POST_XY_M, 0.05, 0.12, 2.2, 6000)
    grass = _grass(rng, near_xy=POST_XY_M, height_m=0.5, count=3000)
    hidden = post[:, 2] < 0.45
    points = np.vstack([*parts.values(), post[~hidden], grass])

    poles = _poles(points)

    assert len(poles) == 1
    # Inside the crown it is followed up as long as its surface shows: to its top, within a slab.
    assert abs(poles[0].top_m - 2.2) <= PoleConfig().slab_m
    seen = post[~hidden]
    assert _on(seen[seen[:, 2] <= poles[0].top_m], poles).all()


def test_the_trunk_a_leader_s_bare_tip_and_a_weed_are_no_poles() -> None:
    rng = np.random.default_rng(3)
    parts = _tree(rng)
    weed = _cylinder(rng, np.array([-0.5, 0.3]), 0.04, 0.12, 0.4, 800)  # a stem 0.3 m tall
    grass = _grass(rng, near_xy=np.array([0.4, -0.4]), height_m=0.45, count=3000)
    points = np.vstack([*parts.values(), weed, grass])

    assert _poles(points) == ()


def test_an_upright_nearer_the_crown_s_middle_than_the_trunk_is_not_taken_for_a_post() -> None:
    # Were the trunk found on a post beside it (a better-seen circle at the foot), the tree's own trunk
    # would stand like a post beside it: it is left alone, not cut out of the tree.
    rng = np.random.default_rng(4)
    parts = _tree(rng)
    post = _cylinder(rng, POST_XY_M, 0.05, 0.12, CROWN_TOP_M + 0.5, 8000)
    points = np.vstack([*parts.values(), post])

    poles = _poles(points, trunk_xy=(float(POST_XY_M[0]), float(POST_XY_M[1])))

    assert not _on(parts["trunk"], poles).any()


def test_a_view_s_noisy_and_mixed_pixels_along_a_post_s_outline_are_the_post_s_not_the_crown_s() -> None:
    """One camera 3.5 m away: at the outline of a round post its pixels meet it at grazing incidence and
    scatter along the rays, in front of it and behind; above the crown they would stand as the tree's top.
    What lies along the outline in front of the post inside the crown is leaves, and stays."""
    rng = np.random.default_rng(5)
    camera = np.array([POST_XY_M[0], -3.5, 1.3])
    parts = _tree(rng)
    post = _cylinder(rng, POST_XY_M, 0.05, 0.12, CROWN_TOP_M + 0.5, 8000)
    poles = _poles(np.vstack([*parts.values(), post]))
    z = rng.uniform(CROWN_TOP_M + 0.05, CROWN_TOP_M + 0.45, 60)
    along_ray = rng.choice([-1.0, 1.0], 60) * rng.uniform(0.03, 0.25, 60)  # off the surface, either way
    scattered = np.column_stack([np.full(60, POST_XY_M[0] + 0.04), np.full(60, POST_XY_M[1] - 0.05), z])
    scattered[:, 1] += along_ray
    leaves_in_front = np.column_stack(
        [np.full(30, POST_XY_M[0] + 0.02), np.full(30, -0.25), rng.uniform(1.4, 2.0, 30)]
    )
    beside = np.column_stack([np.full(30, POST_XY_M[0] + 0.2), np.full(30, -0.1), rng.uniform(2.7, 3.0, 30)])

    def in_sight(points: np.ndarray) -> np.ndarray:
        return pole_mask(points, poles, camera_m=camera, spread_m=PoleConfig().spread_m)

    assert not _on(scattered, poles).all()  # the cylinder alone leaves some: they would make the top
    assert in_sight(scattered).all()
    assert not in_sight(leaves_in_front).any()
    assert not in_sight(beside).any()


def test_a_sucker_and_a_second_stem_under_the_crown_are_no_poles() -> None:
    # A root sucker 1.2 cm thick 0.3 m from the trunk reaching into the crown is thinner than any post; a
    # second stem 0.4 m from the trunk, as thick, stands as near the crown's middle as the trunk does.
    rng = np.random.default_rng(6)
    parts = _tree(rng)
    sucker = _cylinder(rng, np.array([0.0, 0.3]), 0.006, 0.12, 1.4, 1500)
    stem = _cylinder(rng, np.array([-0.4, 0.0]), TRUNK_RADIUS_M, 0.12, CROWN_BASE_M + 0.3, 4000)
    crown = parts["crown"] + np.array([-0.2, 0.0, 0.0])  # over both stems
    points = np.vstack([parts["trunk"], crown, parts["tip"], sucker, stem])

    poles = _poles(points)

    assert not _on(sucker, poles).any()
    assert not _on(stem, poles).any()


def test_the_crown_above_a_post_s_top_stays_in_the_tree() -> None:
    rng = np.random.default_rng(7)
    parts = _tree(rng)
    post = _cylinder(rng, POST_XY_M, 0.05, 0.12, 1.6, 5000)  # ends inside the crown
    points = np.vstack([*parts.values(), post])
    camera = np.array([0.0, -3.5, 1.3])

    poles = _poles(points)

    assert len(poles) == 1 and poles[0].top_m <= 1.6 + PoleConfig().slab_m
    above = parts["crown"][parts["crown"][:, 2] > 1.7]
    assert not pole_mask(above, poles, camera_m=camera, spread_m=PoleConfig().spread_m).any()


def test_a_post_s_top_above_the_crown_is_joined_by_the_line_through_all_its_stretches_below() -> None:
    """Held-out near posts 2115021: the stretch by a post's foot, 0.4 m long, leaned 3 cm a metre by what
    stood round it; carried up 3 m, its line missed the post's top above the crown (seen from one view
    only, its centre off the axis towards that camera) by more than the thickest post's radius, the top
    was not joined, and that view's noisy pixels in front of it made the tree's top: H +0.23 m."""
    rng = np.random.default_rng(8)
    parts = _tree(rng)
    foot = _cylinder(rng, POST_XY_M, 0.05, 0.12, 0.55, 1500)
    foot[:, 1] += 0.08 * (foot[:, 2] - 0.12)  # grass and mixed pixels on one side, more so higher up
    below_crown = _cylinder(rng, POST_XY_M, 0.05, 0.85, 1.3, 1500)
    inside_crown = _cylinder(rng, POST_XY_M, 0.05, 1.3, CROWN_TOP_M, 6000)
    top = _cylinder(rng, POST_XY_M, 0.05, CROWN_TOP_M, CROWN_TOP_M + 0.5, 4000)
    top = top[top[:, 1] < POST_XY_M[1]]  # seen from one side: one camera, 3.5 m along -y
    points = np.vstack([*parts.values(), foot, below_crown, inside_crown, top])

    poles = _poles(points)

    assert len(poles) == 1
    highest_alone = max(high for _, high in poles[0].alone_m)
    assert highest_alone > CROWN_TOP_M + 0.4  # the top's stretch is the pole's, standing alone
    assert _on(top, poles).all()


def test_a_post_s_short_top_above_the_crown_is_joined_though_its_few_slabs_seem_to_lean() -> None:
    """Held-out near posts 2120043: a post's top showed above the crown over 20 cm, and the line through
    those four slabs' centres leaned 11 degrees, past the steepest a post stands (10), though four slabs
    fix a lean only to 10 degrees; the top was not a straight stretch, stayed in the tree and made its
    height (H +8 %, D +14 %). A stretch's lean is judged within its standard error."""
    rng = np.random.default_rng(12)
    parts = _tree(rng)
    post = _cylinder(rng, POST_XY_M, 0.05, 0.12, 2.65, 12000)
    top = post[:, 2] > 2.45  # above the crown's leaves round the post
    post[top, 1] += 0.3 * (post[top, 2] - 2.45)  # its centres drift 6 cm (fitted, 17 degrees)
    points = np.vstack([*parts.values(), post])

    poles = _poles(points)

    assert len(poles) == 1
    assert poles[0].top_m >= 2.65
    assert _on(post[top], poles).all()


def test_a_short_stretch_beside_a_post_does_not_bend_its_line_away_from_its_top() -> None:
    """Tuning near posts 2121057: above a post's foot, a short stretch 15 cm beside the post (at the crown's
    top), taken first as the lowest, bent the line through the post's stretches away from its top above
    the crown, which was not joined and made H (+0.56 m). The stretch the line passes nearest is joined
    first."""
    rng = np.random.default_rng(13)
    parts = _tree(rng)
    foot = _cylinder(rng, POST_XY_M, 0.05, 0.12, CROWN_BASE_M, 4000)
    top = _cylinder(rng, POST_XY_M, 0.05, 2.95, 3.45, 3000)  # hidden by leaves from 1 m up to it
    beside = _cylinder(rng, POST_XY_M + np.array([0.15, 0.0]), 0.03, 2.5, 2.65, 600)
    points = np.vstack([*parts.values(), foot, top, beside])

    poles = _poles(points)

    assert len(poles) == 1
    assert _on(top, poles).all()


@pytest.mark.parametrize("side_m", [0.2, -0.2])
def test_a_longer_stem_beside_a_post_s_top_does_not_take_its_place(side_m: float) -> None:
    # At the heights of the post's top a stem 20 cm off its line, 3 cm thick and longer than the top's
    # stretch, is within the reach of the foot's line extrapolated too (a review's probe of a version that
    # joined the longest stretch first: the stem was joined, the post's top left in the tree).
    rng = np.random.default_rng(13)
    parts = _tree(rng)
    foot = _cylinder(rng, POST_XY_M, 0.05, 0.12, CROWN_BASE_M, 4000)
    top = _cylinder(rng, POST_XY_M, 0.05, 2.95, 3.45, 3000)
    stem = _cylinder(rng, POST_XY_M + np.array([side_m, 0.0]), 0.03, 3.0, 3.8, 2000)

    poles = _poles(np.vstack([*parts.values(), foot, top, stem]))

    assert len(poles) == 1
    assert _on(top, poles).all()


def test_a_stem_leaning_more_than_a_post_is_no_pole_though_its_short_stretches_may_seem_plumb() -> None:
    # Split into stretches too short to be a pole's foot, a leaning stem's pieces each pass as straight
    # within their lean's standard error; the lowest is no foot (a review's probe of a first version: a
    # stem leaning 12 degrees, 0.9 m long, taken whole for a pole).
    rng = np.random.default_rng(0)
    parts = _tree(rng)
    z = rng.uniform(0.1, 1.0, 5400)
    angle = rng.uniform(0.0, 2 * np.pi, z.size)
    outwards = np.tan(np.radians(12.0)) * np.array([np.cos(2.6), np.sin(2.6)])
    xy = (
        np.array([-0.55, 0.3])
        + z[:, None] * outwards
        + 0.04 * np.column_stack([np.cos(angle), np.sin(angle)])
    )
    stem = np.column_stack([xy, z]) + rng.normal(0.0, NOISE_M, (z.size, 3))
    assert not _on(stem, _poles(np.vstack([*parts.values(), stem]))).any()


def test_a_post_is_found_though_another_post_beside_the_crown_pulls_the_crown_s_middle_towards_it() -> None:
    """Held-out near posts 2117045: a post 1.4 m from the trunk, 3.5 m tall, put the middle of what stands
    above the other post's foot half-way to it, where the trunk no longer stood clearly nearer than that
    post: the post was left in the tree, and its top above the crown made H. Every post found is left
    out of the crown's middle."""
    rng = np.random.default_rng(9)
    parts = _tree(rng)
    crown = parts["crown"] + np.array([0.3, 0.0, 0.0])  # lopsided towards the far post
    near_post = _cylinder(rng, np.array([-0.45, 0.02]), 0.05, 0.12, CROWN_TOP_M + 0.5, 8000)
    far_post = _cylinder(rng, np.array([1.6, 0.02]), 0.05, 0.12, CROWN_TOP_M + 0.9, 20000)
    points = np.vstack([parts["trunk"], crown, parts["tip"], near_post, far_post])

    poles = _poles(points)

    assert len(poles) == 2
    assert _on(near_post, poles).all()
    assert _on(far_post, poles).all()
    assert not _on(parts["trunk"], poles).any()


def _bent_stem(
    rng: np.random.Generator,
    foot_xy: np.ndarray,
    radius_m: float,
    knee_m: float,
    top_m: float,
    lean_deg: float,
) -> np.ndarray:
    """Points round a stem that leans ``lean_deg`` along x from its foot up to ``knee_m``, then grows plumb
    up to ``top_m``."""
    z = rng.uniform(0.12, top_m, 6000)
    out = np.tan(np.radians(lean_deg)) * np.minimum(z, knee_m)
    angle = rng.uniform(0.0, 2 * np.pi, z.size)
    xy = (
        foot_xy
        + np.column_stack([out, np.zeros_like(out)])
        + radius_m * np.column_stack([np.cos(angle), np.sin(angle)])
    )
    return np.column_stack([xy, z]) + rng.normal(0.0, NOISE_M, (z.size, 3))


def test_a_trunk_or_second_stem_bent_low_down_is_no_pole_though_it_grows_plumb_above_the_bend() -> None:
    # Their lines of groups bend: the plumb stretch above the bend is straight, and its column reaches the
    # ground down the leaning stretch, but it is not where a pole stands (a review's probe: 81 % of such a
    # trunk, and of a second stem 0.25 m from it, taken for a post).
    rng = np.random.default_rng(11)
    parts = _tree(rng)
    stem = _bent_stem(rng, np.array([0.25, 0.0]), 0.04, knee_m=0.45, top_m=1.3, lean_deg=25.0)
    assert not _on(stem, _poles(np.vstack([*parts.values(), stem]))).any()
    trunk = _bent_stem(rng, np.zeros(2), TRUNK_RADIUS_M, knee_m=0.45, top_m=1.3, lean_deg=25.0)
    crown = parts["crown"] + np.array([0.11, 0.0, 0.0])  # between the trunk's foot and its top
    assert not _on(trunk, _poles(np.vstack([trunk, crown]))).any()


def test_the_leader_over_the_trunk_is_not_joined_to_a_post_whose_top_the_crown_hides() -> None:
    # A post's stretch by its foot, 0.3 m long above the grass, carries its line up uncertainly: the bare
    # leader 0.35 m from it over the crown stood within that line's reach (a review's probe: H 3.00 to
    # 2.59 m).
    rng = np.random.default_rng(2)
    parts = _tree(rng)
    post_xy = np.array([0.35, 0.02])
    post = _cylinder(rng, post_xy, 0.05, 0.12, 2.2, 8000)
    leader = _cylinder(rng, np.zeros(2), 0.03, CROWN_TOP_M, CROWN_TOP_M + 0.4, 2000)
    grass = _grass(rng, near_xy=post_xy, height_m=0.5, count=3000)

    poles = _poles(np.vstack([parts["trunk"], parts["crown"], leader, post, grass]))

    assert not _on(leader, poles).any()


def test_a_slab_s_groups_join_cells_within_reach_but_never_across_slabs() -> None:
    slab = np.array([0, 0, 0, 1, 0])
    cell = np.array([[0, 0], [2, 2], [6, 6], [0, 0], [6, 7]])
    count, group = _slab_groups(slab, cell, reach=1)
    # (0, 0) and (2, 2): their squares of one cell touch corner to corner; (6, 6) and (6, 7) share theirs;
    # the cell over (0, 0) in the next slab stands alone. Numbered slab by slab, row by row.
    assert count == 3
    assert group.tolist() == [0, 0, 1, 2, 1]


def test_a_slab_s_groups_are_those_scipy_s_labelling_gives_numbered_alike() -> None:
    rng = np.random.default_rng(0)
    for _ in range(200):
        size = rng.integers(1, 30, 3)
        count = int(rng.integers(1, 300))
        slab = rng.integers(0, size[0], count)
        cell = np.column_stack([rng.integers(0, size[1], count), rng.integers(0, size[2], count)])
        slab, cell = slab - slab.min(), cell - cell.min(axis=0)
        reach = int(rng.integers(1, 4))
        grid = np.zeros((slab.max() + 1, *(cell.max(axis=0) + 1)), dtype=bool)
        grid[slab, cell[:, 0], cell[:, 1]] = True
        for axis in (1, 2):
            grid = ndimage.maximum_filter1d(grid, size=2 * reach + 1, axis=axis)
        within_slab = np.zeros((3, 3, 3), dtype=bool)
        within_slab[1] = True
        labels, expected = ndimage.label(grid, structure=within_slab)
        found, group = _slab_groups(slab, cell, reach)
        assert found == expected
        assert np.array_equal(group, labels[slab, cell[:, 0], cell[:, 1]] - 1)
