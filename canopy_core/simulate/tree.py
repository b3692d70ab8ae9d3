"""Procedural apple trees (trunk, scaffold branches, single-triangle leaves) and their exact dimensions.

A tree grows from a :class:`TreeShape`: a crown envelope of one of three forms (spindle, ellipsoid, open
vase) stretched along and across the row, with a lobed outline, a slight lean, and leaves in clusters so
that the crown is partly see-through. :func:`tree_dimensions` gives the ground truth from the mesh itself
(and the apples hanging in it, if any), with the definitions the measurement uses (H, W, D of Yang, Wang &
Sun 2019, eqs. 5, 6 and 7-8).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum
from functools import cached_property

import numpy as np
from scipy.spatial import ConvexHull
from scipy.spatial.distance import pdist

from canopy_core.simulate.mesh import Mesh, SurfaceKind, hsv_to_rgb, merge_meshes, tube
from canopy_core.simulate.raycast import Sphere

__all__ = [
    "CrownForm",
    "Tree",
    "TreeDimensions",
    "TreeShape",
    "build_tree",
    "random_lean",
    "random_tree_shape",
    "tree_dimensions",
]

_TRUNK_DEPTH_M = 0.12
"""The trunk starts this far below its base so that it meets the uneven ground without a gap."""
_MIN_LEAVES, _MAX_LEAVES = 5000, 30000
_PROFILE_SAMPLES = np.linspace(0.0, 1.0, 201)
_AZIMUTH_SAMPLES = np.linspace(0.0, 2 * np.pi, 361)
_GOLDEN_ANGLE_RAD = np.pi * (3.0 - np.sqrt(5.0))
"""Successive laterals this far apart in azimuth spread evenly round the leader, as phyllotaxis does."""


class CrownForm(StrEnum):
    """The training form of the crown."""

    SPINDLE = "spindle"
    ELLIPSOID = "ellipsoid"
    VASE = "vase"


@dataclass(frozen=True)
class _FormRanges:
    top_m: tuple[float, float]
    crown_base_m: tuple[float, float]
    width_m: tuple[float, float]
    branches: tuple[int, int]


# Tall trees are spindles and wide ones open vases, as in orchards; together the forms span heights of
# 1.8-4.0 m and widths of 1.0-2.6 m.
_RANGES = {
    CrownForm.SPINDLE: _FormRanges(
        top_m=(2.4, 3.95), crown_base_m=(0.45, 0.9), width_m=(1.2, 1.95), branches=(8, 14)
    ),
    CrownForm.ELLIPSOID: _FormRanges(
        top_m=(2.0, 3.5), crown_base_m=(0.55, 1.25), width_m=(1.4, 2.45), branches=(4, 7)
    ),
    CrownForm.VASE: _FormRanges(
        top_m=(1.95, 3.0), crown_base_m=(0.6, 1.2), width_m=(1.7, 2.6), branches=(3, 5)
    ),
}


@dataclass(frozen=True)
class TreeShape:
    """The parameters a tree is grown from; lengths in metres, relative to the trunk base.

    The crown envelope spans ``crown_base_m`` to ``top_m`` in height; its horizontal section is an ellipse
    of semi-axes ``radius_along_row_m`` (x) and ``radius_across_row_m`` (y) times the form's profile,
    modulated by two lobes and shifted by the lean, which grows linearly to ``lean_m`` at the top. A tree
    that leans from its foot (``foot_lean_per_m``: its trunk and crown shift this far horizontally per
    metre of height) carries the whole of it over with the height.
    """

    form: CrownForm
    top_m: float
    crown_base_m: float
    radius_along_row_m: float
    radius_across_row_m: float
    trunk_radius_m: float
    lean_m: tuple[float, float]
    lobe_amplitudes: tuple[float, float]
    lobe_phases: tuple[float, float]
    leaf_density_per_m3: float
    leaves_per_cluster: float
    cluster_spread_m: float
    leaf_hue_deg: float
    branch_count: int
    foot_lean_per_m: tuple[float, float] = (0.0, 0.0)

    @property
    def crown_height_m(self) -> float:
        """Height of the crown envelope."""
        return self.top_m - self.crown_base_m

    @property
    def top_offset_m(self) -> tuple[float, float]:
        """How far the tree's axis at its top stands off its foot, horizontally: both leans together."""
        return (
            self.lean_m[0] + self.foot_lean_per_m[0] * self.top_m,
            self.lean_m[1] + self.foot_lean_per_m[1] * self.top_m,
        )


@dataclass(frozen=True, eq=False)
class Tree:
    """A grown tree: its trunk base (3,) on the ground, its wood and its leaves, in world coordinates."""

    shape: TreeShape
    base: np.ndarray
    wood: Mesh
    leaves: Mesh

    @cached_property
    def mesh(self) -> Mesh:
        """Wood and leaves in one mesh."""
        return merge_meshes([self.wood, self.leaves])


@dataclass(frozen=True)
class TreeDimensions:
    """A tree's ground-truth dimensions in metres, measured on its mesh with the ground at z = ``ground_z``.

    ``height_m`` is the highest point above the ground (eq. 5), ``width_m`` the largest distance between two
    points of the tree projected on the horizontal plane (eq. 6), ``thickness_m`` the top minus the lowest
    leaf point (D, eqs. 7-8 with the true crown base), and ``crown_base_m`` the lowest leaf point above the
    ground. Apples hanging in the crown are part of the tree (the simulation never hangs one below the
    lowest leaf, so the crown base stays the lowest leaf).
    """

    height_m: float
    width_m: float
    thickness_m: float
    crown_base_m: float


def random_tree_shape(rng: np.random.Generator) -> TreeShape:
    """Draw the shape of an apple tree: its form, size, proportions and foliage."""
    form = CrownForm(rng.choice([f.value for f in CrownForm]))
    ranges = _RANGES[form]
    top_m = rng.uniform(*ranges.top_m)
    crown_base_m = min(rng.uniform(*ranges.crown_base_m), top_m - 1.0)
    half_width_m = rng.uniform(*ranges.width_m) / 2.0
    # Above 1 the crown is longer along the row than across it, below 1 the other way round.
    elongation = rng.uniform(1.15, 1.5) if rng.random() < 0.4 else rng.uniform(0.9, 1.1)
    return TreeShape(
        form=form,
        top_m=top_m,
        crown_base_m=crown_base_m,
        radius_along_row_m=half_width_m * min(1.0, elongation),
        radius_across_row_m=half_width_m / max(1.0, elongation),
        trunk_radius_m=rng.uniform(0.04, 0.09),
        lean_m=(rng.uniform(-0.08, 0.08), rng.uniform(-0.08, 0.08)),
        lobe_amplitudes=(rng.uniform(0.0, 0.18), rng.uniform(0.0, 0.12)),
        lobe_phases=(rng.uniform(0.0, 2 * np.pi), rng.uniform(0.0, 2 * np.pi)),
        leaf_density_per_m3=rng.uniform(6000.0, 10000.0),
        leaves_per_cluster=rng.uniform(10.0, 30.0),
        cluster_spread_m=rng.uniform(0.06, 0.12),
        leaf_hue_deg=rng.uniform(88.0, 112.0),
        branch_count=int(rng.integers(ranges.branches[0], ranges.branches[1] + 1)),
    )


def random_lean(rng: np.random.Generator, *, lean_deg: float) -> tuple[float, float]:
    """A lean of ``lean_deg`` from vertical in a random direction, as :attr:`TreeShape.foot_lean_per_m`
    (the horizontal shift per metre of height)."""
    azimuth = rng.uniform(0.0, 2 * np.pi)
    shift = float(np.tan(np.radians(lean_deg)))
    return shift * float(np.cos(azimuth)), shift * float(np.sin(azimuth))


def _raw_profile(form: CrownForm, t: np.ndarray) -> np.ndarray:
    if form is CrownForm.SPINDLE:
        return (1.0 - t) ** 0.85 * np.minimum(1.0, 0.6 + 2.0 * t)
    if form is CrownForm.ELLIPSOID:
        return np.sqrt(np.clip(1.0 - (2.0 * t - 1.0) ** 2, 0.0, None))
    return np.sqrt(np.clip(1.0 - ((t - 0.7) / 0.75) ** 2, 0.0, None))


def _crown_profile(form: CrownForm, t: np.ndarray) -> np.ndarray:
    """The crown's relative radius (max 1) at relative height ``t`` (0 at the crown base, 1 at the top)."""
    return _raw_profile(form, np.clip(t, 0.0, 1.0)) / _raw_profile(form, _PROFILE_SAMPLES).max()


def _hollow(form: CrownForm, t: np.ndarray) -> np.ndarray:
    """Relative radius of the leafless centre: an open vase has none below its top."""
    if form is CrownForm.VASE:
        return 0.55 * np.clip((1.0 - t) / 0.25, 0.0, 1.0)
    return np.zeros_like(t)


def _raw_lobes(shape: TreeShape, azimuth: np.ndarray) -> np.ndarray:
    (a2, a3), (p2, p3) = shape.lobe_amplitudes, shape.lobe_phases
    return 1.0 + a2 * np.cos(2 * azimuth + p2) + a3 * np.cos(3 * azimuth + p3)


def _lobes(shape: TreeShape, azimuth: np.ndarray) -> np.ndarray:
    """The outline's relative radius (max 1) in direction ``azimuth``."""
    return _raw_lobes(shape, azimuth) / _raw_lobes(shape, _AZIMUTH_SAMPLES).max()


def _crown_axis_xy(shape: TreeShape, t: np.ndarray) -> np.ndarray:
    """The tree's axis at relative height ``t`` (of the crown; below 0 the trunk): the crown's lean, and the
    whole tree's from its foot."""
    height_m = shape.crown_base_m + np.asarray(t) * shape.crown_height_m
    return np.clip(t, 0.0, 1.0)[..., None] * np.asarray(shape.lean_m) + height_m[..., None] * np.asarray(
        shape.foot_lean_per_m
    )


def _crown_coordinates(shape: TreeShape, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Relative height t, relative radius and azimuth of points (relative to the trunk base)."""
    t = (points[:, 2] - shape.crown_base_m) / shape.crown_height_m
    offset = points[:, :2] - _crown_axis_xy(shape, t)
    scaled_x = offset[:, 0] / shape.radius_along_row_m
    scaled_y = offset[:, 1] / shape.radius_across_row_m
    return t, np.hypot(scaled_x, scaled_y), np.arctan2(scaled_y, scaled_x)


def _inside_crown(shape: TreeShape, points: np.ndarray) -> np.ndarray:
    t, radius, azimuth = _crown_coordinates(shape, points)
    outer = _crown_profile(shape.form, t) * _lobes(shape, azimuth)
    return (t >= 0.0) & (t <= 1.0) & (radius <= outer) & (radius >= _hollow(shape.form, t) * outer)


def _crown_point(shape: TreeShape, t: np.ndarray, fraction: np.ndarray, azimuth: np.ndarray) -> np.ndarray:
    """Points at relative height t, at ``fraction`` of the envelope's radius in direction ``azimuth``."""
    radius = fraction * _crown_profile(shape.form, t) * _lobes(shape, azimuth)
    xy = _crown_axis_xy(shape, t) + np.stack(
        [
            radius * np.cos(azimuth) * shape.radius_along_row_m,
            radius * np.sin(azimuth) * shape.radius_across_row_m,
        ],
        axis=-1,
    )
    return np.column_stack([xy, shape.crown_base_m + t * shape.crown_height_m])


def _crown_box(shape: TreeShape) -> tuple[np.ndarray, np.ndarray]:
    reach = (
        np.array([shape.radius_along_row_m, shape.radius_across_row_m])
        + np.abs(shape.lean_m)
        + np.abs(shape.foot_lean_per_m) * shape.top_m
    )
    return (
        np.array([-reach[0], -reach[1], shape.crown_base_m]),
        np.array([reach[0], reach[1], shape.top_m]),
    )


def _sample_in_crown(shape: TreeShape, rng: np.random.Generator, count: int) -> np.ndarray:
    low, high = _crown_box(shape)
    found: list[np.ndarray] = []
    total = 0
    while total < count:
        candidates = rng.uniform(low, high, size=(4 * count, 3))
        inside = candidates[_inside_crown(shape, candidates)]
        found.append(inside)
        total += len(inside)
    return np.concatenate(found)[:count]


def _crown_volume_m3(shape: TreeShape, rng: np.random.Generator) -> float:
    low, high = _crown_box(shape)
    probe = rng.uniform(low, high, size=(20000, 3))
    return float(np.prod(high - low) * _inside_crown(shape, probe).mean())


def _leaf_centres(shape: TreeShape, rng: np.random.Generator) -> np.ndarray:
    """Leaf centres in clusters (shoots) inside the crown; the spaces between clusters are the gaps."""
    leaf_count = int(
        np.clip(shape.leaf_density_per_m3 * _crown_volume_m3(shape, rng), _MIN_LEAVES, _MAX_LEAVES)
    )
    found: list[np.ndarray] = []
    total = 0
    while total < leaf_count:
        clusters = _sample_in_crown(shape, rng, max(8, int(leaf_count / shape.leaves_per_cluster)))
        per_cluster = rng.poisson(shape.leaves_per_cluster * 1.5, size=len(clusters))
        centres = np.repeat(clusters, per_cluster, axis=0)
        centres += rng.normal(0.0, shape.cluster_spread_m, size=centres.shape)
        centres = centres[_inside_crown(shape, centres)]
        found.append(centres)
        total += len(centres)
    centres = np.concatenate(found)
    return centres[rng.permutation(len(centres))[:leaf_count]]


def _leaves(shape: TreeShape, rng: np.random.Generator) -> Mesh:
    centres = _leaf_centres(shape, rng)
    count = len(centres)
    normals = rng.normal(size=(count, 3)) + np.array([0.0, 0.0, 0.7])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    along = np.cross(normals, rng.normal(size=(count, 3)))
    along /= np.linalg.norm(along, axis=1, keepdims=True)
    across = np.cross(normals, along)
    length = rng.uniform(0.04, 0.08, size=(count, 1))
    width = length * rng.uniform(0.45, 0.6, size=(count, 1))
    stalk_end = centres - along * length / 2
    vertices = np.stack(
        [stalk_end + across * width / 2, stalk_end - across * width / 2, centres + along * length / 2], axis=1
    )
    colors = hsv_to_rgb(
        shape.leaf_hue_deg + rng.normal(0.0, 6.0, count),
        rng.uniform(0.45, 0.75, count),
        rng.uniform(0.28, 0.58, count),
    )
    return Mesh(
        vertices=vertices.reshape(-1, 3),
        triangles=np.arange(3 * count, dtype=np.int32).reshape(-1, 3),
        colors=colors,
        kinds=np.full(count, SurfaceKind.LEAF, dtype=np.int8),
    )


def _bark_color(rng: np.random.Generator) -> np.ndarray:
    return hsv_to_rgb(
        np.array([rng.uniform(20.0, 32.0)]), np.array([rng.uniform(0.25, 0.4)]), np.array([0.33])
    )[0]


def _trunk(shape: TreeShape, rng: np.random.Generator, color: np.ndarray) -> tuple[Mesh, float]:
    """The trunk (and central leader) and the height it ends at."""
    crown_h = shape.crown_height_m
    end_z = {
        CrownForm.SPINDLE: shape.top_m,
        CrownForm.ELLIPSOID: shape.crown_base_m + 0.8 * crown_h,
        CrownForm.VASE: shape.crown_base_m + 0.1,
    }[shape.form]
    heights = np.concatenate([[-_TRUNK_DEPTH_M, 0.0], np.linspace(0.0, end_z, 6)[1:]])
    t = (heights - shape.crown_base_m) / crown_h
    wander = np.concatenate([[[0.0, 0.0], [0.0, 0.0]], rng.normal(0.0, 0.012, size=(len(heights) - 2, 2))])
    centreline = np.column_stack([_crown_axis_xy(shape, t) + wander, heights])
    taper = np.clip(1.0 - 0.8 * np.clip(heights, 0.0, None) / end_z, 0.2, 1.0)
    radii = shape.trunk_radius_m * taper
    radii[-1] = 0.004
    return tube(centreline, radii, color=color, kind=SurfaceKind.BARK), end_z


def _branch_geometry(
    shape: TreeShape, rng: np.random.Generator, trunk_end_z: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Start heights, tip relative heights, tip radial fractions and azimuths of the scaffold branches."""
    n = shape.branch_count
    base, crown_h = shape.crown_base_m, shape.crown_height_m
    step = 2 * np.pi / n if shape.form is CrownForm.VASE else _GOLDEN_ANGLE_RAD
    azimuth = rng.uniform(0.0, 2 * np.pi) + step * np.arange(n) + rng.normal(0.0, 0.2, n)
    if shape.form is CrownForm.SPINDLE:
        start_z = np.sort(rng.uniform(base + 0.02, base + 0.75 * crown_h, n))
        tip_z = np.minimum(start_z + rng.uniform(0.05, 0.3, n), shape.top_m - 0.1)
        fraction = rng.uniform(0.6, 0.9, n)
    elif shape.form is CrownForm.ELLIPSOID:
        start_z = rng.uniform(base - 0.05, base + 0.35 * crown_h, n)
        tip_z = np.minimum(start_z + rng.uniform(0.2, 0.6, n) * crown_h, shape.top_m - 0.15 * crown_h)
        fraction = rng.uniform(0.5, 0.85, n)
    else:
        start_z = trunk_end_z - rng.uniform(0.0, 0.15, n)
        tip_z = base + rng.uniform(0.45, 0.8, n) * crown_h
        fraction = rng.uniform(0.6, 0.85, n)
    return np.clip(start_z, 0.2, trunk_end_z), (tip_z - base) / crown_h, fraction, azimuth


def _branches(
    shape: TreeShape, rng: np.random.Generator, trunk_end_z: float, color: np.ndarray
) -> list[Mesh]:
    start_z, tip_t, fraction, azimuth = _branch_geometry(shape, rng, trunk_end_z)
    starts = np.column_stack(
        [_crown_axis_xy(shape, (start_z - shape.crown_base_m) / shape.crown_height_m), start_z]
    )
    tips = _crown_point(shape, tip_t, fraction, azimuth)
    start_radius = np.minimum(0.5 * shape.trunk_radius_m * (1.0 - 0.6 * start_z / shape.top_m), 0.035)
    meshes = []
    for start, tip, radius in zip(starts, tips, start_radius, strict=True):
        middle = (start + tip) / 2 + np.array([0.0, 0.0, rng.uniform(-0.05, 0.1)])
        centreline = np.stack([start, middle, tip])
        meshes.append(
            tube(
                centreline,
                np.array([radius, 0.6 * radius, 0.006]),
                color=color,
                kind=SurfaceKind.BARK,
                sides=6,
            )
        )
    return meshes


def build_tree(shape: TreeShape, rng: np.random.Generator, *, base: np.ndarray) -> Tree:
    """Grow a tree of ``shape`` whose trunk stands at ``base`` (the ground point at the trunk's centre)."""
    color = _bark_color(rng)
    trunk, trunk_end_z = _trunk(shape, rng, color)
    wood = merge_meshes([trunk, *_branches(shape, rng, trunk_end_z, color)])
    leaves = _leaves(shape, rng)
    offset = np.asarray(base, dtype=float)
    return Tree(shape=shape, base=offset, wood=wood.translated(offset), leaves=leaves.translated(offset))


def tree_dimensions(tree: Tree, *, ground_z: float = 0.0, fruit: Sequence[Sphere] = ()) -> TreeDimensions:
    """The exact H, W, D and crown base of a tree's mesh and the apples hanging in it (see
    :class:`TreeDimensions`; the fruit counts as crown, as leaves do).

    The width is the largest distance between two points of the vertices and the apples projected on the
    xy plane: between two vertices it is reached on the vertices' convex hull, and the farthest points of
    two discs of centres distance d apart and radii r, s are d + r + s apart.
    """
    vertices = tree.mesh.vertices
    centres = np.array([apple.centre for apple in fruit]).reshape(-1, 3)
    radii = np.array([apple.radius_m for apple in fruit])
    top_z = max(float(vertices[:, 2].max()), float((centres[:, 2] + radii).max(initial=-np.inf)))
    lowest_crown_z = min(
        float(tree.leaves.vertices[:, 2].min()), float((centres[:, 2] - radii).min(initial=np.inf))
    )
    plan = vertices[:, :2]
    hull_points = plan[ConvexHull(plan).vertices]
    width_m = float(pdist(hull_points).max())
    if len(fruit):
        points = np.concatenate([hull_points, centres[:, :2]])
        reach = np.concatenate([np.zeros(len(hull_points)), radii])
        apart = np.linalg.norm(points[:, None, :] - points[None, len(hull_points) :, :], axis=-1)
        width_m = max(width_m, float((apart + reach[:, None] + radii[None, :]).max()))
    return TreeDimensions(
        height_m=top_z - ground_z,
        width_m=width_m,
        thickness_m=top_z - lowest_crown_z,
        crown_base_m=lowest_crown_z - ground_z,
    )
