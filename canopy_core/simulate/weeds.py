"""Weeds at the trunk's foot: clumps of tall grass and leafy weeds, and suckers growing from the trunk base.

Clumps stand within 0.6 m of the trunk (where the balls lie, 0.35-0.8 m out, so that a clump sometimes
hides a ball's lower part), 3-15 cm across and 10-60 cm tall, green or dry. A grass clump is a tuft of thin
bent blades; a leafy weed is a few thin stems with leaves along them. Suckers are thin shoots with a few
leaves rising from the trunk's base. Every top stays at least 15 cm below the main tree's lowest leaf, so
that the crown base stays where the tree puts it; weeds are not part of the tree's ground truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from canopy_core.simulate.ground import Ground
from canopy_core.simulate.mesh import Mesh, SurfaceKind, hsv_to_rgb, merge_meshes, tube
from canopy_core.simulate.tree import Tree

__all__ = ["CROWN_CLEARANCE_M", "Sucker", "WeedClump", "Weeds", "grow_weeds"]

CROWN_CLEARANCE_M = 0.15
"""Weeds' and suckers' tops stay this far below the main tree's lowest leaf."""
_CLUMPS = (6, 25)
_CLUMP_REACH_M = 0.6
_CLUMP_RADIUS_M = (0.015, 0.075)
_CLUMP_HEIGHT_M = (0.1, 0.6)
_GRASS_CHANCE = 0.6
_DRY_CHANCE = 0.35
_BLADES = (8, 40)
_BLADE_WIDTH_M = (0.003, 0.008)
_BLADE_LEAN = (0.05, 0.5)
"""A blade's tip leans out by this fraction of its height."""
_BLADE_POINTS = 4
_STEMS = (1, 5)
_STEM_RADIUS_M = (0.0015, 0.003)
_STEM_LEAVES = (3, 8)
_WEED_LEAF_LENGTH_M = (0.03, 0.08)
_GREEN = ((70.0, 115.0), (0.35, 0.7), (0.25, 0.55))
_DRY = ((35.0, 58.0), (0.3, 0.65), (0.4, 0.75))
"""Hue (degrees), saturation and value ranges of green and dry weeds."""
_SUCKERS = (1, 6)
_SUCKER_HEIGHT_M = (0.4, 0.6)
_SUCKER_RADIUS_M = (0.003, 0.005)
_SUCKER_LEAVES = (3, 7)
_SUCKER_LEAN_M = (0.02, 0.12)
"""A sucker's tip stands this far out from its foot."""
_SUCKER_COLOR = ((40.0, 80.0), (0.3, 0.5), (0.3, 0.45))
_TIP_RADIUS_M = 0.0005
_BURIED_M = 0.02
"""Blades, stems and shoots start this far below the ground, so that they meet the uneven ground."""


@dataclass(frozen=True)
class WeedClump:
    """A clump: centre on the ground (metres), radius, tallest top above its ground, grass or leafy, dry."""

    center_m: tuple[float, float, float]
    radius_m: float
    height_m: float
    grass: bool
    dry: bool
    stems: int


@dataclass(frozen=True)
class Sucker:
    """A shoot from the trunk's base: where it starts and its top's height (world z, metres)."""

    base_m: tuple[float, float, float]
    top_z_m: float


@dataclass(frozen=True, eq=False)
class Weeds:
    """The clumps, the suckers and their mesh."""

    clumps: tuple[WeedClump, ...]
    suckers: tuple[Sucker, ...]
    mesh: Mesh


def _hsv(rng: np.random.Generator, ranges: tuple[tuple[float, float], ...], count: int) -> np.ndarray:
    hue, saturation, value = (rng.uniform(low, high, count) for low, high in ranges)
    return hsv_to_rgb(hue, saturation, value)


def _leaves(rng: np.random.Generator, stalks: np.ndarray, colors: np.ndarray) -> Mesh:
    """Leaf triangles hanging from the points ``stalks`` (n, 3), pointing outwards and a little up."""
    count = len(stalks)
    along = rng.normal(size=(count, 3)) + np.array([0.0, 0.0, 0.6])
    along /= np.linalg.norm(along, axis=1, keepdims=True)
    across = np.cross(along, rng.normal(size=(count, 3)))
    across /= np.linalg.norm(across, axis=1, keepdims=True)
    length = rng.uniform(*_WEED_LEAF_LENGTH_M, size=(count, 1))
    width = length * rng.uniform(0.3, 0.6, size=(count, 1))
    vertices = np.stack(
        [stalks + across * width / 2, stalks - across * width / 2, stalks + along * length], 1
    )
    return Mesh(
        vertices=vertices.reshape(-1, 3),
        triangles=np.arange(3 * count, dtype=np.int32).reshape(-1, 3),
        colors=colors.astype(np.float32),
        kinds=np.full(count, SurfaceKind.LEAF, dtype=np.int8),
    )


def _below(mesh: Mesh, top_z: float) -> Mesh:
    """The mesh with every vertex above ``top_z`` lowered to it (the tips of leaves reaching too high)."""
    vertices = mesh.vertices.copy()
    vertices[:, 2] = np.minimum(vertices[:, 2], top_z)
    return Mesh(vertices, mesh.triangles, mesh.colors, mesh.kinds)


def _blades(rng: np.random.Generator, bases: np.ndarray, heights: np.ndarray, color: np.ndarray) -> Mesh:
    """Grass blades: bent strips from ``bases`` (n, 3) up ``heights`` (n,), narrowing to a tip."""
    count = len(bases)
    t = np.linspace(0.0, 1.0, _BLADE_POINTS)
    azimuth = rng.uniform(0.0, 2 * np.pi, count)
    outward = np.column_stack([np.cos(azimuth), np.sin(azimuth), np.zeros(count)])
    sideways = np.column_stack([-np.sin(azimuth), np.cos(azimuth), np.zeros(count)])
    lean = rng.uniform(*_BLADE_LEAN, count) * heights
    spine = (
        bases[:, None, :]
        + (lean[:, None] * t**2)[..., None] * outward[:, None, :]
        + (heights[:, None] * t)[..., None] * np.array([0.0, 0.0, 1.0])
    )
    half_width = (rng.uniform(*_BLADE_WIDTH_M, count)[:, None] * (1.0 - 0.85 * t)) / 2
    edges = np.stack(
        [
            spine - half_width[..., None] * sideways[:, None, :],
            spine + half_width[..., None] * sideways[:, None, :],
        ],
        axis=2,
    )
    index = np.arange(count * _BLADE_POINTS * 2).reshape(count, _BLADE_POINTS, 2)
    left, right = index[:, :-1, 0], index[:, :-1, 1]
    left_up, right_up = index[:, 1:, 0], index[:, 1:, 1]
    triangles = np.concatenate(
        [
            np.stack([left, right, right_up], -1).reshape(-1, 3),
            np.stack([left, right_up, left_up], -1).reshape(-1, 3),
        ]
    ).astype(np.int32)
    shade = rng.uniform(0.85, 1.15, size=(len(triangles), 1))
    return Mesh(
        vertices=edges.reshape(-1, 3),
        triangles=triangles,
        colors=np.clip(color * shade, 0.0, 1.0).astype(np.float32),
        kinds=np.full(len(triangles), SurfaceKind.LEAF, dtype=np.int8),
    )


def _clump(rng: np.random.Generator, ground: Ground, tree: Tree, top_z: float) -> tuple[WeedClump, Mesh]:
    """A clump standing outside the trunk, spread evenly over the area within 0.6 m of it."""
    radius = rng.uniform(*_CLUMP_RADIUS_M)
    nearest_m = tree.shape.trunk_radius_m + radius
    distance = np.sqrt(rng.uniform(nearest_m**2, _CLUMP_REACH_M**2))
    azimuth = rng.uniform(0.0, 2 * np.pi)
    x, y = tree.base[0] + distance * np.cos(azimuth), tree.base[1] + distance * np.sin(azimuth)
    ground_z = float(ground.height_at(x, y))
    height = min(rng.uniform(*_CLUMP_HEIGHT_M), top_z - ground_z)
    grass, dry = bool(rng.random() < _GRASS_CHANCE), bool(rng.random() < _DRY_CHANCE)
    color = _hsv(rng, _DRY if dry else _GREEN, 1)[0]
    low, high = _BLADES if grass else _STEMS
    stems = int(rng.integers(low, high + 1))
    spot = radius * np.sqrt(rng.uniform(size=stems))
    spot_azimuth = rng.uniform(0.0, 2 * np.pi, stems)
    bases_xy = np.column_stack([x + spot * np.cos(spot_azimuth), y + spot * np.sin(spot_azimuth)])
    bases = np.column_stack([bases_xy, ground.height_at(bases_xy[:, 0], bases_xy[:, 1]) - _BURIED_M])
    # The tallest stem reaches the clump's height; the others fall short of it.
    heights = height * np.append(1.0, rng.uniform(0.4, 1.0, stems - 1))
    heights = np.minimum(heights + _BURIED_M, top_z - bases[:, 2])
    if grass:
        mesh = _blades(rng, bases, heights, color)
    else:
        meshes = []
        for base, stem_height in zip(bases, heights, strict=True):
            tip = base + np.array([*rng.normal(0.0, 0.05 * stem_height, 2), stem_height])
            centreline = np.linspace(base, tip, 3)
            meshes.append(
                tube(
                    centreline,
                    np.array([rng.uniform(*_STEM_RADIUS_M)] * 2 + [_TIP_RADIUS_M]),
                    color=color,
                    kind=SurfaceKind.LEAF,
                    sides=3,
                )
            )
            leaf_count = int(rng.integers(_STEM_LEAVES[0], _STEM_LEAVES[1] + 1))
            stalks = base + rng.uniform(0.3, 0.9, (leaf_count, 1)) * (tip - base)
            meshes.append(_leaves(rng, stalks, _hsv(rng, _DRY if dry else _GREEN, leaf_count)))
        mesh = merge_meshes(meshes)
    mesh = _below(mesh, top_z)
    clump_top = float(mesh.vertices[:, 2].max())
    clump = WeedClump(
        center_m=(float(x), float(y), ground_z),
        radius_m=float(radius),
        height_m=clump_top - ground_z,
        grass=grass,
        dry=dry,
        stems=stems,
    )
    return clump, mesh


def _sucker(rng: np.random.Generator, tree: Tree, top_z: float) -> tuple[Sucker, Mesh]:
    azimuth = rng.uniform(0.0, 2 * np.pi)
    outward = np.array([np.cos(azimuth), np.sin(azimuth), 0.0])
    base = tree.base + outward * tree.shape.trunk_radius_m * 0.9 + np.array([0.0, 0.0, -_BURIED_M])
    height = min(rng.uniform(*_SUCKER_HEIGHT_M), top_z - base[2])
    tip = base + outward * rng.uniform(*_SUCKER_LEAN_M) + np.array([*rng.normal(0.0, 0.02, 2), height])
    centreline = base + np.linspace(0.0, 1.0, 4)[:, None] * (tip - base)
    radius = rng.uniform(*_SUCKER_RADIUS_M)
    shoot = tube(
        centreline,
        np.array([radius, radius, 0.7 * radius, _TIP_RADIUS_M]),
        color=_hsv(rng, _SUCKER_COLOR, 1)[0],
        kind=SurfaceKind.BARK,
        sides=4,
    )
    leaf_count = int(rng.integers(_SUCKER_LEAVES[0], _SUCKER_LEAVES[1] + 1))
    stalks = base + rng.uniform(0.4, 0.95, (leaf_count, 1)) * (tip - base)
    leaf_colors = hsv_to_rgb(
        tree.shape.leaf_hue_deg + rng.normal(0.0, 6.0, leaf_count),
        rng.uniform(0.45, 0.75, leaf_count),
        rng.uniform(0.3, 0.6, leaf_count),
    )
    mesh = _below(merge_meshes([shoot, _leaves(rng, stalks, leaf_colors)]), top_z)
    foot = tree.base + outward * tree.shape.trunk_radius_m
    sucker = Sucker(
        base_m=(float(foot[0]), float(foot[1]), float(foot[2])), top_z_m=float(mesh.vertices[:, 2].max())
    )
    return sucker, mesh


def grow_weeds(rng: np.random.Generator, ground: Ground, tree: Tree) -> Weeds:
    """6-25 weed clumps within 0.6 m of ``tree``'s trunk and 1-6 suckers from its base, every top at least
    15 cm below its lowest leaf."""
    top_z = float(tree.leaves.vertices[:, 2].min()) - CROWN_CLEARANCE_M
    clumps = [_clump(rng, ground, tree, top_z) for _ in range(int(rng.integers(_CLUMPS[0], _CLUMPS[1] + 1)))]
    suckers = [_sucker(rng, tree, top_z) for _ in range(int(rng.integers(_SUCKERS[0], _SUCKERS[1] + 1)))]
    return Weeds(
        clumps=tuple(clump for clump, _ in clumps),
        suckers=tuple(sucker for sucker, _ in suckers),
        mesh=merge_meshes([mesh for _, mesh in clumps] + [mesh for _, mesh in suckers]),
    )
