"""Orchard floors beyond green grass: straw, red and brown soil, dark mulch, and fallen leaves on them.

Real orchard floors are often the colour of a calibration ball: dry grass and straw are as yellow and as
saturated as the yellow ball, red and brown soils reach the red ball's hue, and autumn leaves are both. A
:class:`GroundPalette` repaints the ground's triangles: a material in the herbicide strip, another on the
sward beside it (blended in smooth patches with a second one), then discs of straw, soil or mulch from 10 cm
to metres across, some of them in the ring around the trunk where the balls lie (0.35-0.8 m from it).
:func:`fallen_leaves` scatters leaf-sized flat triangles on the ground, densest under the crown.

Colours are given as HSV ranges (hue in degrees, saturation and value in [0, 1]); each capture draws its
own shade of a material within the range and every triangle varies around it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from canopy_core.simulate.ground import Ground, smooth_field
from canopy_core.simulate.mesh import Mesh, SurfaceKind, hsv_to_rgb

__all__ = ["MATERIALS", "GroundPalette", "GroundPatch", "Material", "fallen_leaves", "random_palette"]


@dataclass(frozen=True)
class Material:
    """A ground material's colours: ranges of hue (degrees), saturation and value."""

    hue_deg: tuple[float, float]
    saturation: tuple[float, float]
    value: tuple[float, float]


MATERIALS: dict[str, Material] = {
    "green grass": Material(hue_deg=(80.0, 115.0), saturation=(0.35, 0.65), value=(0.28, 0.5)),
    "straw": Material(hue_deg=(40.0, 60.0), saturation=(0.35, 0.75), value=(0.4, 0.8)),
    "red soil": Material(hue_deg=(5.0, 16.0), saturation=(0.4, 0.7), value=(0.3, 0.6)),
    "brown soil": Material(hue_deg=(14.0, 25.0), saturation=(0.35, 0.6), value=(0.22, 0.5)),
    "mulch": Material(hue_deg=(12.0, 35.0), saturation=(0.2, 0.5), value=(0.08, 0.25)),
}
"""The floor materials; straw overlaps the yellow ball's colours, the soils the red ball's."""
_STRIP_MATERIALS = ("straw", "red soil", "brown soil", "mulch")
_SWARD_MATERIALS = ("green grass", "straw")
_PATCH_MATERIALS = ("straw", "red soil", "brown soil", "mulch")
_SHADE_SPREAD = 0.25
"""Each triangle's colour varies within this fraction of its material's ranges around the capture's shade."""
_PATCHES = (4, 16)
_PATCH_RADIUS_M = (0.05, 2.0)
_PATCH_REACH_M = 5.0
"""Patch centres lie within this distance of the trunk (the part of the floor the cameras see well)."""
_BALL_RING_PATCHES = (2, 6)
_BALL_RING_M = (0.25, 0.9)
_BALL_RING_PATCH_RADIUS_M = (0.08, 0.5)
_PATCH_EDGE_JITTER = 0.25
"""Patch edges are ragged: a triangle belongs to a patch within its radius times 1 +- this."""
_STRIP_EDGE_WAVE_M = 0.06

_LEAVES = (1500, 6000)
_LEAF_SPREAD_M = (0.8, 1.8)
"""Fallen leaves lie around the trunk, normally distributed with this standard deviation per axis."""
_LEAF_LENGTH_M = (0.04, 0.08)
_LEAF_HEIGHT_M = (0.003, 0.008)
"""Fallen leaves lie this far above the ground, so that they are not buried in it."""
_LEAF_TILT = 0.15
_LEAF_COLORS = Material(hue_deg=(0.0, 55.0), saturation=(0.4, 0.9), value=(0.25, 0.7))
"""Yellow, orange, red and brown autumn leaves."""


@dataclass(frozen=True)
class GroundPatch:
    """A disc of ``material`` on the floor: centre (x, y) and radius in metres."""

    material: str
    center_m: tuple[float, float]
    radius_m: float


@dataclass(frozen=True)
class GroundPalette:
    """How the floor is painted: the strip's material, the sward's two blended materials, the patches."""

    strip: str
    sward: tuple[str, str]
    patches: tuple[GroundPatch, ...]


def _shade(rng: np.random.Generator, material: Material) -> tuple[np.ndarray, np.ndarray]:
    """This capture's shade of a material (hue, saturation, value) and the spread of its triangles."""
    ranges = np.array([material.hue_deg, material.saturation, material.value])
    centre = rng.uniform(ranges[:, 0], ranges[:, 1])
    return centre, _SHADE_SPREAD * (ranges[:, 1] - ranges[:, 0])


def _paint(rng: np.random.Generator, material: Material, count: int) -> np.ndarray:
    """``count`` RGB colours (count, 3) of one shade of ``material``, each within its ranges."""
    centre, spread = _shade(rng, material)
    ranges = np.array([material.hue_deg, material.saturation, material.value])
    hsv = np.clip(centre + rng.uniform(-spread, spread, size=(count, 3)), ranges[:, 0], ranges[:, 1])
    return hsv_to_rgb(hsv[:, 0], hsv[:, 1], hsv[:, 2])


def _patches(rng: np.random.Generator) -> tuple[GroundPatch, ...]:
    patches = []
    for _ in range(int(rng.integers(_PATCHES[0], _PATCHES[1] + 1))):
        distance = _PATCH_REACH_M * np.sqrt(rng.uniform())
        azimuth = rng.uniform(0.0, 2 * np.pi)
        radius = np.exp(rng.uniform(*np.log(_PATCH_RADIUS_M)))
        patches.append((distance, azimuth, radius))
    for _ in range(int(rng.integers(_BALL_RING_PATCHES[0], _BALL_RING_PATCHES[1] + 1))):
        patches.append(
            (rng.uniform(*_BALL_RING_M), rng.uniform(0.0, 2 * np.pi), rng.uniform(*_BALL_RING_PATCH_RADIUS_M))
        )
    return tuple(
        GroundPatch(
            material=str(rng.choice(_PATCH_MATERIALS)),
            center_m=(float(distance * np.cos(azimuth)), float(distance * np.sin(azimuth))),
            radius_m=float(radius),
        )
        for distance, azimuth, radius in patches
    )


def random_palette(rng: np.random.Generator, ground: Ground) -> tuple[GroundPalette, np.ndarray]:
    """Draw a floor palette and paint ``ground`` with it.

    Returns
    -------
    GroundPalette
        What was drawn.
    numpy.ndarray
        (n, 3) float32 RGB in [0, 1], one row per triangle of ``ground.mesh``.
    """
    palette = GroundPalette(
        strip=str(rng.choice(_STRIP_MATERIALS)),
        sward=(str(rng.choice(_SWARD_MATERIALS)), str(rng.choice(_SWARD_MATERIALS))),
        patches=_patches(rng),
    )
    centroids = ground.mesh.vertices[ground.mesh.triangles].mean(axis=1)
    x, y = centroids[:, 0], centroids[:, 1]
    count = len(centroids)
    edge_m = ground.strip_half_width_m + _STRIP_EDGE_WAVE_M * np.sin(
        2 * np.pi * x / rng.uniform(0.8, 2.5) + rng.uniform(0, 2 * np.pi)
    )
    in_strip = np.abs(y) < edge_m + rng.normal(0.0, 0.03, count)
    second = smooth_field(rng, x, y, offset=(-1.0, 1.0))[:, None]
    sward = (1.0 - second) * _paint(rng, MATERIALS[palette.sward[0]], count) + second * _paint(
        rng, MATERIALS[palette.sward[1]], count
    )
    colors = np.where(in_strip[:, None], _paint(rng, MATERIALS[palette.strip], count), sward)
    for patch in palette.patches:
        distance = np.hypot(x - patch.center_m[0], y - patch.center_m[1])
        ragged = patch.radius_m * (1.0 + rng.uniform(-_PATCH_EDGE_JITTER, _PATCH_EDGE_JITTER, count))
        inside = np.flatnonzero(distance < ragged)
        colors[inside] = _paint(rng, MATERIALS[patch.material], len(inside))
    return palette, colors.astype(np.float32)


def fallen_leaves(rng: np.random.Generator, ground: Ground) -> Mesh:
    """Leaf-sized triangles (4-8 cm) lying almost flat on the ground around the trunk: yellow, orange, red
    and brown."""
    count = int(rng.integers(_LEAVES[0], _LEAVES[1] + 1))
    centres_xy = rng.normal(0.0, rng.uniform(*_LEAF_SPREAD_M), size=(count, 2))
    heights = ground.height_at(centres_xy[:, 0], centres_xy[:, 1]) + rng.uniform(*_LEAF_HEIGHT_M, count)
    centres = np.column_stack([centres_xy, heights])
    normals = np.column_stack([rng.normal(0.0, _LEAF_TILT, size=(count, 2)), np.ones(count)])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    along = np.cross(normals, rng.normal(size=(count, 3)))
    along /= np.linalg.norm(along, axis=1, keepdims=True)
    across = np.cross(normals, along)
    length = rng.uniform(*_LEAF_LENGTH_M, size=(count, 1))
    width = length * rng.uniform(0.45, 0.6, size=(count, 1))
    stalk_end = centres - along * length / 2
    vertices = np.stack(
        [stalk_end + across * width / 2, stalk_end - across * width / 2, centres + along * length / 2], axis=1
    )
    colors = hsv_to_rgb(
        rng.uniform(*_LEAF_COLORS.hue_deg, count),
        rng.uniform(*_LEAF_COLORS.saturation, count),
        rng.uniform(*_LEAF_COLORS.value, count),
    )
    return Mesh(
        vertices=vertices.reshape(-1, 3),
        triangles=np.arange(3 * count, dtype=np.int32).reshape(-1, 3),
        colors=colors,
        kinds=np.full(count, SurfaceKind.GROUND, dtype=np.int8),
    )
