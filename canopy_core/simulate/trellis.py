"""A trellis: horizontal steel wires along the row through the trees, held by posts.

Wires run along x through the trunk line (y within 5 cm of 0), so through the measured tree's crown, from
0.4 m above the ground to the crown's top, sometimes with one 0.1-0.8 m above the top (the support wire of
tall spindles). They are 2.5-5 mm thick: a Kinect v2 depth pixel covers about 8 mm at 3 m, so a wire fills
part of a pixel and shows up only through the mixed pixels the sensor model makes of its 3x3 rays. Each
wire sags between its supports as a parabola (a catenary this shallow), 0.2-0.8 % of the span. Posts stand
at both ends of the stretch of row the scene holds (7-12 m out) and, more often than in a plain scene,
between the main tree and its neighbours; they are tall enough for the top wire.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from canopy_core.simulate.ground import Ground
from canopy_core.simulate.mesh import Mesh, SurfaceKind, hsv_to_rgb, merge_meshes, tube
from canopy_core.simulate.scene import Orchard, post_span_m, trellis_post

__all__ = ["Trellis", "Wire", "build_trellis", "wire_height_m"]

_WIRES = (2, 5)
_WIRE_DIAMETER_M = (0.0025, 0.005)
_LOWEST_WIRE_M = 0.4
_WIRE_SPACING_M = 0.2
_ABOVE_CROWN_CHANCE = 0.4
_ABOVE_CROWN_M = (0.1, 0.8)
_WIRE_Y_M = 0.05
_SAG_PER_SPAN = (0.002, 0.008)
_WIRE_STEP_M = 0.2
"""Wires are tubes with a ring every this many metres, enough to follow their sag."""
_WIRE_SIDES = 4
_END_POST_X_M = (7.0, 12.0)
_LINE_POST_CHANCE = 0.95
_POST_ABOVE_WIRE_M = (0.05, 0.2)
_WIRE_SATURATION = (0.0, 0.08)
_WIRE_VALUE = (0.45, 0.75)
"""Galvanised steel: grey, from dull to bright."""


@dataclass(frozen=True)
class Wire:
    """One wire: its height (world z, metres) at its supports on level ground, which stand at
    ``supports_x_m`` along the row, its diameter and y position; between two supports it hangs
    ``sag_per_span`` times the span lower at mid-span, as a parabola (see :func:`wire_height_m`). On a
    hillside its supports climb ``rise_per_m`` metres per metre along the row, ``height_m`` being its
    height at x = 0: the wire runs parallel to the ground from post to post, as a real trellis's does."""

    height_m: float
    diameter_m: float
    y_m: float
    sag_per_span: float
    supports_x_m: tuple[float, ...]
    rise_per_m: float = 0.0


@dataclass(frozen=True, eq=False)
class Trellis:
    """The wires, the posts (ground points at their feet) and the mesh of both."""

    wires: tuple[Wire, ...]
    post_positions: tuple[tuple[float, float, float], ...]
    mesh: Mesh


def _heights(rng: np.random.Generator, count: int, crown_top_z: float) -> np.ndarray:
    """Wire heights, at least 20 cm apart, from 0.4 m to the crown top or, sometimes, above it."""
    while True:
        heights = np.sort(rng.uniform(_LOWEST_WIRE_M, crown_top_z, count))
        if rng.random() < _ABOVE_CROWN_CHANCE:
            heights[-1] = crown_top_z + rng.uniform(*_ABOVE_CROWN_M)
        if np.diff(heights).min(initial=np.inf) >= _WIRE_SPACING_M:
            return heights


def wire_height_m(wire: Wire, x: np.ndarray) -> np.ndarray:
    """The height (world z) of the axis of ``wire`` at positions ``x`` along the row, between its ends."""
    supports = np.asarray(wire.supports_x_m)
    span = np.clip(np.searchsorted(supports, x, side="right") - 1, 0, len(supports) - 2)
    left, right = supports[span], supports[span + 1]
    sag = wire.sag_per_span * 4.0 * (x - left) * (right - x) / (right - left)
    return wire.height_m + wire.rise_per_m * x - sag


def build_trellis(rng: np.random.Generator, orchard: Orchard, *, near_posts: bool = False) -> Trellis:
    """Draw 2-5 wires along the row through ``orchard``'s main tree, with their posts (``near_posts``: a
    line post on each side within the crown's reach, as
    :func:`~canopy_core.simulate.scene.build_orchard` stands them)."""
    ground: Ground = orchard.ground
    crown_top_z = float(orchard.main_tree.mesh.vertices[:, 2].max())
    heights = _heights(rng, int(rng.integers(_WIRES[0], _WIRES[1] + 1)), crown_top_z)
    post_height = (heights[-1] + _POST_ABOVE_WIRE_M[0], heights[-1] + _POST_ABOVE_WIRE_M[1])
    posts_x = [side * rng.uniform(*_END_POST_X_M) for side in (-1, 1)]
    for side, neighbour in zip((-1, 1), orchard.neighbours, strict=True):
        if rng.random() < _LINE_POST_CHANCE or near_posts:
            posts_x.append(side * rng.uniform(*post_span_m(neighbour, near=near_posts)))
    posts = [trellis_post(rng, ground, float(x), height_m=post_height) for x in posts_x]
    supports_x = np.sort(np.array(posts_x))
    x = np.linspace(supports_x[0], supports_x[-1], int(np.ptp(supports_x) / _WIRE_STEP_M) + 1)
    x = np.unique(np.concatenate([x, supports_x]))
    y = rng.uniform(-_WIRE_Y_M, _WIRE_Y_M)
    color = hsv_to_rgb(
        np.array([rng.uniform(190.0, 230.0)]),
        np.array([rng.uniform(*_WIRE_SATURATION)]),
        np.array([rng.uniform(*_WIRE_VALUE)]),
    )[0]
    wires: list[Wire] = []
    meshes: list[Mesh] = []
    along_row, across_row = ground.hillside_gradient
    for height in heights:
        diameter = float(rng.uniform(*_WIRE_DIAMETER_M))
        wire_y = float(y + rng.normal(0.0, 0.005))
        wire = Wire(
            height_m=float(height + across_row * wire_y),
            diameter_m=diameter,
            y_m=wire_y,
            sag_per_span=float(rng.uniform(*_SAG_PER_SPAN)),
            supports_x_m=tuple(float(v) for v in supports_x),
            rise_per_m=along_row,
        )
        centreline = np.column_stack([x, np.full_like(x, wire.y_m), wire_height_m(wire, x)])
        meshes.append(
            tube(
                centreline,
                np.full(len(x), wire.diameter_m / 2),
                color=color,
                kind=SurfaceKind.WIRE,
                sides=_WIRE_SIDES,
            )
        )
        wires.append(wire)
    return Trellis(
        wires=tuple(wires),
        post_positions=tuple(position for _, position in posts),
        mesh=merge_meshes([*meshes, *(mesh for mesh, _ in posts)]),
    )
