"""Trellis posts and other poles standing beside the tree, found by their shape alone.

A trellis post (wood, concrete or steel, 5-20 cm thick, 2-4 m tall) stands in the tree line, and in many
rows within a metre of a trunk, where the crown grows round it. Apart from the crown it is a body rising
from the ground, which the crown's rules leave out (:func:`canopy_core.metrics.crown_mask`); touching the
crown, it joins it, and its lower part set the crown base and its top the height (probe 2112: posts 0.5-1.4
m from the trunk, 4 of 14 trees measured confidently wrong, D +37 % to +49 %, H +0.6 m once).

Colour does not tell a post (weathered wood and concrete look like bark, soil or sky), and neither does
its size alone (a trunk is as thick). Its shape does: seen in thin horizontal slabs, where it stands in open
air (below the crown, above it, beyond its edge) each slab of it is a small compact group of points with
nothing else near it, and the groups of successive slabs stand in one straight, nearly vertical line that
goes down to the ground. Foliage is neither compact and alone in slab after slab, nor straight. The tree's
own trunk is such a line too, and is recognised by its foot: a pole's stands apart from the trunk's circle
(:attr:`canopy_core.ground.GroundFrame.trunk_xy_m`). Through the crown the pole is followed along its line
as long as something is seen on it, hidden spans up to ``max_gap_m`` bridged, and on to any straight line
of compact groups above that continues it (a post whose top stands above the crown).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from canopy_core.config import PoleConfig
from canopy_core.ground import CLEARLY_NEARER, crown_middle
from canopy_core.kdtree import point_tree
from canopy_core.trunk_axis import SOLID_INSIDE_SHARE, TrunkAxis

__all__ = ["Pole", "find_poles", "pole_mask"]

_MIN_GROUP_POINTS = 3
"""A slab's group of fewer points is a speck (a flying pixel), not a piece of a pole."""
_COMPACT_SHARE = 0.9
"""A slab of a pole is compact when this share of its points lie within the thickest pole's radius of its
centre: the rest may be its noisiest pixels, at grazing incidence on its outline, scattered along the rays
by a decimetre or more."""
_EXTRAPOLATION_SDS = 2.0
"""A stretch continues a pole's line above when its centres lie within this many standard errors of that
line where they stand (:func:`_extrapolation_sd`), beyond the thickest pole's radius and the tolerance."""
_SHORT_LEAN_SDS = 2.0
"""A stretch too short to be a pole's foot (under ``config.min_length_m``) may lean past the steepest a pole
leans by this many standard errors of its lean (:func:`_lean_sd`): such a stretch is only ever joined to a
pole found from the ground, by where it stands, and four slabs fix a lean only to 10 degrees."""
_MIN_CROWN_POINTS = 100
"""Fewer points than this standing above a pole's lowest stretch alone, off the uprights, are no crown over
it: a trellis wire's pixels, a neighbour's twig (a crown shows thousands)."""
_MIN_CHAIN_SLABS = 3
"""A straight stretch of fewer groups is not known to be straight. Stretches this short are taken only as the
rest of a pole found from the ground (the top of a post standing a little above the crown)."""


@dataclass(frozen=True, eq=False)
class Pole:
    """A pole standing on the ground: its axis runs straight through each stretch where it stands alone and
    from one to the next (the views' registration may bend it by a few centimetres over metres), held
    plumb beyond them; its points lie within ``radius_m`` of it, up to ``top_m`` high."""

    axis: TrunkAxis
    """Where the axis stands at each height (a trunk's axis is kept the same way)."""
    surface_radius_m: float
    """How far from the axis its surface's points lie (their noise included)."""
    tolerance_m: float
    """The margin round that surface within which points are the pole's."""
    top_m: float
    """Height (world z) of the pole's highest slab seen."""
    alone_m: tuple[tuple[float, float], ...]
    """The heights (world z, lowest and highest) of each stretch where it stands alone."""

    @property
    def radius_m(self) -> float:
        """How far from the axis the pole's points lie: its surface, with the tolerance."""
        return self.surface_radius_m + self.tolerance_m

    def contains(self, points_m: np.ndarray) -> np.ndarray:
        """Mask of the ``(N, 3)`` world points that are the pole's (and whatever touches its surface)."""
        return (self.axis.distance_m(points_m) <= self.radius_m) & (points_m[:, 2] <= self.top_m)

    def in_sight(self, points_m: np.ndarray, camera_m: np.ndarray, *, spread_m: float) -> np.ndarray:
        """Mask of one view's ``(N, 3)`` world points that its camera (centre ``camera_m``) sees along the
        pole's outline (seen from above): behind its near surface at any height up to its top, which
        the pole hides from that camera, so that only its mixed pixels lie there; and in front of it up
        to ``spread_m`` where it stands alone (``alone_m``), its own noisiest pixels: the last pixels
        across a round pole meet it at grazing incidence, where depth noise along the ray grows to
        centimetres and decimetres. Nothing where the camera stands inside the pole's radius."""
        to_axis = self.axis.xy_at(points_m[:, 2]) - camera_m[:2]
        distance = np.linalg.norm(to_axis, axis=1)
        outside = distance > self.radius_m
        toward = to_axis / np.maximum(distance, self.radius_m)[:, None]
        offset = points_m[:, :2] - camera_m[:2]
        along = np.einsum("ij,ij->i", offset, toward)
        across = np.abs(offset[:, 0] * toward[:, 1] - offset[:, 1] * toward[:, 0])
        outline = outside & (across * distance <= self.radius_m * along) & (points_m[:, 2] <= self.top_m)
        near = distance - self.radius_m
        alone = np.zeros(points_m.shape[0], dtype=bool)
        for low, high in self.alone_m:
            alone |= (points_m[:, 2] >= low) & (points_m[:, 2] <= high)
        return outline & ((along >= near) | (alone & (along >= near - spread_m)))


@dataclass(frozen=True)
class _Chain:
    """Compact groups of successive slabs standing in one straight line."""

    slabs: np.ndarray
    """``(K,)`` slab indices, ascending."""
    centres_xy_m: np.ndarray
    """``(K, 2)`` the groups' centres."""
    points: np.ndarray
    """Indices of the chain's points (of each group, the ``_COMPACT_SHARE`` nearest its centre)."""
    foot_xy_m: np.ndarray
    lean_per_m: np.ndarray
    from_foot: bool
    """Whether it begins at the lowest slab of its line of groups; a stretch split off above a bend in
    that line (see :func:`_straight_stretches`) is not the foot of a pole."""


def find_poles(
    points_m: np.ndarray,
    heights_m: np.ndarray,
    *,
    trunk_xy_m: np.ndarray,
    trunk_radius_m: float,
    foot_below_m: float,
    config: PoleConfig,
) -> tuple[Pole, ...]:
    """The poles standing among the ``(N, 3)`` world points (tree candidates, wires removed), each
    point's height above the local ground given (``heights_m``).

    A pole is a straight line of compact groups (see the module's docstring) at least ``config.min_length_m``
    long, whose column (its points within the radius its groups show) reaches down, hidden spans bridged,
    to less than ``foot_below_m`` above the ground, and whose axis stands at least
    ``config.min_trunk_gap_m`` outside the trunk's bark there (the trunk's foot ``trunk_xy_m``, radius
    ``trunk_radius_m``).
    """
    if points_m.shape[0] == 0:
        return ()
    slab_of = np.floor(points_m[:, 2] / config.slab_m).astype(np.int64)
    chains, alone = _straight_chains(points_m, slab_of, config)
    grounded = []
    for chain in chains:
        pole = _grounded_pole(
            chain,
            chains,
            points_m,
            heights_m,
            slab_of,
            alone,
            foot_below_m,
            config,
            trunk_xy_m,
            trunk_radius_m,
        )
        if pole is None:
            continue
        axis_low = pole.axis.xy_at(points_m[chain.points, 2].min(keepdims=True))[0]
        if _by_trunk(axis_low[None], trunk_xy_m, trunk_radius_m, config):
            continue  # the trunk itself, or too near it to be told from it
        grounded.append(pole)
    uprights = np.vstack([trunk_xy_m, *(pole.axis.centres_xy_m for pole in grounded)])
    # Not the tree's own trunk (the trunk found a post), nor a second stem, however lopsided the crown.
    return tuple(
        pole for pole in grounded if _trunk_clearly_under_crown(pole, points_m, trunk_xy_m, uprights)
    )


def _by_trunk(xy_m: np.ndarray, trunk_xy_m: np.ndarray, trunk_radius_m: float, config: PoleConfig) -> bool:
    """Whether any of the ``(K, 2)`` positions stands within ``config.min_trunk_gap_m`` of the trunk's bark
    (its foot ``trunk_xy_m``, radius ``trunk_radius_m``): too near to be told from the trunk."""
    return bool(np.linalg.norm(xy_m - trunk_xy_m, axis=1).min() < trunk_radius_m + config.min_trunk_gap_m)


def _trunk_clearly_under_crown(
    pole: Pole, points_m: np.ndarray, trunk_xy_m: np.ndarray, uprights_xy_m: np.ndarray
) -> bool:
    """Whether the trunk stands clearly nearer than ``pole`` the middle of what stands above the pole's
    lowest stretch alone (:func:`canopy_core.ground.crown_middle`, ``CLEARLY_NEARER``), as it does under
    the crown it carries; else the pole may be the tree's own trunk, were the trunk found on a post, or a
    second stem, and is left in the tree. What stands round the ``uprights_xy_m`` (the trunk and every
    pole found, each axis's centres) is no crown there: a post 1.4 m from the trunk, 3.5 m tall, put the
    middle of a crown 1.7 m wide 0.5 m off its trunk, half-way to it, and another post on the other side
    was left in the tree. True when fewer than ``_MIN_CROWN_POINTS`` points, anywhere in the region, stand
    above that stretch off the uprights (a post standing alone nearly to the crown's top has only wire
    pixels above it)."""
    above = points_m[points_m[:, 2] > pole.alone_m[0][1]]
    middle = crown_middle(above[:, :2], uprights_xy_m, min_points=_MIN_CROWN_POINTS)
    if middle is None:
        return True
    at_middle = pole.axis.xy_at(np.median(above[:, 2], keepdims=True))[0]
    return bool(np.linalg.norm(trunk_xy_m - middle) < CLEARLY_NEARER * np.linalg.norm(at_middle - middle))


def pole_mask(
    points_m: np.ndarray, poles: tuple[Pole, ...], *, camera_m: np.ndarray, spread_m: float
) -> np.ndarray:
    """Mask of one view's ``(N, 3)`` world points on any of ``poles`` or along its outline as that view's
    camera (centre ``camera_m``) sees it (:meth:`Pole.in_sight`)."""
    mask = np.zeros(points_m.shape[0], dtype=bool)
    for pole in poles:
        mask |= pole.contains(points_m) | pole.in_sight(points_m, camera_m, spread_m=spread_m)
    return mask


def _slab_groups(slab: np.ndarray, cell: np.ndarray, reach: int) -> tuple[int, np.ndarray]:
    """How many groups the occupied cells form, and each point's group: the points' slabs ``slab`` and grid
    cells ``cell`` (``(N, 2)``, rows and columns, all from 0), cells within ``reach`` cells of each other
    (a square round each) joined, never across slabs. Groups are numbered in the order of their first cell,
    slab by slab and row by row (as ``scipy.ndimage.label`` numbers them, which this replaces: importing
    SciPy's image module cost every measurement 40 ms).

    The slabs are stacked into one image with ``reach`` empty rows between them, so that neither the
    square round a cell nor a group's 8-neighbours reach into the next slab; OpenCV dilates and labels it.
    """
    slab, cell = np.asarray(slab, dtype=np.int64), np.asarray(cell, dtype=np.int64)
    slabs, rows, columns = int(slab.max()) + 1, int(cell[:, 0].max()) + 1, int(cell[:, 1].max()) + 1
    pitch = rows + max(reach, 1)  # at least one empty row: groups never join across it
    image = np.zeros((slabs * pitch, columns), dtype=np.uint8)
    image[slab * pitch + cell[:, 0], cell[:, 1]] = 1
    joined = cv2.dilate(image, np.ones((2 * reach + 1, 2 * reach + 1), dtype=np.uint8))
    joined.reshape(slabs, pitch, columns)[:, rows:] = 0  # the rows between slabs join nothing
    count, labels, stats, _ = cv2.connectedComponentsWithStats(joined, connectivity=8, ltype=cv2.CV_32S)
    row = slab * pitch + cell[:, 0]
    label = labels[row, cell[:, 1]]
    # OpenCV numbers the groups in an order of its own: renumbered by each one's first cell, the leftmost
    # of its top row, which the squares of its occupied cells within ``reach`` rows of that row reach.
    top = stats[:, cv2.CC_STAT_TOP].astype(np.int64)
    near_top = row <= top[label] + reach
    left = np.full(count, columns, dtype=np.int64)
    np.minimum.at(left, label[near_top], np.maximum(cell[near_top, 1] - reach, 0))
    number = np.empty(count, dtype=np.int64)
    number[1 + np.argsort(top[1:] * columns + left[1:])] = np.arange(count - 1)
    return count - 1, number[label]


def _straight_chains(
    points_m: np.ndarray, slab_of: np.ndarray, config: PoleConfig
) -> tuple[list[_Chain], np.ndarray]:
    """The straight, nearly vertical lines of compact groups standing alone, slab after slab, and the mask
    of the points in any compact group (standing alone in their slab).

    Each slab's points are grouped on a grid of ``config.cell_m`` cells, cells within about
    ``config.isolation_m`` of each other joined; a group is compact when its points (but the farthest
    tenth, ``_COMPACT_SHARE``) lie within ``config.max_radius_m`` (and the tolerance) of its centre (see
    :func:`_trimmed_groups`). Groups of slabs one or two apart whose centres stand within the lean's reach
    join a line of groups; its straight stretches (:func:`_straight_stretches`: within ``config.tolerance_m``
    (RMS) of a line leaning at most ``config.max_lean_deg``) are the chains.
    """
    cell = np.floor(points_m[:, :2] / config.cell_m).astype(np.int64)
    cell -= cell.min(axis=0)
    slab = slab_of - slab_of.min()
    reach = max(1, int(np.ceil(config.isolation_m / config.cell_m / 2)))
    count, group = _slab_groups(slab, cell, reach)
    sizes = np.bincount(group, minlength=count)
    centres, order, starts, extent = _trimmed_groups(points_m[:, :2], group, sizes)
    kept = np.ceil(_COMPACT_SHARE * sizes).astype(np.int64)  # each group's points nearest its centre
    group_slab = np.zeros(count, dtype=np.int64)
    group_slab[group] = slab_of
    compact = np.flatnonzero(
        (sizes >= _MIN_GROUP_POINTS) & (extent <= config.max_radius_m + config.tolerance_m)
    )
    alone = np.isin(group, compact)
    if compact.size < 2:
        return [], alone
    lean = np.tan(np.radians(config.max_lean_deg))
    pairs = point_tree(centres[compact]).query_pairs(
        r=config.tolerance_m + 2 * lean * config.slab_m, output_type="ndarray"
    )
    apart = np.abs(group_slab[compact[pairs[:, 0]]] - group_slab[compact[pairs[:, 1]]])
    pairs = pairs[(apart >= 1) & (apart <= 2)]
    _, chain_of = connected_components(
        coo_matrix((np.ones(pairs.shape[0]), (pairs[:, 0], pairs[:, 1])), shape=(compact.size,) * 2),
        directed=False,
    )
    chains = []
    for members in np.split(np.argsort(chain_of), np.cumsum(np.bincount(chain_of))[:-1]):
        groups = compact[members]
        slabs = group_slab[groups]
        if np.unique(slabs).size != slabs.size or slabs.size < _MIN_CHAIN_SLABS:
            continue  # two groups in one slab: no single line (a fork of branches); or too few
        ascending = np.argsort(slabs)
        groups, slabs = groups[ascending], slabs[ascending]
        for low, high, foot, lean_per_m in _straight_stretches(
            (slabs + 0.5) * config.slab_m, centres[groups], config
        ):
            stretch = groups[low:high]
            chains.append(
                _Chain(
                    slabs=slabs[low:high],
                    centres_xy_m=centres[stretch],
                    points=np.concatenate([order[starts[g] : starts[g] + kept[g]] for g in stretch]),
                    foot_xy_m=foot,
                    lean_per_m=lean_per_m,
                    from_foot=low == 0,
                )
            )
    return chains, alone


def _straight_stretches(
    heights_m: np.ndarray, centres_xy_m: np.ndarray, config: PoleConfig
) -> list[tuple[int, int, np.ndarray, np.ndarray]]:
    """The stretches (``[low, high)`` of the ``(K,)`` ascending heights and their ``(K, 2)`` centres) that
    stand in straight lines, each with its line's foot and lean (:func:`_line`): within
    ``config.tolerance_m`` (RMS) of a line leaning at most ``config.max_lean_deg``, each
    ``_MIN_CHAIN_SLABS`` long at least; a stretch shorter than ``config.min_length_m``, which never stands
    as a pole's foot, may lean more by ``_SHORT_LEAN_SDS`` standard errors of its lean (a post's top above
    a crown, seen 20 cm high, was fitted leaning 11 degrees and left in the tree: held-out near posts
    2120043, H +8 %). The whole, when it is straight; else split where the worse side's line fits best, and
    each side the same way.

    Where one view stops seeing a round pole (hidden behind leaves, or out of its frame), its slabs' centres
    move towards the view that still sees it, by up to two thirds of its radius: a post seen from both
    sides below and from one above the crown (held-out near posts 2119029, 1.1 m above a crown 2.2 m tall)
    is two straight stretches 4 cm apart, not one line."""
    count = heights_m.size
    if count < _MIN_CHAIN_SLABS:
        return []
    foot, lean_per_m, rms = _line(heights_m, centres_xy_m)
    steepest = np.tan(np.radians(config.max_lean_deg))
    if heights_m[-1] - heights_m[0] + config.slab_m < config.min_length_m:  # as a pole's foot is judged
        steepest += _SHORT_LEAN_SDS * _lean_sd(heights_m, config.tolerance_m)
    if rms <= config.tolerance_m and np.linalg.norm(lean_per_m) <= steepest:
        return [(0, count, foot, lean_per_m)]
    splits = range(_MIN_CHAIN_SLABS, count - _MIN_CHAIN_SLABS + 1)
    if not splits:
        return []
    worse = [
        max(_line(heights_m[:k], centres_xy_m[:k])[2], _line(heights_m[k:], centres_xy_m[k:])[2])
        for k in splits
    ]
    split = splits[int(np.argmin(worse))]
    below = _straight_stretches(heights_m[:split], centres_xy_m[:split], config)
    above = _straight_stretches(heights_m[split:], centres_xy_m[split:], config)
    return below + [(low + split, high + split, foot, lean) for low, high, foot, lean in above]


def _trimmed_groups(
    xy_m: np.ndarray, group: np.ndarray, sizes: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each group's centre, robust to its farthest points: the mean of the ``_COMPACT_SHARE`` of its points
    nearest the mean of all. Returns the centres; the points' order by group and, within each, by distance
    from its centre; where each group starts in that order; and how far from its centre that share of
    each group's points lie. Every group holds a point (``sizes`` > 0)."""
    count, n = sizes.size, group.size
    starts = np.concatenate([[0], np.cumsum(sizes)])

    def mean_of(mask: np.ndarray) -> np.ndarray:
        weights = np.bincount(group[mask], minlength=count)
        sums = [np.bincount(group[mask], weights=xy_m[mask, axis], minlength=count) for axis in (0, 1)]
        return np.column_stack(sums) / np.maximum(weights, 1)[:, None]

    def by_distance(centres: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        from_centre = np.linalg.norm(xy_m - centres[group], axis=1)
        order = np.lexsort((from_centre, group))
        rank = np.empty(n, dtype=np.int64)
        rank[order] = np.arange(n) - starts[group[order]]
        return from_centre, order, rank

    _, _, rank = by_distance(mean_of(np.ones(n, dtype=bool)))
    centres = mean_of(rank < np.ceil(_COMPACT_SHARE * sizes[group]))
    from_centre, order, _ = by_distance(centres)
    extent = from_centre[order[starts[:-1] + np.floor(_COMPACT_SHARE * (sizes - 1)).astype(np.int64)]]
    return centres, order, starts, extent


def _line(heights_m: np.ndarray, centres_xy_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """The least-squares line (x, y) = foot + lean * z through ``(K, 2)`` centres at ``(K,)`` heights:
    its foot, its lean per metre and the centres' RMS distance from it."""
    design = np.column_stack([np.ones_like(heights_m), heights_m])
    fit, *_ = np.linalg.lstsq(design, centres_xy_m, rcond=None)
    residual = np.linalg.norm(centres_xy_m - design @ fit, axis=1)
    return fit[0], fit[1], float(np.sqrt(np.mean(residual**2)))


def _lean_sd(heights_m: np.ndarray, sd_m: float) -> float:
    """The standard error of the lean of the least-squares line (:func:`_line`) through centres at
    ``heights_m``, each off the pole's axis by ``sd_m``."""
    return sd_m / float(np.sqrt(np.sum((heights_m - heights_m.mean()) ** 2)))


def _extrapolation_sd(heights_m: np.ndarray, at_m: np.ndarray, sd_m: float) -> np.ndarray:
    """The standard error at heights ``at_m`` of the least-squares line (:func:`_line`) through centres at
    ``heights_m``, each off the pole's axis by ``sd_m`` (standard deviation): the mean's error and the
    lean's, carried from the centres' mean height."""
    spread = np.sum((heights_m - heights_m.mean()) ** 2)
    return sd_m * np.sqrt(1.0 / heights_m.size + (at_m - heights_m.mean()) ** 2 / spread)


def _pole_along(parts: list[_Chain], points_m: np.ndarray, config: PoleConfig, *, top_m: float) -> Pole:
    """The pole through the chains ``parts`` up to ``top_m``: each part's own line over its stretch,
    straight lines between them. Its radius is as far as a slab's points lie from the line (the median over
    the parts' slabs, so that grass at a post's foot does not widen it) with the tolerance, at most the
    thickest pole's: each slab of a part is a group with nothing else near it, so all of its points are
    the pole's, the mixed pixels at its outline too."""
    heights, centres, radii = [], [], []
    for part in sorted(parts, key=lambda chain: int(chain.slabs[0])):
        ends = (part.slabs[[0, -1]] + 0.5) * config.slab_m
        heights.append(ends)
        centres.append(part.foot_xy_m + ends[:, None] * part.lean_per_m)
        members = points_m[part.points]
        offsets = members[:, :2] - (part.foot_xy_m + members[:, 2:3] * part.lean_per_m)
        slab_of = np.floor(members[:, 2] / config.slab_m).astype(np.int64) - part.slabs[0]
        widest = np.zeros(part.slabs[-1] - part.slabs[0] + 1)
        np.maximum.at(widest, slab_of, np.linalg.norm(offsets, axis=1))
        radii.extend(widest[part.slabs - part.slabs[0]])
    return Pole(
        axis=TrunkAxis(heights_m=np.concatenate(heights), centres_xy_m=np.concatenate(centres)),
        surface_radius_m=min(float(np.median(radii)), config.max_radius_m),
        tolerance_m=config.tolerance_m,
        top_m=top_m,
        alone_m=tuple((float(low), float(high)) for low, high in heights),
    )


def _grounded_pole(
    chain: _Chain,
    chains: list[_Chain],
    points_m: np.ndarray,
    heights_m: np.ndarray,
    slab_of: np.ndarray,
    alone: np.ndarray,
    foot_below_m: float,
    config: PoleConfig,
    trunk_xy_m: np.ndarray,
    trunk_radius_m: float,
) -> Pole | None:
    """The pole ``chain`` is part of, if it is one and rises from the ground: the chain is the foot of its
    line of groups (no bend below it), at least ``config.min_length_m`` long and ``config.min_radius_m``
    thick, reaches down to within ``config.max_gap_m`` of ``foot_below_m`` above the ground (grass may hide
    a post's foot), and its column goes on down to below it through hidden spans up to
    ``config.max_gap_m``. It goes on up through those of the other ``chains`` above it, as thick, that
    continue its line: within the thickest pole's radius, the tolerance and two standard errors of the line
    through every stretch taken so far where they stand (a short stretch's lean carried over metres is
    uncertain by decimetres; 0.5 m of a post by its foot put its line 0.17 m off the post at 3.2 m), the
    one the line passes nearest taken first, the line refitted and the rest weighed again, one stretch at
    each height (:func:`_distance_from_line`); none standing over the trunk's foot within its bark and
    ``config.min_trunk_gap_m`` (``trunk_xy_m``, ``trunk_radius_m``: the tree's leader). From the
    highest of them it goes on up as long as its surface shows (:func:`_surface_top`). None otherwise."""
    if not chain.from_foot:
        return None  # above a bend of its line (a trunk or a stem leaning low down): not where a pole stands
    if (chain.slabs[-1] - chain.slabs[0] + 1) * config.slab_m < config.min_length_m:
        return None  # too short to be told from a weed's stem
    if heights_m[chain.points].min() >= foot_below_m + config.max_gap_m:
        return None  # stands alone only high up (a leader's bare tip over the crown): not from the ground
    pole = _pole_along([chain], points_m, config, top_m=float(np.inf))
    if pole.surface_radius_m < config.min_radius_m:
        return None  # a sucker, a shoot, a stake's line of pixels
    column = pole.contains(points_m) & (slab_of <= chain.slabs[0])
    column[chain.points] = True
    downwards = np.unique(slab_of[column])[::-1]
    breaks = np.flatnonzero(-np.diff(downwards) > _gap_slabs(config))
    lowest = downwards[breaks[0]] if breaks.size else downwards[-1]
    if heights_m[column & (slab_of >= lowest)].min() >= foot_below_m:
        return None  # its column ends above the ground: it hangs (a branch), or stands on something
    parts = [chain]
    heights = (chain.slabs + 0.5) * config.slab_m
    foot, lean_per_m = chain.foot_xy_m, chain.lean_per_m
    # Nearest the line first: of the stretches within its reach, the one it passes closest is the post's
    # own; a stretch 15 cm beside the post at the crown's top, taken first as the lowest, bent the refitted
    # line away from the post's top above the crown (tuning near posts 2121057, H +0.56 m). Each stretch
    # taken refits the line, and the rest are weighed again on it.
    rest = [
        other
        for other in chains
        if other.slabs[0] > chain.slabs[-1]
        and not _by_trunk(other.centres_xy_m, trunk_xy_m, trunk_radius_m, config)  # the tree's leader
        and _pole_along([other], points_m, config, top_m=0.0).surface_radius_m >= config.min_radius_m
    ]
    while rest:
        distances = [_distance_from_line(other, heights, foot, lean_per_m, config) for other in rest]
        nearest = int(np.argmin(distances))
        if not np.isfinite(distances[nearest]):
            break
        taken = rest[nearest]
        rest = [other for other in rest if not _overlap(other, taken)]  # one part at each height
        parts.append(taken)
        heights = np.concatenate([heights, (taken.slabs + 0.5) * config.slab_m])
        foot, lean_per_m, _ = _line(heights, np.concatenate([part.centres_xy_m for part in parts]))
    highest = max(parts, key=lambda part: int(part.slabs[-1]))
    joined = _pole_along(parts, points_m, config, top_m=float(np.inf))
    return replace(joined, top_m=_surface_top(joined, highest, points_m, slab_of, alone, config))


def _distance_from_line(
    chain: _Chain, heights_m: np.ndarray, foot_xy_m: np.ndarray, lean_per_m: np.ndarray, config: PoleConfig
) -> float:
    """How far ``chain``'s centres lie from the line ``foot_xy_m + lean_per_m * z`` fitted through centres at
    ``heights_m`` (their mean distance); infinite when any lies beyond the line's reach there: the thickest
    pole's radius, the tolerance, and ``_EXTRAPOLATION_SDS`` standard errors of the line where it stands."""
    chain_heights = (chain.slabs + 0.5) * config.slab_m
    distance = np.linalg.norm(chain.centres_xy_m - (foot_xy_m + chain_heights[:, None] * lean_per_m), axis=1)
    reach = (
        config.max_radius_m
        + config.tolerance_m
        + _EXTRAPOLATION_SDS * _extrapolation_sd(heights_m, chain_heights, config.tolerance_m)
    )
    return float(distance.mean()) if (distance <= reach).all() else float(np.inf)


def _overlap(one: _Chain, other: _Chain) -> bool:
    """Whether two chains share a height (a slab range)."""
    return bool(one.slabs[0] <= other.slabs[-1] and other.slabs[0] <= one.slabs[-1])


def _surface_top(
    pole: Pole,
    highest: _Chain,
    points_m: np.ndarray,
    slab_of: np.ndarray,
    alone: np.ndarray,
    config: PoleConfig,
) -> float:
    """How high ``pole`` goes: from its ``highest`` stretch alone, up through the slabs where its surface
    shows (points on it, few inside it: a pole is solid; ``SOLID_INSIDE_SHARE``) or where what lies on it
    stands alone (``alone``: a compact group, as the top of a post with the wires' clips and stubs on it),
    spans where nothing shows on it up to ``config.max_gap_m`` bridged (leaves in front of it); it ends
    where nothing shows for longer, or where leaves fill it."""
    distance = pole.axis.distance_m(points_m)
    near = distance <= pole.radius_m
    inside = distance < pole.surface_radius_m - pole.tolerance_m
    top = int(highest.slabs[-1])
    hidden = 0
    for slab in range(top + 1, int(slab_of.max()) + 1):
        shown = near & (slab_of == slab)
        if not shown.any():
            hidden += 1
            if hidden >= _gap_slabs(config):
                break
            continue
        solid = np.count_nonzero(shown & inside) <= SOLID_INSIDE_SHARE * np.count_nonzero(shown & ~inside)
        if not (solid or alone[shown].all()):
            break
        top, hidden = slab, 0
    return float((top + 1) * config.slab_m)


def _gap_slabs(config: PoleConfig) -> int:
    """Slabs one past the longest hidden span a pole is followed through (``config.max_gap_m``)."""
    return int(np.floor(config.max_gap_m / config.slab_m)) + 1
