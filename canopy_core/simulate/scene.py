"""The orchard around the measured tree: ground, the neighbouring trees of the row, trellis posts, the balls.

World frame: z up, x along the row, y across it, the main tree's trunk base at the origin on the ground.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from canopy_core.simulate.ground import Ground, random_ground
from canopy_core.simulate.mesh import Mesh, SurfaceKind, hsv_to_rgb, merge_meshes, tube
from canopy_core.simulate.raycast import Sphere
from canopy_core.simulate.tree import Tree, build_tree, random_tree_shape

__all__ = ["BALL_COLORS", "BALL_DIAMETER_M", "Orchard", "build_orchard", "resting_balls"]

BALL_DIAMETER_M = 0.10
BALL_COLORS: dict[str, tuple[int, int, int]] = {
    "red": (200, 35, 35),
    "yellow": (225, 200, 40),
    "blue": (35, 70, 205),
}
"""The balls' RGB reflectances (8-bit), in the order capture.json lists the colours."""

_NEIGHBOUR_DISTANCE_M = (3.0, 4.0)
_MIN_CROWN_GAP_M = 0.3
_GAP_MARGIN_M = 0.05
"""Neighbour triangles are removed within the gap plus this, so that no triangle's inside comes closer."""
_POST_MIN_DISTANCE_M = 1.6
_POST_CHANCE = 0.7


@dataclass(frozen=True, eq=False)
class Orchard:
    """Everything in the scene but the balls; ``mesh`` holds it all for the renderer."""

    ground: Ground
    main_tree: Tree
    neighbours: tuple[Tree, ...]
    post_positions: tuple[tuple[float, float, float], ...]
    mesh: Mesh


def _neighbour(rng: np.random.Generator, ground: Ground, main_points: cKDTree, side: int) -> Tree:
    """A tree of the row on one side (+1: +x), pruned back from the main tree (``main_points``, its
    vertices) where it reaches too close."""
    x = side * rng.uniform(*_NEIGHBOUR_DISTANCE_M)
    y = rng.normal(0.0, 0.05)
    base = np.array([x, y, float(ground.height_at(x, y))])
    tree = build_tree(random_tree_shape(rng), rng, base=base)
    reach_m = _MIN_CROWN_GAP_M + _GAP_MARGIN_M
    return Tree(
        shape=tree.shape,
        base=tree.base,
        wood=tree.wood.without_triangles_near(main_points, reach_m),
        leaves=tree.leaves.without_triangles_near(main_points, reach_m),
    )


def _post(rng: np.random.Generator, ground: Ground, x: float) -> tuple[Mesh, tuple[float, float, float]]:
    """A wooden trellis post about 10 cm thick and 2.2 m tall, standing in the row at ``x``."""
    y = rng.normal(0.0, 0.03)
    ground_z = float(ground.height_at(x, y))
    top_z = ground_z + rng.uniform(2.1, 2.3)
    radius = rng.uniform(0.045, 0.055)
    centreline = np.array([[x, y, ground_z - 0.3], [x, y, top_z], [x, y, top_z + 0.005]])
    color = hsv_to_rgb(
        np.array([rng.uniform(25.0, 35.0)]), np.array([rng.uniform(0.2, 0.3)]), np.array([0.5])
    )[0]
    mesh = tube(centreline, np.array([radius, radius, 0.001]), color=color, kind=SurfaceKind.POST)
    return mesh, (x, y, ground_z)


def build_orchard(rng: np.random.Generator) -> Orchard:
    """Draw a stretch of orchard row: ground, the main tree at the origin, a neighbour on each side
    3-4 m away along x, and trellis posts between them at least 1.6 m from the main trunk."""
    ground = random_ground(rng)
    main_tree = build_tree(random_tree_shape(rng), rng, base=np.zeros(3))
    main_points = cKDTree(main_tree.mesh.vertices)
    neighbours = tuple(_neighbour(rng, ground, main_points, side) for side in (-1, 1))
    posts: list[tuple[Mesh, tuple[float, float, float]]] = []
    for side, neighbour in zip((-1, 1), neighbours, strict=True):
        if rng.random() < _POST_CHANCE:
            farthest_m = min(2.4, abs(float(neighbour.base[0])) - 0.8)
            posts.append(_post(rng, ground, side * rng.uniform(_POST_MIN_DISTANCE_M, farthest_m)))
    return Orchard(
        ground=ground,
        main_tree=main_tree,
        neighbours=neighbours,
        post_positions=tuple(position for _, position in posts),
        mesh=merge_meshes(
            [ground.mesh, main_tree.mesh, *(tree.mesh for tree in neighbours), *(mesh for mesh, _ in posts)]
        ),
    )


def resting_balls(ground: Ground, positions_xy: np.ndarray) -> tuple[Sphere, ...]:
    """The calibration balls, one per colour of :data:`BALL_COLORS` in order, resting on the ground at
    ``positions_xy`` (3, 2): centre at the ground's height there plus the radius."""
    radius = BALL_DIAMETER_M / 2
    heights = ground.height_at(positions_xy[:, 0], positions_xy[:, 1])
    return tuple(
        Sphere(
            centre=np.array([x, y, z + radius]),
            radius_m=radius,
            color=np.asarray(rgb, dtype=np.float32) / 255.0,
        )
        for (x, y), z, rgb in zip(positions_xy, heights, BALL_COLORS.values(), strict=True)
    )
