"""The trunk's axis followed up from its foot, and the crown told from a leaning or bending trunk by it."""

from __future__ import annotations

import numpy as np
import pytest

from canopy_core.config import MetricsConfig
from canopy_core.foliage import foliage_mask
from canopy_core.metrics import canopy_metrics
from canopy_core.trunk_axis import TrunkAxis, follow_trunk

BARK, LEAF = (95, 75, 55), (60, 125, 45)
CROWN_BASE_M = 1.1
FOOT_RADIUS_M = 0.07


def _axis_xy(z_m: np.ndarray, lean_per_m: float) -> np.ndarray:
    """The true trunk's centre at each height: leaning along x, bending a little along y."""
    return np.column_stack([lean_per_m * z_m, 0.02 * np.sin(3.0 * z_m)])


def _radius(z_m: np.ndarray) -> np.ndarray:
    """The trunk tapers from 7 cm at the foot by 1.5 cm a metre."""
    return FOOT_RADIUS_M - 0.015 * z_m


def _trunk(
    rng: np.random.Generator,
    *,
    lean_per_m: float,
    top_m: float,
    arc_rad: tuple[float, float] = (0, 2 * np.pi),
) -> np.ndarray:
    """Bark points on the trunk's surface from the ground to ``top_m``, over the arc ``arc_rad`` round it
    (all round: the views together; half of it: one view)."""
    z = rng.uniform(0.0, top_m, 6000)
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


@pytest.mark.parametrize("arc_rad", [(0.0, 2 * np.pi), (-np.pi, 0.0)], ids=["all round", "one side"])
def test_the_axis_follows_a_leaning_bending_trunk_up_from_its_foot(arc_rad: tuple[float, float]) -> None:
    rng = np.random.default_rng(1)
    lean = np.tan(np.radians(15.0))
    points = _trunk(rng, lean_per_m=lean, top_m=1.2, arc_rad=arc_rad)

    axis = follow_trunk(points, (0.0, 0.0), foot_radius_m=FOOT_RADIUS_M, config=MetricsConfig())

    heights = np.linspace(0.2, 1.1, 10)
    error_m = np.linalg.norm(axis.xy_at(heights) - _axis_xy(heights, lean), axis=1)
    assert error_m.max() < 0.01, error_m
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

    axis = follow_trunk(points, (0.0, 0.0), foot_radius_m=FOOT_RADIUS_M, config=MetricsConfig())

    heights = np.linspace(0.1, CROWN_BASE_M, 11)
    error_m = np.linalg.norm(axis.xy_at(heights) - _axis_xy(heights, lean), axis=1)
    assert error_m.max() < 0.02, error_m
    # where the leaves hide it, the axis holds where the bark was last seen
    np.testing.assert_allclose(axis.xy_at(np.array([2.0, 2.9])), axis.centres_xy_m[[-1, -1]])
    assert axis.heights_m[-1] < CROWN_BASE_M + 0.5


def test_without_a_circle_at_the_foot_the_axis_stands_plumb_above_it() -> None:
    points = _trunk(np.random.default_rng(3), lean_per_m=0.3, top_m=1.2)

    axis = follow_trunk(points, (0.1, -0.2), foot_radius_m=None, config=MetricsConfig())

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
    followed = canopy_metrics(
        points,
        trunk=follow_trunk(points, (0.0, 0.0), foot_radius_m=FOOT_RADIUS_M, config=config),
        foliage=foliage,
        config=config,
    )

    lowest_leaf_m = float(points[-20000:, 2].min())
    assert plumb.crown_base_m < lowest_leaf_m - 0.2  # the column round the foot lets the outline chain down
    # inside the column, the outline joins the crown only within the link distance of its leaves
    assert lowest_leaf_m - config.crown_link_m <= followed.crown_base_m <= lowest_leaf_m
