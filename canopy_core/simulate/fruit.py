"""Apples: exact spheres hanging among the crown's leaves and lying on the ground, some beside the balls.

An apple is a :class:`~canopy_core.simulate.raycast.Sphere` of kind ``FRUIT``, 6-9 cm across, red (hue
350-10 degrees, the red ball's), yellow-green (hue 50-80 degrees, reaching the yellow ball's) or two-coloured
(a red blush on a yellow-green side). A capture's apples are mostly of one variety, as in a block of one
cultivar. Hanging apples sit just below a leaf of the crown, so they lie inside its envelope or stick out of
it by less than their size, and never lower than the lowest leaf (the crown base keeps its meaning); they
are part of the tree's ground-truth size. Fallen apples rest on the ground under the tree, and some lie
10-40 cm from a ball, often one of the ball's colour.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from canopy_core.simulate.ground import Ground
from canopy_core.simulate.mesh import SurfaceKind, hsv_to_rgb
from canopy_core.simulate.raycast import Sphere
from canopy_core.simulate.scene import BALL_COLORS
from canopy_core.simulate.tree import Tree

__all__ = ["APPLE_DIAMETER_M", "VARIETIES", "fallen_apples", "hanging_apples"]

APPLE_DIAMETER_M = (0.06, 0.09)
VARIETIES = ("red", "yellow-green", "bicolour")
_MAIN_VARIETY_SHARE = 0.8
"""The share of a capture's apples of its main variety; the rest are of any variety."""
_RED = ((350.0, 370.0), (0.6, 0.9), (0.3, 0.65))
_YELLOW_GREEN = ((50.0, 80.0), (0.5, 0.85), (0.5, 0.8))
"""Hue (degrees), saturation and value ranges of the two apple colours."""
_HANGING = (30, 150)
_HANG_BELOW_LEAF_M = (0.0, 0.04)
_HANG_JITTER_M = 0.015
_ABOVE_LOWEST_LEAF_M = 0.02
"""A hanging apple's bottom stays this far above the crown's lowest leaf."""
_APPLE_GAP_M = 0.003
_FALLEN = (0, 15)
_BESIDE_BALL_SHARE = 0.4
_BESIDE_BALL_M = (0.1, 0.4)
"""Distance from a ball's centre to the centre of an apple lying beside it."""
_BALL_COLOURED_CHANCE = 0.6
_FALLEN_SPREAD_M = 1.0
"""Other fallen apples lie around the trunk, normally distributed with this standard deviation per axis."""
_CLEARANCE_M = 0.005
_TRUNK_CLEARANCE_M = 0.14
"""Fallen apples' centres keep this far from the trunk's axis (trunk radii are at most 9 cm)."""
_PLACEMENT_TRIES = 20


def _color(rng: np.random.Generator, ranges: tuple[tuple[float, float], ...]) -> np.ndarray:
    hue, saturation, value = (np.array([rng.uniform(*r)]) for r in ranges)
    return hsv_to_rgb(hue, saturation, value)[0]


def _apple(rng: np.random.Generator, centre: np.ndarray, radius: float, variety: str) -> Sphere:
    """An apple of ``variety`` (see :data:`VARIETIES`, its label); a two-coloured one's blush faces a random
    side (more often up, where the sun reaches it)."""
    if variety == "bicolour":
        side = rng.normal(size=3) + np.array([0.0, 0.0, 0.5])
        return Sphere(
            centre=centre,
            radius_m=radius,
            color=_color(rng, _YELLOW_GREEN),
            kind=SurfaceKind.FRUIT,
            second_color=_color(rng, _RED),
            second_side=side / np.linalg.norm(side),
            label=variety,
        )
    return Sphere(
        centre=centre,
        radius_m=radius,
        color=_color(rng, _RED if variety == "red" else _YELLOW_GREEN),
        kind=SurfaceKind.FRUIT,
        label=variety,
    )


def _variety(rng: np.random.Generator, main: str) -> str:
    return main if rng.random() < _MAIN_VARIETY_SHARE else str(rng.choice(VARIETIES))


def _clear_of(centre: np.ndarray, radius: float, others: Sequence[Sphere], gap_m: float) -> bool:
    return all(np.linalg.norm(centre - other.centre) >= radius + other.radius_m + gap_m for other in others)


def hanging_apples(rng: np.random.Generator, tree: Tree, main_variety: str) -> tuple[Sphere, ...]:
    """30-150 apples, mostly of ``main_variety``, each hanging just below a leaf of ``tree``'s crown."""
    count = int(rng.integers(_HANGING[0], _HANGING[1] + 1))
    leaf_centres = tree.leaves.vertices[tree.leaves.triangles].mean(axis=1)
    lowest_leaf_z = float(tree.leaves.vertices[:, 2].min())
    candidates = leaf_centres[rng.integers(0, len(leaf_centres), 4 * count)]
    radii = rng.uniform(*APPLE_DIAMETER_M, len(candidates)) / 2
    candidates = candidates + rng.normal(0.0, _HANG_JITTER_M, candidates.shape)
    candidates[:, 2] -= radii + rng.uniform(*_HANG_BELOW_LEAF_M, len(candidates))
    apples: list[Sphere] = []
    for centre, radius in zip(candidates, radii, strict=True):
        if len(apples) == count:
            break
        if centre[2] - radius >= lowest_leaf_z + _ABOVE_LOWEST_LEAF_M and _clear_of(
            centre, radius, apples, _APPLE_GAP_M
        ):
            apples.append(_apple(rng, centre, float(radius), _variety(rng, main_variety)))
    return tuple(apples)


def fallen_apples(
    rng: np.random.Generator,
    ground: Ground,
    balls: Sequence[Sphere],
    main_variety: str,
    *,
    avoid: Sequence[Sphere] = (),
) -> tuple[Sphere, ...]:
    """0-15 apples resting on the ground: some 10-40 cm from one of ``balls`` (red balls get red apples,
    the yellow ball yellow-green ones, more often than not), the others around the trunk. None touches a
    ball, the trunk, another apple or one of ``avoid``."""
    count = int(rng.integers(_FALLEN[0], _FALLEN[1] + 1))
    apples: list[Sphere] = []
    for _ in range(count):
        radius = float(rng.uniform(*APPLE_DIAMETER_M) / 2)
        beside = rng.random() < _BESIDE_BALL_SHARE
        ball_index = int(rng.integers(0, len(balls)))
        variety = _variety(rng, main_variety)
        if beside and rng.random() < _BALL_COLOURED_CHANCE:
            variety = {"red": "red", "yellow": "yellow-green"}.get(list(BALL_COLORS)[ball_index], variety)
        for _ in range(_PLACEMENT_TRIES):
            if beside:
                azimuth = rng.uniform(0.0, 2 * np.pi)
                xy = balls[ball_index].centre[:2] + rng.uniform(*_BESIDE_BALL_M) * np.array(
                    [np.cos(azimuth), np.sin(azimuth)]
                )
            else:
                xy = rng.normal(0.0, _FALLEN_SPREAD_M, 2)
            centre = np.array([xy[0], xy[1], float(ground.height_at(xy[0], xy[1])) + radius])
            if np.hypot(*xy) >= _TRUNK_CLEARANCE_M and _clear_of(
                centre, radius, [*balls, *avoid, *apples], _CLEARANCE_M
            ):
                apples.append(_apple(rng, centre, radius, variety))
                break
    return tuple(apples)
