"""The orchard floor: an uneven heightfield with a bare herbicide strip along the row and grass beside it.

The field is a regular 10 cm grid within 5.5 m of the trunk (where cameras stand and depth is read)
surrounded by cells growing to 40 m, so that the colour camera sees ground up to the horizon. Heights are a
gentle undulation (metres of wavelength, a few centimetres high) plus bumps of +-2-4 cm, with a tilt of at
most 0.5 degrees (or a hillside's slope, when one is asked for), shifted so that the ground is exactly z = 0
at the trunk base (the origin).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter

from canopy_core.simulate.mesh import Mesh, SurfaceKind, hsv_to_rgb

__all__ = ["Ground", "random_ground", "smooth_field"]

_CELL_M = 0.1
_INNER_CELLS = 55
"""The fine grid spans +-5.5 m."""
_OUTER_GROWTH = 1.45
_OUTER_EXTENT_M = 40.0
_BUMP_FADE_M = 0.5


@dataclass(frozen=True, eq=False)
class Ground:
    """The ground's heightfield on the grid ``xs`` x ``ys`` (``heights_m[j, i]`` at ``(xs[i], ys[j])``) and
    its mesh, which splits each grid cell into two triangles along its (i, j)-(i+1, j+1) diagonal."""

    xs: np.ndarray
    ys: np.ndarray
    heights_m: np.ndarray
    strip_half_width_m: float
    tilt_deg: float
    mesh: Mesh
    hillside_gradient: tuple[float, float] = (0.0, 0.0)
    """A hillside's rise in metres per metre along x and y, which a trellis's wires climb with from post to
    post; zero on nearly level ground, whose slight tilt they ignore (strung level)."""

    def height_at(self, x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
        """Exact height of the triangulated ground surface at horizontal positions ``(x, y)``."""
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        i = np.clip(np.searchsorted(self.xs, x, side="right") - 1, 0, len(self.xs) - 2)
        j = np.clip(np.searchsorted(self.ys, y, side="right") - 1, 0, len(self.ys) - 2)
        fx = (x - self.xs[i]) / (self.xs[i + 1] - self.xs[i])
        fy = (y - self.ys[j]) / (self.ys[j + 1] - self.ys[j])
        z00, z10 = self.heights_m[j, i], self.heights_m[j, i + 1]
        z01, z11 = self.heights_m[j + 1, i], self.heights_m[j + 1, i + 1]
        lower = z00 + fx * (z10 - z00) + fy * (z11 - z10)
        upper = z00 + fy * (z01 - z00) + fx * (z11 - z01)
        return np.where(fx >= fy, lower, upper)


def _axis() -> np.ndarray:
    inner = np.arange(-_INNER_CELLS, _INNER_CELLS + 1) * _CELL_M
    steps = [1.5 * _CELL_M]
    while _INNER_CELLS * _CELL_M + sum(steps) < _OUTER_EXTENT_M:
        steps.append(steps[-1] * _OUTER_GROWTH)
    outer = _INNER_CELLS * _CELL_M + np.cumsum(steps)
    return np.concatenate([-outer[::-1], inner, outer])


def _undulation(rng: np.random.Generator, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    height = np.zeros_like(x)
    for _ in range(3):
        direction = rng.uniform(0.0, 2 * np.pi)
        wavelength_m = rng.uniform(3.0, 10.0)
        along = x * np.cos(direction) + y * np.sin(direction)
        height += rng.uniform(0.01, 0.035) * np.sin(
            2 * np.pi * along / wavelength_m + rng.uniform(0, 2 * np.pi)
        )
    return height


def _bumps(rng: np.random.Generator, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """Bumps of a few centimetres on the fine grid, fading out towards its border, zero beyond."""
    inner_x = np.abs(xs) <= _INNER_CELLS * _CELL_M + 1e-9
    inner_y = np.abs(ys) <= _INNER_CELLS * _CELL_M + 1e-9
    noise = gaussian_filter(rng.normal(size=(inner_y.sum(), inner_x.sum())), sigma=rng.uniform(1.5, 3.0))
    noise *= rng.uniform(0.012, 0.02) / noise.std()
    edge_m = _INNER_CELLS * _CELL_M - np.maximum.outer(np.abs(ys[inner_y]), np.abs(xs[inner_x]))
    noise *= np.clip(edge_m / _BUMP_FADE_M, 0.0, 1.0)
    bumps = np.zeros((len(ys), len(xs)))
    bumps[np.ix_(inner_y, inner_x)] = noise
    return bumps


def _grid_triangles(nx: int, ny: int) -> np.ndarray:
    index = np.arange(nx * ny).reshape(ny, nx)
    v00, v10 = index[:-1, :-1].ravel(), index[:-1, 1:].ravel()
    v01, v11 = index[1:, :-1].ravel(), index[1:, 1:].ravel()
    return np.concatenate([np.stack([v00, v10, v11], 1), np.stack([v00, v11, v01], 1)]).astype(np.int32)


def smooth_field(
    rng: np.random.Generator, x: np.ndarray, y: np.ndarray, *, offset: tuple[float, float]
) -> np.ndarray:
    """A smooth random field in [0, 1] varying over metres at horizontal positions ``(x, y)``: the share
    of a floor's second material (dry grass in green grass, soil in straw). Four plane waves of 1-4 m
    wavelength summed with an offset drawn from ``offset`` (lower: less of the second material), then
    squashed by a logistic."""
    field = np.zeros_like(x) + rng.uniform(*offset)
    for _ in range(4):
        direction = rng.uniform(0.0, 2 * np.pi)
        along = x * np.cos(direction) + y * np.sin(direction)
        field += np.sin(2 * np.pi * along / rng.uniform(1.0, 4.0) + rng.uniform(0, 2 * np.pi))
    return 1.0 / (1.0 + np.exp(-2.0 * field))


def _colors(rng: np.random.Generator, centroids: np.ndarray, strip_half_width_m: float) -> np.ndarray:
    """Per-triangle colours: bare soil in the strip, green to dry grass outside it.

    Saturations stay low (soil, dry grass) or hues green, so that no ground colour falls into the red,
    yellow or blue ball ranges.
    """
    x, y = centroids[:, 0], centroids[:, 1]
    count = len(centroids)
    edge_m = strip_half_width_m + 0.06 * np.sin(2 * np.pi * x / rng.uniform(0.8, 2.5) + rng.uniform(0, 6.3))
    in_strip = np.abs(y) < edge_m + rng.normal(0.0, 0.03, count)
    soil = hsv_to_rgb(
        rng.uniform(22.0, 32.0, count), rng.uniform(0.25, 0.38, count), rng.uniform(0.3, 0.45, count)
    )
    green = hsv_to_rgb(
        rng.uniform(85.0, 110.0, count), rng.uniform(0.4, 0.6, count), rng.uniform(0.3, 0.48, count)
    )
    dry = hsv_to_rgb(
        rng.uniform(55.0, 70.0, count), rng.uniform(0.2, 0.32, count), rng.uniform(0.42, 0.58, count)
    )
    dryness = smooth_field(rng, x, y, offset=(-1.0, 0.5))[:, None]
    grass = (1.0 - dryness) * green + dryness * dry
    return np.where(in_strip[:, None], soil, grass).astype(np.float32)


def random_ground(rng: np.random.Generator, *, slope_deg: float | None = None) -> Ground:
    """Draw an uneven orchard floor with z = 0 at the origin (the main tree's trunk base), nearly level
    (tilted by at most 0.5 degrees) or, with ``slope_deg``, on a hillside of that slope in a random
    direction. The tilt is drawn either way, so that a slope leaves every other draw as it was."""
    xs = ys = _axis()
    grid_x, grid_y = np.meshgrid(xs, ys)
    tilt_deg = rng.uniform(0.0, 0.5)
    if slope_deg is not None:
        tilt_deg = slope_deg
    tilt_direction = rng.uniform(0.0, 2 * np.pi)
    rise = np.tan(np.radians(tilt_deg)) * np.array([np.cos(tilt_direction), np.sin(tilt_direction)])
    heights = (
        _undulation(rng, grid_x, grid_y)
        + _bumps(rng, xs, ys)
        + np.tan(np.radians(tilt_deg)) * (grid_x * np.cos(tilt_direction) + grid_y * np.sin(tilt_direction))
    )
    origin_j, origin_i = int(np.flatnonzero(ys == 0.0)[0]), int(np.flatnonzero(xs == 0.0)[0])
    heights -= heights[origin_j, origin_i]
    vertices = np.column_stack([grid_x.ravel(), grid_y.ravel(), heights.ravel()])
    triangles = _grid_triangles(len(xs), len(ys))
    strip_half_width_m = rng.uniform(0.45, 0.6)
    mesh = Mesh(
        vertices=vertices,
        triangles=triangles,
        colors=_colors(rng, vertices[triangles].mean(axis=1), strip_half_width_m),
        kinds=np.full(len(triangles), SurfaceKind.GROUND, dtype=np.int8),
    )
    return Ground(
        xs=xs,
        ys=ys,
        heights_m=heights,
        strip_half_width_m=strip_half_width_m,
        tilt_deg=tilt_deg,
        mesh=mesh,
        hillside_gradient=(0.0, 0.0) if slope_deg is None else (float(rise[0]), float(rise[1])),
    )
