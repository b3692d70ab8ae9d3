"""The orchard around the measured tree: ground, the neighbouring trees of the row, trellis posts, the balls.

World frame: z up, x along the row, y across it, the main tree's trunk base at the origin on the ground.
The scenario families of :mod:`.scenario` dress this orchard (other ground colours, wires, weeds, fallen
leaves) through :meth:`Orchard.dressed`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import cKDTree

from canopy_core.simulate.ground import Ground, random_ground
from canopy_core.simulate.mesh import Mesh, SurfaceKind, hsv_to_rgb, merge_meshes, tube
from canopy_core.simulate.raycast import Sphere
from canopy_core.simulate.tree import Tree, build_tree, random_tree_shape

__all__ = [
    "BALL_COLORS",
    "BALL_DIAMETER_M",
    "Orchard",
    "build_orchard",
    "post_span_m",
    "resting_balls",
    "trellis_post",
]

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
_POST_HEIGHT_M = (2.1, 2.3)
_NEAR_POST_DISTANCE_M = (0.5, 1.4)
"""With ``near_posts``, how far from the main trunk (along x) a post stands: within the crown's reach, as
in rows whose posts stand between trees planted a metre or two apart, or in the tree line beside one."""
_NEAR_POST_HEIGHT_M = (2.0, 3.8)
"""With ``near_posts`` and no trellis, a post's height: below the crown's top or above it (line posts of a
tall-spindle orchard stand 3-4 m)."""


@dataclass(frozen=True, eq=False)
class Orchard:
    """Everything in the scene but the balls; ``mesh`` holds it all for the renderer, the ground's triangles
    first."""

    ground: Ground
    main_tree: Tree
    neighbours: tuple[Tree, ...]
    post_positions: tuple[tuple[float, float, float], ...]
    mesh: Mesh

    def dressed(
        self,
        *,
        ground_colors: np.ndarray | None = None,
        extras: Sequence[Mesh] = (),
        post_positions: Sequence[tuple[float, float, float]] = (),
    ) -> Orchard:
        """The orchard with its ground repainted in ``ground_colors`` (one RGB row per ground triangle; as it
        is if None), ``extras`` (wires, weeds, fallen leaves, more posts) added to its mesh and the posts at
        ``post_positions`` added to its list."""
        ground, colors = self.ground, self.mesh.colors
        if ground_colors is not None:
            ground_mesh = replace(ground.mesh, colors=np.asarray(ground_colors, dtype=np.float32))
            ground = replace(ground, mesh=ground_mesh)
            colors = np.concatenate([ground_mesh.colors, colors[ground_mesh.triangle_count :]])
        return replace(
            self,
            ground=ground,
            post_positions=(*self.post_positions, *post_positions),
            mesh=merge_meshes([replace(self.mesh, colors=colors), *extras]),
        )


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


def trellis_post(
    rng: np.random.Generator, ground: Ground, x: float, *, height_m: tuple[float, float] = _POST_HEIGHT_M
) -> tuple[Mesh, tuple[float, float, float]]:
    """A wooden trellis post about 10 cm thick standing in the row at ``x``, its height above the ground
    drawn from ``height_m`` (2.1-2.3 m by default), and the ground point at its foot."""
    y = rng.normal(0.0, 0.03)
    ground_z = float(ground.height_at(x, y))
    top_z = ground_z + rng.uniform(*height_m)
    radius = rng.uniform(0.045, 0.055)
    centreline = np.array([[x, y, ground_z - 0.3], [x, y, top_z], [x, y, top_z + 0.005]])
    color = hsv_to_rgb(
        np.array([rng.uniform(25.0, 35.0)]), np.array([rng.uniform(0.2, 0.3)]), np.array([0.5])
    )[0]
    mesh = tube(centreline, np.array([radius, radius, 0.001]), color=color, kind=SurfaceKind.POST)
    return mesh, (x, y, ground_z)


def post_span_m(neighbour: Tree, *, near: bool = False) -> tuple[float, float]:
    """How far from the main trunk (along x) a post may stand on the side of ``neighbour``: beyond the
    crown's reach, or (``near``) within it."""
    low, high = _NEAR_POST_DISTANCE_M if near else (_POST_MIN_DISTANCE_M, 2.4)
    return low, min(high, abs(float(neighbour.base[0])) - 0.8)


def build_orchard(
    rng: np.random.Generator,
    *,
    posts: bool = True,
    near_posts: bool = False,
    slope_deg: float | None = None,
    foot_lean_per_m: tuple[float, float] = (0.0, 0.0),
) -> Orchard:
    """Draw a stretch of orchard row: ground (level, or of ``slope_deg``: see :func:`random_ground`), the
    main tree at the origin, leaning from its foot by ``foot_lean_per_m`` (see ``TreeShape``), a
    neighbour on each side 3-4 m away along x, and (if ``posts``; a trellis with wires brings its own)
    trellis posts between them at least 1.6 m from the main trunk (``near_posts``: one on each side, 0.5-1.4 m
    from it and 2.0-3.8 m tall, within the crown's reach). Posts and neighbours stand upright whatever the
    slope, and so does the main tree unless told to lean. The trees are drawn before the posts: with
    ``near_posts`` the same seed grows the same trees."""
    ground = random_ground(rng, slope_deg=slope_deg)
    shape = replace(random_tree_shape(rng), foot_lean_per_m=foot_lean_per_m)
    main_tree = build_tree(shape, rng, base=np.zeros(3))
    main_points = cKDTree(main_tree.mesh.vertices)
    neighbours = tuple(_neighbour(rng, ground, main_points, side) for side in (-1, 1))
    post_meshes: list[tuple[Mesh, tuple[float, float, float]]] = []
    for side, neighbour in zip((-1, 1), neighbours, strict=True):
        if posts and (rng.random() < _POST_CHANCE or near_posts):
            post_meshes.append(
                trellis_post(
                    rng,
                    ground,
                    side * rng.uniform(*post_span_m(neighbour, near=near_posts)),
                    height_m=_NEAR_POST_HEIGHT_M if near_posts else _POST_HEIGHT_M,
                )
            )
    return Orchard(
        ground=ground,
        main_tree=main_tree,
        neighbours=neighbours,
        post_positions=tuple(position for _, position in post_meshes),
        mesh=merge_meshes(
            [
                ground.mesh,
                main_tree.mesh,
                *(tree.mesh for tree in neighbours),
                *(mesh for mesh, _ in post_meshes),
            ]
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
