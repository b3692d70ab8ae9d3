"""A support stake beside the main trunk, as most young high-density (tall-spindle) apple trees have: a
galvanised conduit or a bamboo cane about 2 cm thick, touching the trunk's bark or a few centimetres off it,
its foot in the ground and its top anywhere from half a metre inside the crown to half a metre above it
(the tree not yet grown to it). It is not part of the tree: the ground truth's dimensions leave it out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from canopy_core.simulate.mesh import Mesh, SurfaceKind, hsv_to_rgb, tube

__all__ = ["Stake", "random_stake"]

_RADIUS_M = (0.008, 0.012)
_GAP_M = (0.0, 0.03)
"""From the trunk's bark at its foot to the stake's surface: the trunk is tied to it."""
_TOP_ABOVE_CROWN_M = (-0.5, 0.5)
_BURIED_M = 0.3


@dataclass(frozen=True, eq=False)
class Stake:
    """The stake's axis position (world x, y), its top (world z), its radius and its mesh."""

    xy_m: tuple[float, float]
    top_m: float
    radius_m: float
    mesh: Mesh


def random_stake(
    rng: np.random.Generator, *, crown_top_z_m: float, trunk_radius_m: float, lean_xy_m: tuple[float, float]
) -> Stake:
    """Draw a stake beside the main trunk (its foot at the origin, ``trunk_radius_m`` thick there, its top
    leaning by ``lean_xy_m``), its top within ``_TOP_ABOVE_CROWN_M`` of ``crown_top_z_m``; grey conduit or
    tan cane.

    The stake stands on the side the trunk leans away from (within a quarter turn of it), so that the lean
    carries the trunk off it; the trunk's axis also wanders (1.2 cm a node), which in about one tree in
    twenty still grazes the stake low down, by up to 2 cm."""
    away = np.arctan2(-lean_xy_m[1], -lean_xy_m[0])
    azimuth = away + rng.uniform(-0.5 * np.pi, 0.5 * np.pi)
    radius = rng.uniform(*_RADIUS_M)
    distance = trunk_radius_m + radius + rng.uniform(*_GAP_M)
    x, y = distance * np.cos(azimuth), distance * np.sin(azimuth)
    top = crown_top_z_m + rng.uniform(*_TOP_ABOVE_CROWN_M)
    color = hsv_to_rgb(
        np.array([rng.uniform(25.0, 45.0)]),
        np.array([rng.uniform(0.05, 0.4)]),
        np.array([rng.uniform(0.4, 0.7)]),
    )[0]
    centreline = np.array([[x, y, -_BURIED_M], [x, y, top], [x, y, top + 0.003]])
    mesh = tube(centreline, np.array([radius, radius, 0.001]), color=color, kind=SurfaceKind.POST)
    return Stake(xy_m=(float(x), float(y)), top_m=float(top), radius_m=float(radius), mesh=mesh)
