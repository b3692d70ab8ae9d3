"""The trunk's axis followed up from its foot, and the crown told from a leaning or bending trunk by it."""

from __future__ import annotations

import numpy as np
import pytest

from canopy_core.config import MetricsConfig
from canopy_core.foliage import foliage_mask
from canopy_core.ground import TRUNK_SLICE_M
from canopy_core.metrics import canopy_metrics
from canopy_core.trunk_axis import TrunkAxis, follow_trunk

BARK, LEAF = (95, 75, 55), (60, 125, 45)
CROWN_BASE_M = 1.1
FOOT_Z_M = sum(TRUNK_SLICE_M) / 2
"""The ground frame finds the trunk's foot circle in its low slice: the circle at this height."""


def _axis_xy(z_m: np.ndarray, lean_per_m: float) -> np.ndarray:
    """The true trunk's centre at each height: leaning along x, bending a little along y."""
    return np.column_stack([lean_per_m * z_m, 0.02 * np.sin(3.0 * z_m)])


def _radius(z_m: np.ndarray) -> np.ndarray:
    """The trunk tapers from 7 cm at the ground by 1.5 cm a metre."""
    return 0.07 - 0.015 * np.asarray(z_m)


def _follow(points: np.ndarray, lean_per_m: float, config: MetricsConfig | None = None) -> TrunkAxis:
    """The axis followed from the foot circle the ground frame finds: the trunk's circle in its slice."""
    foot = _axis_xy(np.array([FOOT_Z_M]), lean_per_m)[0]
    return follow_trunk(
        points, foot, foot_radius_m=float(_radius(FOOT_Z_M)), config=config or MetricsConfig()
    )


def _trunk(
    rng: np.random.Generator,
    *,
    lean_per_m: float,
    top_m: float,
    arc_rad: tuple[float, float] = (0, 2 * np.pi),
    count: int = 6000,
) -> np.ndarray:
    """Bark points on the trunk's surface from the ground to ``top_m``, over the arc ``arc_rad`` round it
    (all round: the views together; half of it: one view)."""
    z = rng.uniform(0.0, top_m, count)
    angle = rng.uniform(*arc_rad, z.size)
    ring = np.column_stack([np.cos(angle), np.sin(angle)]) * _radius(z)[:, None]
    return np.column_stack([_axis_xy(z, lean_per_m) + ring, z])


def _crown(rng: np.random.Generator, *, lean_per_m: float) -> np.ndarray:
    """Leaves from ``CROWN_BASE_M`` up to 2.9 m round the leaning trunk's top."""
    direction = rng.normal(size=(20000, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    blob = direction * np.array([0.8, 0.6, 0.9]) * rng.uniform(0, 1, (20000, 1)) ** (1 / 3)
    centre_z = CROWN_BASE_M + 0.9
    return blob + np.r_[_axis_xy(np.array([centre_z]), lean_per_m)[0], centre_z]


def _error_m(axis: TrunkAxis, heights_m: np.ndarray, lean_per_m: float) -> np.ndarray:
    return np.linalg.norm(axis.xy_at(heights_m) - _axis_xy(heights_m, lean_per_m), axis=1)


@pytest.mark.parametrize("arc_rad", [(0.0, 2 * np.pi), (-np.pi, 0.0)], ids=["all round", "one side"])
def test_the_axis_follows_a_leaning_bending_trunk_up_from_its_foot(arc_rad: tuple[float, float]) -> None:
    rng = np.random.default_rng(1)
    lean = np.tan(np.radians(15.0))
    points = _trunk(rng, lean_per_m=lean, top_m=1.2, arc_rad=arc_rad)

    axis = _follow(points, lean)

    heights = np.linspace(FOOT_Z_M, 1.1, 10)
    assert _error_m(axis, heights, lean).max() < 0.01, _error_m(axis, heights, lean)
    assert np.linalg.norm(_axis_xy(np.array([1.1]), lean)) > 0.25  # far outside a plumb column


def test_weeds_round_the_foot_and_the_crown_round_the_trunk_leave_the_axis_where_the_bark_is() -> None:
    rng = np.random.default_rng(2)
    lean = np.tan(np.radians(10.0))
    trunk = _trunk(rng, lean_per_m=lean, top_m=1.6)
    weeds = np.vstack(
        [
            rng.normal([0.25 * np.cos(a), 0.25 * np.sin(a), 0.2], [0.08, 0.08, 0.1], size=(600, 3))
            for a in (0.4, 2.5, 4.3)
        ]
    )
    points = np.vstack([trunk, weeds, _crown(rng, lean_per_m=lean)])

    axis = _follow(points, lean)

    heights = np.linspace(FOOT_Z_M, CROWN_BASE_M, 10)
    assert _error_m(axis, heights, lean).max() < 0.02, _error_m(axis, heights, lean)


@pytest.mark.parametrize("leaves", [600, 20000], ids=["sparse leaves", "leaves denser than the bark"])
def test_leaves_round_the_trunk_end_the_axis_where_the_bark_was_last_seen(leaves: int) -> None:
    # The bark is seen to 0.8 m; above it, within the lean's reach, leaves fill the trunk's circle: no
    # circle holds as many points as the bark's did, or (denser) every circle has as many inside it.
    rng = np.random.default_rng(5)
    lean = np.tan(np.radians(10.0))
    trunk = _trunk(rng, lean_per_m=lean, top_m=0.8)
    foliage = np.column_stack(
        [
            _axis_xy(np.full(leaves, 0.95), lean) + rng.uniform(-0.12, 0.12, (leaves, 2)),
            rng.uniform(0.8, 1.1, leaves),
        ]
    )

    axis = _follow(np.vstack([trunk, foliage]), lean)

    assert 0.6 < axis.heights_m[-1] < 0.8
    np.testing.assert_allclose(axis.xy_at(np.array([1.0, 1.4])), axis.centres_xy_m[[-1, -1]])


def test_a_wider_ring_standing_on_the_trunk_is_not_taken_for_it() -> None:
    # The bark (5.8 cm radius there) is seen to 0.8 m; on it stands a hollow ring of 8 cm, 1.4 cm off its
    # axis (a fork's stems round a hollow, a guard), which the lean would let the axis step onto.
    rng = np.random.default_rng(8)
    lean = np.tan(np.radians(10.0))
    trunk = _trunk(rng, lean_per_m=lean, top_m=0.8)
    angle, z = rng.uniform(0, 2 * np.pi, 8000), rng.uniform(0.8, 1.6, 8000)
    ring = np.column_stack([_axis_xy(np.full(z.size, 0.8), lean) + 0.01, z])
    ring[:, :2] += 0.08 * np.column_stack([np.cos(angle), np.sin(angle)])

    axis = _follow(np.vstack([trunk, ring]), lean)

    assert axis.heights_m[-1] < 0.9  # at most the slab where bark and ring meet


def test_the_axis_stays_on_the_bark_beside_a_stake_and_ends_where_the_bark_hides_longer_than_the_gap() -> (
    None
):
    # A stake 2 cm thick stands beside the bark all the way up; leaves hide the trunk from 0.7 to 1.3 m,
    # where only the stake shows, and the trunk shows again above (a leader, or a branch).
    rng = np.random.default_rng(6)
    lean = np.tan(np.radians(8.0))
    trunk = _trunk(rng, lean_per_m=lean, top_m=1.8)
    trunk = trunk[(trunk[:, 2] < 0.7) | (trunk[:, 2] > 1.3)]
    angle, z = rng.uniform(0, 2 * np.pi, 3000), rng.uniform(0.0, 1.8, 3000)
    stake = np.column_stack([0.1 + 0.01 * np.cos(angle), -0.08 + 0.01 * np.sin(angle), z])

    axis = _follow(np.vstack([trunk, stake]), lean)

    heights = np.linspace(FOOT_Z_M, 0.65, 5)
    assert _error_m(axis, heights, lean).max() < 0.01
    assert axis.heights_m[-1] < 0.7  # more than trunk_max_gap_m hidden: the bark above is not followed


def test_no_lean_allowed_or_no_circle_at_the_foot_keeps_the_axis_plumb_above_it() -> None:
    points = _trunk(np.random.default_rng(3), lean_per_m=0.3, top_m=1.2)

    for axis in (
        follow_trunk(points, (0.1, -0.2), foot_radius_m=None, config=MetricsConfig()),
        follow_trunk(points, (0.1, -0.2), foot_radius_m=0.07, config=MetricsConfig(trunk_max_lean_deg=0.0)),
    ):
        np.testing.assert_allclose(axis.xy_at(np.array([0.0, 0.6, 2.0])), [[0.1, -0.2]] * 3)


def _tree_with_outline(rng: np.random.Generator, lean_per_m: float) -> tuple[np.ndarray, np.ndarray]:
    """A leaning trunk into a crown, its outline on one side a line of mixed pixels that the leaves behind
    the trunk colour green (as a camera whose white balance greens the bark sees it): points ``(N, 3)`` and
    their colours."""
    bark = _trunk(rng, lean_per_m=lean_per_m, top_m=CROWN_BASE_M + 0.2)
    z = rng.uniform(0.3, CROWN_BASE_M + 0.2, 800)
    outline = np.column_stack(
        [_axis_xy(z, lean_per_m) + np.column_stack([np.zeros_like(z), _radius(z) + 0.005]), z]
    )
    crown = _crown(rng, lean_per_m=lean_per_m)
    colours = np.vstack([np.tile(BARK, (len(bark), 1)), np.tile(LEAF, (len(outline) + len(crown), 1))])
    return np.vstack([bark, outline, crown]), colours.astype(np.uint8)


@pytest.mark.parametrize("lean_deg", [5.0, 15.0])
def test_a_leaning_trunks_green_outline_is_not_taken_for_the_crown_reaching_down(lean_deg: float) -> None:
    rng = np.random.default_rng(4)
    lean = np.tan(np.radians(lean_deg))
    points, colours = _tree_with_outline(rng, lean)
    foliage = foliage_mask(colours, min_index=0.15)
    config = MetricsConfig()

    plumb = canopy_metrics(points, trunk=TrunkAxis.vertical((0.0, 0.0)), foliage=foliage, config=config)
    followed = canopy_metrics(points, trunk=_follow(points, lean), foliage=foliage, config=config)

    lowest_leaf_m = float(points[-20000:, 2].min())
    assert plumb.crown_base_m < lowest_leaf_m - 0.2  # the column round the foot lets the outline chain down
    # inside the column, the outline joins the crown only within the link distance of its leaves
    assert lowest_leaf_m - config.crown_link_m <= followed.crown_base_m <= lowest_leaf_m
