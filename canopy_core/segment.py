"""Separating the measured tree from whatever else stands in the region of interest.

A cylinder round the trunk (round the balls where no trunk is found) holds the tree, but also what reaches
into it from outside: a neighbour's crown, a trellis post, the trellis wires. Such intruders enter through
the cylinder's wall.

Wires (:func:`find_wires`) are found first, because they join everything they pass through: a wire runs
along the row through the trunk line, so through the crown, and on to the posts and the neighbours. Each
view shows it as a sparse, straight, nearly level line of points, a little off the other views' (mixed
pixels, see :func:`wire_mask`), that crosses the whole cylinder, hidden where it runs through the crown;
a branch is thicker, and ends inside the crown. A wire also runs on beyond the cylinder, between the crown
and the neighbours: lines seen there on both sides of the tree, in line, are wires, their direction and
slope fixed over metres, and they are sought first. Failing that, the first wire is sought by a Hough
transform over level lines (direction, offset, height) among the points whose neighbourhood, in one
view, is a thin line (local principal components), and when none is a wire, among the points in open
air (no more round them than a line's: a wire above the crown, against the sky, that dropout breaks into
pieces too short to look thin). The trellis's other wires run beside the first, so they are sought
parallel to it, among all the points with a sparse neighbourhood, and from each straight, level chain of
thin-line points parallel to it (a wire the crown hides but for a short stretch). A line is a wire when it is
nearly level, seen over a length that leaves and twigs never line up over, and crosses the cylinder: its
own points and what hides it cover most of its chord; or when it stands free, nothing but itself within a
neighbourhood's radius, seen along a fifth of its chord and between sightings half of it apart (against
the sky, dropout takes most of a thin wire and nothing hides the rest). Its points are then removed along
its whole length, inside the crown too.

The other intruders are separated from the tree by a gap. The tree itself need not be one connected body
in the data: thin scaffold branches hidden by leaves leave its crown floating above its trunk. So the
points are grouped into bodies separated by gaps wider than ``link_m`` (on occupied voxels: fast, and
indifferent to point density), and a body is dropped only when it touches the wall and is neither joined
to the trunk nor a large part of what is in the cylinder, or when it is a speck of a few voxels
(:func:`tree_component`).
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from canopy_core.kdtree import NearestTree, point_tree
from canopy_core.voxels import occupied_voxels

__all__ = ["Wire", "find_wires", "is_wire_piece", "tree_component", "wire_mask"]

_TRUNK_SEED_RADIUS_M = 0.35
"""Voxels this close to the trunk's axis, in the lowest part of the cloud, belong to the tree's trunk."""
_TRUNK_SEED_HEIGHT_M = 0.6
_WALL_BAND_M = 0.1
"""A body with points this close to the cylinder's wall comes from outside it."""
_LARGE_SHARE = 0.25
"""A body holding this share of the voxels is (part of) the tree even if it reaches the wall."""
_SPECK_VOXELS = 4

_WIRE_NEIGHBOURHOOD_M = 0.1
"""Radius of the neighbourhood whose shape tells a line: ten times a wire's thickness with its noise, so a
wire's neighbourhood is a thin line; a few times a leaf's size, so a leaf's is not."""
_WIRE_OPEN_SPAN_M = 0.3
"""A wire is seen over at least this length (beside the crown, or in the gap of at least 0.3 m between two
crowns of a row); no leaf or twig lies straight over as much."""
_FIRST_WIRE_SEEN = 0.2
"""The first wire, sought in any direction, is seen as a thin line in at least this share of its chord
through the cylinder, wherever no crown hides it; leaves at a crown's edge line up by chance in a few
short stretches (at most 17 % of a chord in 109 simulated captures, 56 of them without wires; the first
wire of a trellis was seen in 20-90 %). The trellis's other wires, sought parallel to it, may be
hidden more."""
_WIRE_WALL_M = 0.2
"""A wire enters and leaves the cylinder through its wall, where it is seen within this distance of both
ends of its chord (twice the wall band: dropout leaves gaps in a sparse line). Leaves at a crown's edge
never line up with both ends (none of the candidate lines in the same 109 captures did)."""
_WIRE_SEEN_ALONE = 0.5
"""A line seen in this share of its chord is a wire whatever the rest of the chord holds: part of a wire
above a tall crown is out of the cameras' view."""
_SEEN_WIRE_MAX_SLOPE_DEG = 10.0
"""A line seen along most of its chord (:data:`_WIRE_SEEN_ALONE`) crosses the cylinder as no leaf or branch
does, so it is a wire even sloping this much against the fitted ground: the ground plane of a few metres
of undulating floor tilts by degrees, and a wire sags towards its posts."""
_SIGHT_STEP_M = 0.02
_SIGHT_RADIUS_M = 0.02
"""A line of sight is blocked where a point lies within this distance of it (about a pixel's footprint at
3 m), sampled every ``_SIGHT_STEP_M``."""
_SIGHT_CLEARANCE_M = 0.15
"""What lies this close before a place along the line of sight does not hide it (the wire's own mixed
pixels, leaves touching it)."""
_WIRE_BIN_M = 0.1
"""Length of the stretches of a line's chord whose occupation measures how much of it is covered."""
_FIRST_WIRE_TRIES = 3
"""Most lines tried for the first wire: it is the most evident line, or nearly (the first or second tried in
50 simulated captures with wires); lines after those are leaves lining up by chance."""
_WIRE_FIT_ROUNDS = 4
"""Rounds of the wire's fit: the first on the Hough line's points, then on the points near the fit."""
_WIRE_FIT_REACH = 2.0
"""Each round of the fit takes in the points within this many tolerances of the last round's line."""
_WIRE_MAX_LINES = 10
"""Most candidate lines examined: orchards string two to five wires, and each rejected candidate line
takes its points out of the search."""
_WIRE_STRETCH_M = 0.15
"""A chain of thin-line cells that runs straight and level over this length in plan, parallel to a wire
found, is a stretch of another wire of the trellis seen beside the crown: longer than a leaf (5-10 cm),
where the Hough transform may rank chance lines of leaves first."""
_WIRE_MAX_TURN_DEG = 6.0
"""The first wire's fit, from where the search found it (often one side of the crown, a metre or less),
errs in direction and slope by up to this angle (4.3 degrees in a simulated capture); it is then turned,
within this angle, to the line its points cover most of the chord along (:func:`_turned_to_cover`)."""
_WIRE_VIEW_OFFSET_M = 0.1
"""A view's line of a wire stands up to this far off the wire: its mixed pixels blend the wire's depth with
the background's, by more against a near background (7 cm in a simulated capture)."""
_FREE_STANDING_SHARE = 0.9
"""A line stands free, in open air, when at least this share of the points (cells) within
:data:`_WIRE_NEIGHBOURHOOD_M` of it lie on it, within the tolerance: nothing but a wire stands along a
straight, level line with nothing round it (a wire above a crown, seen against the sky). The rest allows
a stray flying pixel."""
_WIRE_STRETCH_MAX_TURN_DEG = 10.0
"""Such a chain runs within this angle of the wire found (or, beyond the cylinder, of the line joining it
to a chain on the tree's other side): its own direction, over a few cells of ``tolerance_m``, errs by
several degrees; the wire is then fitted along the found wire's direction (or to both chains)."""
_SCENE_PAIRS_TRIED = 10
"""Most pairs of chains fitted for each wire sought across the scene, those of the longest chains first: a
wire shows as one chain or a few on either side of the tree, and a trellis strings two to five."""


@dataclass(frozen=True, eq=False)
class Wire:
    """A trellis wire in the world frame: a straight line in plan, its height sloping evenly along it.

    ``origin_xy_m`` is a point of the line in plan and ``direction_xy`` its unit direction; the wire's
    height at signed distance s from the origin along the direction is ``height_m + slope * s``. A wire's
    sag curves it by about a centimetre over the region of interest (a few centimetres over spans of metres
    between posts), which the tolerance absorbs.
    """

    origin_xy_m: np.ndarray
    direction_xy: np.ndarray
    height_m: float
    slope: float

    def offsets_m(self, points_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each ``(N, 3)`` point's horizontal offset across the wire, and its height above the wire."""
        offset = points_m[:, :2] - self.origin_xy_m
        along = offset @ self.direction_xy
        across = offset @ np.array([-self.direction_xy[1], self.direction_xy[0]])
        return across, points_m[:, 2] - (self.height_m + self.slope * along)

    def at(self, along_m: np.ndarray) -> np.ndarray:
        """The ``(N, 3)`` points of the wire at signed distances ``along_m`` from its origin."""
        plan = self.origin_xy_m + np.outer(along_m, self.direction_xy)
        return np.column_stack([plan, self.height_m + self.slope * along_m])

    def distance_m(self, points_m: np.ndarray) -> np.ndarray:
        """Distance of each ``(N, 3)`` point from the wire."""
        return np.hypot(*self.offsets_m(points_m))

    def chord(self, roi_radius_m: float) -> tuple[float, float] | None:
        """Where the wire enters and leaves the cylinder of ``roi_radius_m`` round the z axis, as distances
        along it from its origin; None when it misses the cylinder."""
        return _chord(self.origin_xy_m, self.direction_xy, roi_radius_m)


def tree_component(
    points_m: np.ndarray,
    trunk_xy_m: np.ndarray,
    *,
    roi_radius_m: float,
    link_m: float = 0.15,
    voxel_m: float = 0.04,
) -> np.ndarray:
    """Mask of the points that belong to the tree.

    Parameters
    ----------
    points_m
        ``(N, 3)`` candidate tree points in the world frame, inside a vertical cylinder of radius
        ``roi_radius_m`` around the z axis (ground already removed).
    trunk_xy_m
        The trunk's horizontal position.
    roi_radius_m
        The cylinder's radius.
    link_m
        Two voxels closer than this belong to the same body.
    voxel_m
        Voxel edge of the grouping.

    Returns
    -------
    numpy.ndarray
        Boolean mask over ``points_m``.
    """
    if points_m.shape[0] == 0:
        return np.zeros(0, dtype=bool)
    voxels = occupied_voxels(points_m, voxel_m)
    cells, point_cell = voxels.cells, voxels.of_point
    centres = (cells + 0.5) * voxel_m
    pairs = point_tree(centres).query_pairs(r=link_m, output_type="ndarray")
    graph = coo_matrix(
        (np.ones(pairs.shape[0], dtype=np.int8), (pairs[:, 0], pairs[:, 1])), shape=(len(cells), len(cells))
    )
    count, labels = connected_components(graph, directed=False)
    sizes = np.bincount(labels, minlength=count)
    low = centres[:, 2] < centres[:, 2].min() + _TRUNK_SEED_HEIGHT_M
    near_trunk = np.linalg.norm(centres[:, :2] - trunk_xy_m, axis=1) < _TRUNK_SEED_RADIUS_M
    trunk = np.zeros(count, dtype=bool)
    trunk[labels[low & near_trunk]] = True
    at_wall = np.zeros(count, dtype=bool)
    at_wall[labels[np.linalg.norm(centres[:, :2], axis=1) > roi_radius_m - _WALL_BAND_M]] = True
    large = sizes >= _LARGE_SHARE * len(cells)
    keep = (trunk | large | ~at_wall) & (sizes > _SPECK_VOXELS)
    keep |= trunk
    return keep[labels][point_cell.ravel()]


def find_wires(
    views_m: Sequence[np.ndarray],
    *,
    beyond_views_m: Sequence[np.ndarray] = (),
    cameras_m: Sequence[np.ndarray] | None = None,
    roi_radius_m: float,
    tolerance_m: float,
    spread_m: float,
    max_slope_deg: float,
    min_coverage: float,
) -> list[Wire]:
    """The trellis wires crossing the region of interest.

    Parameters
    ----------
    views_m
        Each view's ``(N, 3)`` points in the world frame inside the vertical cylinder of radius
        ``roi_radius_m`` round the z axis, ground removed. Thin lines are sought in each view alone: each
        view sees a wire as one line, but the views' lines stand apart by their mixed pixels (see
        :func:`wire_mask`), and two lines side by side are not thin.
    beyond_views_m
        Each view's points in the world frame beyond the cylinder's wall, clear of the floor (none when
        empty). A wire seen there on both sides of the cylinder, in line, is the first wire
        (:func:`_across_scene_wires`): it runs on from post to post, its direction and slope fixed over
        metres, where a line of leaves ends with its crown.
    cameras_m
        Each view's camera centre in the world frame. A stretch of a wire's chord counts as covered when
        something stands between it and every camera (the crown hides it there); without the cameras,
        when something lies within a neighbourhood's radius of it.
    roi_radius_m
        The cylinder's radius.
    tolerance_m
        A wire's points lie within this distance of its line (its thickness, the depth noise, the views'
        registration); also the edge of the cells the points are thinned to.
    spread_m
        How far across a wire, at its height, its mixed pixels lie (see :func:`wire_mask`); once a wire is
        found, they are not searched again.
    max_slope_deg
        A wire is level within this angle everywhere inside the cylinder (its slope and its sag).
    min_coverage
        Share of the wire's chord through the cylinder that its own points and what hides it (the crowns
        it passes through) cover; the rest is out of view or lost to dropout.

    Returns
    -------
    list[Wire]
        The wires found, the most evident first.
    """
    views = [_cell_centroids(points, tolerance_m) for points in views_m if points.shape[0] >= 2]
    if not views:
        return []
    seen_by = [i for i, points in enumerate(views_m) if points.shape[0] >= 2]
    sight = (
        None
        if cameras_m is None
        else _SightLines(
            [NearestTree(views_m[i]) for i in seen_by], [np.asarray(cameras_m[i]) for i in seen_by]
        )
    )
    cells = np.concatenate(views)
    line_cells = [_line_cells(view, tolerance_m) for view in views]
    sparse_pool = cells[np.concatenate([sparse for sparse, _, _ in line_cells])]
    thin_pool = cells[np.concatenate([thin for _, thin, _ in line_cells])]
    open_pool = cells[np.concatenate([in_open_air for _, _, in_open_air in line_cells])]
    sparse_views = [view[sparse] for view, (sparse, _, _) in zip(views, line_cells, strict=True)]
    max_slope = float(np.tan(np.radians(max_slope_deg)))

    def tried(
        pool: np.ndarray, members: np.ndarray, first: Wire | None, *, stretch: bool = False
    ) -> tuple[Wire | None, np.ndarray]:
        """The wire fitted to ``members`` of ``pool`` (parallel to ``first`` when given) if it is one, and
        the pool's points near the fitted line. A thin ``stretch`` parallel to ``first`` is fitted at its
        slope and need be seen over :data:`_WIRE_STRETCH_M` only: thin, straight, level and parallel to a
        wire over that length, it is that much of a wire as no line of leaves is."""
        wire, members = _fit_wire(
            pool,
            members,
            roi_radius_m=roi_radius_m,
            tolerance_m=tolerance_m,
            direction_xy=None if first is None else first.direction_xy,
            slope=first.slope if stretch and first is not None else None,
        )
        if wire is None:
            return None, members

        def crosses(line: Wire, seen: np.ndarray) -> bool:
            return _crosses_as_wire(
                line,
                seen,
                cells,
                roi_radius_m=roi_radius_m,
                max_slope=max_slope,
                min_coverage=min_coverage,
                first=first,
                sight=sight,
                open_span_m=_WIRE_STRETCH_M if stretch else _WIRE_OPEN_SPAN_M,
                tolerance_m=tolerance_m,
            )

        if crosses(wire, pool[members]):
            return wire, members
        # A first wire seen thin along half its chord but fitted a few degrees askew (mixed pixels at one
        # end) misses its own far stretch and covers too little of its chord to pass: turned to where the
        # views' lines run, it is judged again (2066008: the top wire fitted 3.8 degrees askew covered 70 %
        # of its chord, turned 100 %; W had come out 24 % wide with no wire found).
        if first is not None or not _spans_half_chord(wire, pool[members], roi_radius_m=roi_radius_m):
            return None, members
        turned = _turned_to_cover(wire, sparse_views, roi_radius_m=roi_radius_m, tolerance_m=tolerance_m)
        along_turned = np.hypot(*turned.offsets_m(pool)) < _WIRE_VIEW_OFFSET_M
        if crosses(turned, pool[along_turned]):
            return turned, along_turned
        return None, members

    def masked(pool: np.ndarray, wire: Wire) -> np.ndarray:
        return pool[~wire_mask(pool, [wire], tolerance_m=tolerance_m, spread_m=spread_m)]

    def first_in_cylinder(thin_pool: np.ndarray) -> tuple[Wire | None, int, np.ndarray]:
        """The first wire sought inside the cylinder alone, how many lines that tried, and the thin-line
        pool without the lines tried and rejected.

        It is sought among thin lines in any direction, the most evident first; when none is one, among
        lines in open air (a wire above a crown, or one seen through gaps in it, which dropout breaks into
        pieces too short to look thin), where it must stand free or be seen at both ends of its chord.
        """
        first: Wire | None = None
        tries = 0
        wall_to_wall = _wall_to_wall_wire(
            thin_pool,
            cells,
            roi_radius_m=roi_radius_m,
            tolerance_m=tolerance_m,
            max_slope=max_slope,
            min_coverage=min_coverage,
            sight=sight,
        )
        for in_open_air in (False, True):
            pool = open_pool if in_open_air else thin_pool
            for _ in range(_FIRST_WIRE_TRIES):
                members = _best_line(pool, tolerance_m=tolerance_m, roi_radius_m=roi_radius_m)
                if members is None:
                    break
                tries += 1
                wire, members = tried(pool, members, None)
                if wire is not None and (
                    not in_open_air
                    or _stands_free(wire, cells, roi_radius_m=roi_radius_m, tolerance_m=tolerance_m)
                    or _seen_at_both_walls(wire, pool[members], roi_radius_m=roi_radius_m)
                ):
                    first = wire
                    break
                pool = pool[~members]
            if not in_open_air:
                thin_pool = pool
            if first is not None:
                break
        # A wire seen where it enters and where it leaves the cylinder settles the trellis's direction: a
        # first wire that runs askew of it by more than the turn could correct took in leaves at the crown's
        # edge (2058003: 13 degrees askew, W 17 % wide). One parallel to it may be another wire.
        if first is not None:
            first = _turned_to_cover(first, sparse_views, roi_radius_m=roi_radius_m, tolerance_m=tolerance_m)
        if wall_to_wall is not None and (first is None or _askew(first, wall_to_wall) > _WIRE_MAX_TURN_DEG):
            first = _turned_to_cover(
                wall_to_wall, sparse_views, roi_radius_m=roi_radius_m, tolerance_m=tolerance_m
            )
        return first, tries, thin_pool

    # Wires seen beyond the cylinder on both sides of it, in line, come first: nothing else runs straight
    # and level across the scene (2082028: a line of leaves 5 degrees askew was taken for the first wire,
    # the two wires it hid were missed, and W came out 12 % wide).
    wires = _across_scene_wires(
        [_cell_centroids(points, tolerance_m) for points in beyond_views_m if points.shape[0] >= 2],
        thin_pool,
        cells,
        roi_radius_m=roi_radius_m,
        tolerance_m=tolerance_m,
        spread_m=spread_m,
        max_slope=max_slope,
        min_coverage=min_coverage,
        sight=sight,
    )
    # Every line tried counts against the search's lines; each wire found across the scene as one.
    tries = len(wires)
    if not wires:
        found, tries, thin_pool = first_in_cylinder(thin_pool)
        if found is None:
            return []
        wires = [found]
    first = wires[0]
    for known in wires:
        thin_pool, sparse_pool = masked(thin_pool, known), masked(sparse_pool, known)
    # A line of leaves through the crown, parallel to the wires, must not claim first the mixed pixels
    # round a wire seen thin only beside the crown (2049045: a line 7 cm above the top wire took its 35 cm
    # beyond the crown, and W came out 12 % wide). So the trellis's other wires are sought parallel to the
    # first: where a stretch of one is seen thin, however briefly (beside a crown that hides the rest), and
    # then also where they are seen too briefly to look thin.
    claimed = np.zeros(thin_pool.shape[0], dtype=bool)
    for stretch in _parallel_stretches(thin_pool, first, tolerance_m=tolerance_m):
        beside = None if stretch[claimed].any() else tried(thin_pool, stretch, first, stretch=True)[0]
        if beside is not None and not _apart_from(beside, wires, roi_radius_m=roi_radius_m):
            beside = None
        if beside is not None:
            wires.append(beside)
            claimed |= wire_mask(thin_pool, [beside], tolerance_m=tolerance_m, spread_m=spread_m)
            sparse_pool = masked(sparse_pool, beside)
    for _ in range(tries, _WIRE_MAX_LINES):
        members = _best_parallel_line(sparse_pool, first, tolerance_m=tolerance_m)
        if members is None:
            break
        wire, members = tried(sparse_pool, members, first)
        if wire is None or not _apart_from(wire, wires, roi_radius_m=roi_radius_m):
            sparse_pool = sparse_pool[~members]
        else:
            wires.append(wire)
            sparse_pool = masked(sparse_pool, wire)
    return wires


def is_wire_piece(points_m: np.ndarray, *, min_length_m: float, max_thickness_m: float) -> bool:
    """Whether the ``(N, 3)`` points of a small body lie along a straight, nearly level line at least
    ``min_length_m`` long in plan, within ``max_thickness_m`` (RMS) of it in height: a stretch of trellis
    wire seen apart from the rest (beside a crown, between gaps of dropout), which :func:`find_wires` may
    miss when too little of the wire shows.

    The line's direction is the points' main horizontal direction; the height is fitted along it, sloping at
    most :data:`_SEEN_WIRE_MAX_SLOPE_DEG`. Across the line in plan the points may spread as a wire's mixed
    pixels do; a leaf or a cluster of leaves is shorter, or not level.
    """
    if points_m.shape[0] < 3:
        return False
    plan = points_m[:, :2] - points_m[:, :2].mean(axis=0)
    direction = np.linalg.svd(plan, full_matrices=False)[2][0]
    along = plan @ direction
    if np.ptp(along) < min_length_m:
        return False
    slope, height = np.polyfit(along, points_m[:, 2], 1)
    rise = points_m[:, 2] - (height + slope * along)
    return bool(
        abs(slope) <= np.tan(np.radians(_SEEN_WIRE_MAX_SLOPE_DEG))
        and np.sqrt(np.mean(rise**2)) <= max_thickness_m
    )


def wire_mask(
    points_m: np.ndarray,
    wires: list[Wire],
    *,
    tolerance_m: float,
    spread_m: float,
    camera_m: np.ndarray | None = None,
) -> np.ndarray:
    """Mask of the ``(N, 3)`` points of any of ``wires``: within ``tolerance_m`` of the plane through it and
    the camera at ``camera_m`` (world frame) that saw the points, and within ``spread_m`` across it in plan
    or anywhere behind it as that camera sees it; without a camera, within ``tolerance_m`` of its height and
    ``spread_m`` across it.

    A wire is thinner than a depth pixel, so every pixel that sees it blends its depth with what lies
    behind: its points stand off the wire along the camera's rays through it, in the plane that holds the
    wire and the camera's centre, each view's the other way, as far behind the wire as the background
    (the far side of the region of interest, or beyond). A camera at the wire's height sees that plane
    level; one 1.2 m high looking at a wire 2.5 m high 3 m away sees it sloping by 23 degrees, and a mixed
    pixel 30 cm behind the wire stands 12 cm below its height.
    """
    on_wire = np.zeros(points_m.shape[0], dtype=bool)
    for wire in wires:
        across, rise = wire.offsets_m(points_m)
        if camera_m is None:
            on_wire |= (np.abs(rise) < tolerance_m) & (np.abs(across) < spread_m)
            continue
        camera_across = wire.offsets_m(np.asarray(camera_m, dtype=float)[None, :])[0][0]
        behind = across * np.sign(camera_across) < 0.0
        near = np.abs(_off_sight_plane(wire, points_m, camera_m)) < tolerance_m
        on_wire |= near & ((np.abs(across) < spread_m) | behind)
    return on_wire


def _off_sight_plane(wire: Wire, points_m: np.ndarray, camera_m: np.ndarray) -> np.ndarray:
    """Signed distance of each point from the plane holding ``wire`` and the camera centre ``camera_m``;
    the height above the wire when the camera lies on the wire's line (no such plane)."""
    direction = np.append(wire.direction_xy, wire.slope)
    origin = np.append(wire.origin_xy_m, wire.height_m)
    normal = np.cross(direction, origin - camera_m)
    length = float(np.linalg.norm(normal))
    if length < 1e-9:
        return wire.offsets_m(points_m)[1]
    normal /= length
    normal *= np.sign(normal[2]) or 1.0
    return (points_m - origin) @ normal


@dataclass(frozen=True, eq=False)
class _SightLines:
    """Each view's points (indexed) and camera centre: what stands between a camera and a place."""

    trees: list[NearestTree]
    cameras_m: list[np.ndarray]

    def hidden(self, places_m: np.ndarray) -> np.ndarray:
        """Whether each of ``(N, 3)`` places is hidden from every camera: some point of that camera's view
        lies within ``_SIGHT_RADIUS_M`` of the line of sight, between the camera and ``_SIGHT_CLEARANCE_M``
        short of the place. A wire is not seen where the crown stands in front of it, from every side."""
        hidden = np.ones(places_m.shape[0], dtype=bool)
        for tree, camera in zip(self.trees, self.cameras_m, strict=True):
            rays = places_m - camera
            lengths = np.linalg.norm(rays, axis=1)
            steps = np.arange(_SIGHT_STEP_M, float(lengths.max()), _SIGHT_STEP_M)
            inside = steps[None, :] < (lengths - _SIGHT_CLEARANCE_M)[:, None]
            samples = camera + (steps[None, :, None] / lengths[:, None, None]) * rays[:, None, :]
            # The nearest point alone tells whether any lies within reach: a bounded search stops early.
            nearest, _ = tree.query(
                samples[inside], distance_upper_bound=np.nextafter(_SIGHT_RADIUS_M, np.inf)
            )
            near = nearest <= _SIGHT_RADIUS_M
            blocked = np.zeros(inside.shape, dtype=bool)
            blocked[inside] = near
            hidden &= blocked.any(axis=1)
        return hidden


def _chord(origin_xy: np.ndarray, direction_xy: np.ndarray, radius_m: float) -> tuple[float, float] | None:
    """Where the level line through ``origin_xy`` along unit ``direction_xy`` enters and leaves the
    cylinder of ``radius_m`` round the z axis (distances along it from ``origin_xy``); None if it misses."""
    offset = float(origin_xy @ np.array([-direction_xy[1], direction_xy[0]]))
    if abs(offset) >= radius_m:
        return None
    middle = -float(origin_xy @ direction_xy)
    half = float(np.sqrt(radius_m**2 - offset**2))
    return middle - half, middle + half


def _cell_centroids(points_m: np.ndarray, cell_m: float) -> np.ndarray:
    """The centroids of the points in each occupied cubic cell of edge ``cell_m``."""
    keys = np.floor(points_m / cell_m).astype(np.int64)
    keys -= keys.min(axis=0)
    span = keys.max(axis=0) + 1
    flat = (keys[:, 0] * span[1] + keys[:, 1]) * span[2] + keys[:, 2]
    _, cell, counts = np.unique(flat, return_inverse=True, return_counts=True)
    cell = cell.ravel()
    sums = np.column_stack(
        [np.bincount(cell, weights=points_m[:, k], minlength=counts.size) for k in range(3)]
    )
    return sums / counts[:, None]


def _line_cells(cells_m: np.ndarray, tolerance_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Masks of the sparse cells, whose neighbourhood holds no more cells than a line's; among them of the
    thin-line cells, whose neighbourhood is a thin straight line: spread along one direction over at
    least the neighbourhood's radius and across it by less than half the tolerance; and of the cells in
    open air, whose neighbourhood holds no more than one line crossing it would, whatever their shape
    (a wire far from everything, broken by dropout into pieces of a cell or two).

    Cells have an edge of ``tolerance_m``, so a line crosses at most ``2 r / tolerance_m + 1`` cells of a
    neighbourhood of radius r; twice as many allows for a noisy line's straddling cell boundaries. A
    neighbourhood holding more is part of a surface or a volume.
    """
    radius = _WIRE_NEIGHBOURHOOD_M
    line = int(np.ceil(2 * radius / tolerance_m + 1))
    most = 2 * line
    distances, neighbours = NearestTree(cells_m).query(cells_m, k=most + 1, distance_upper_bound=radius)
    found = np.isfinite(distances)
    count = found.sum(axis=1)
    sparse = count <= most
    in_open_air = count <= line
    examined = np.flatnonzero(sparse & (count >= 3))
    found = found[examined]
    padded = np.vstack([cells_m, np.zeros((1, 3))])
    around = padded[np.where(found, neighbours[examined], cells_m.shape[0])]
    weight = found[..., None].astype(float)
    mean = (around * weight).sum(axis=1) / count[examined, None]
    deviation = (around - mean[:, None, :]) * weight
    variances = np.linalg.eigvalsh(
        np.einsum("cki,ckj->cij", deviation, deviation) / count[examined, None, None]
    )
    thin = np.zeros(cells_m.shape[0], dtype=bool)
    # Across: within half the tolerance. Along: a line through the neighbourhood's centre at least its
    # radius long (a uniform spread over a length L has variance L^2 / 12).
    thin[examined] = (variances[:, 1] <= (tolerance_m / 2) ** 2) & (variances[:, 2] >= radius**2 / 12)
    return sparse, thin, in_open_air


def _best_line(pool_m: np.ndarray, *, tolerance_m: float, roi_radius_m: float) -> np.ndarray | None:
    """Mask over ``pool_m`` of the points of the best level line in any direction: a Hough transform over
    the lines' direction in plan (in steps that turn a line by at most ``tolerance_m`` within the cylinder
    of ``roi_radius_m``), offset and height (in steps of ``tolerance_m``), each line scored by the length
    it covers (stretches of :data:`_WIRE_BIN_M` holding a point); None when no line covers
    :data:`_WIRE_OPEN_SPAN_M`. Every wire of a trellis votes for the same direction."""
    if pool_m.shape[0] == 0:
        return None
    angles = np.arange(0.0, np.pi, tolerance_m / roi_radius_m)
    directions = np.column_stack([np.cos(angles), np.sin(angles)])
    along = pool_m[:, :2] @ directions.T
    across = pool_m[:, :2] @ np.column_stack([-directions[:, 1], directions[:, 0]]).T
    line = np.stack(
        [
            np.broadcast_to(np.arange(angles.size), along.shape),
            np.floor(across / tolerance_m).astype(np.int64),
            np.broadcast_to(np.floor(pool_m[:, 2:] / tolerance_m).astype(np.int64), along.shape),
        ]
    ).reshape(3, -1)
    line_key = np.ravel_multi_index(
        tuple(line - line.min(axis=1, keepdims=True)), tuple(np.ptp(line, axis=1) + 1)
    )
    best_key, covered_m = _best_covered_line(line_key, along.ravel())
    if covered_m < _WIRE_OPEN_SPAN_M:
        return None
    chosen = np.flatnonzero(line_key == best_key)
    angle = int(chosen[0] % angles.size)
    points = chosen // angles.size
    direction = np.append(directions[angle], 0.0)
    centre = pool_m[points].mean(axis=0)
    offset = pool_m - centre
    return np.linalg.norm(offset - np.outer(offset @ direction, direction), axis=1) < tolerance_m


def _best_parallel_line(
    pool_m: np.ndarray, parallel_to: Wire, *, tolerance_m: float, shortest_m: float = _WIRE_OPEN_SPAN_M
) -> np.ndarray | None:
    """Mask over ``pool_m`` of the points of the best line parallel to ``parallel_to`` (in plan and in
    slope): a Hough transform over the lines' offset across it and height, in steps of ``tolerance_m``,
    each scored by the length it covers (stretches of :data:`_WIRE_BIN_M` holding a point); None when no
    line covers ``shortest_m``."""
    if pool_m.shape[0] == 0:
        return None
    across, rise = parallel_to.offsets_m(pool_m)
    along = (pool_m[:, :2] - parallel_to.origin_xy_m) @ parallel_to.direction_xy
    line = np.floor(np.column_stack([across, rise]) / tolerance_m).astype(np.int64)
    line -= line.min(axis=0)
    line_key = line[:, 0] * (int(line[:, 1].max()) + 1) + line[:, 1]
    best_key, covered_m = _best_covered_line(line_key, along)
    if covered_m < shortest_m:
        return None
    chosen = line_key == best_key
    centre = np.array([np.mean(across[chosen]), np.mean(rise[chosen])])
    return np.hypot(across - centre[0], rise - centre[1]) < tolerance_m


def _best_covered_line(line_key: np.ndarray, along_m: np.ndarray) -> tuple[int, float]:
    """The Hough transforms' vote: of the lines ``line_key`` (one non-negative integer per point and line,
    the point's position ``along_m`` it), the one that covers most length (stretches of
    :data:`_WIRE_BIN_M` holding a point), the lowest key among equals; and that length in metres."""
    stretch = np.floor(along_m / _WIRE_BIN_M).astype(np.int64)
    first = stretch.min()
    stretches = int(stretch.max() - first) + 1
    # The stretches each line covers, as one sorted list of (line, stretch) keys: each line's in a run.
    # (Its runs found by hand: run by the wire search's turns thousands of times on a few hundred points,
    # numpy.diff's prepend and append cost more than the rest.)
    covered_lines = _distinct(line_key * stretches + (stretch - first)) // stretches
    run_starts = np.empty(covered_lines.size, dtype=bool)
    run_starts[0] = True
    np.not_equal(covered_lines[1:], covered_lines[:-1], out=run_starts[1:])
    starts = np.flatnonzero(run_starts)
    ends = np.empty_like(starts)
    ends[:-1] = starts[1:]
    ends[-1] = covered_lines.size
    score = ends - starts
    best = int(np.argmax(score))
    return int(covered_lines[starts[best]]), float(score[best] * _WIRE_BIN_M)


def _distinct(values: np.ndarray) -> np.ndarray:
    """The distinct ``values``, sorted. By a sort, not ``numpy.unique``: for values alone NumPy (2.3 on) goes
    through a hash table, five to ten times slower on the Hough transform's hundreds of thousands of mostly
    distinct keys."""
    ordered = np.sort(values, axis=None)
    if ordered.size == 0:
        return ordered
    return ordered[np.concatenate(([True], ordered[1:] != ordered[:-1]))]


def _straight_stretches(pool_m: np.ndarray, *, tolerance_m: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """The chains of ``pool_m`` (thin-line cells joined within :data:`_WIRE_NEIGHBOURHOOD_M`) that run
    straight and level (:func:`is_wire_piece`) over at least :data:`_WIRE_STRETCH_M`, longest first: each
    one's mask over the pool and its direction in plan.

    A wire that the crown hides along most of its chord shows only a short stretch on either side of it:
    too little for the Hough transform to rank above the lines that leaves at the crown's edge form by
    chance, but as long and as thin as no leaf is.
    """
    if pool_m.shape[0] < 3:
        return []
    pairs = point_tree(pool_m).query_pairs(_WIRE_NEIGHBOURHOOD_M, output_type="ndarray")
    graph = coo_matrix(
        (np.ones(pairs.shape[0], dtype=np.int8), (pairs[:, 0], pairs[:, 1])), shape=(len(pool_m),) * 2
    )
    count, labels = connected_components(graph, directed=False)
    stretches: list[tuple[float, np.ndarray, np.ndarray]] = []
    for chain in np.flatnonzero(np.bincount(labels, minlength=count) >= 3):
        members = labels == chain
        points = pool_m[members]
        if not is_wire_piece(points, min_length_m=_WIRE_STRETCH_M, max_thickness_m=tolerance_m / 2):
            continue
        plan = points[:, :2] - points[:, :2].mean(axis=0)
        direction = np.linalg.svd(plan, full_matrices=False)[2][0]
        stretches.append((float(np.ptp(plan @ direction)), members, direction))
    return [(members, direction) for _, members, direction in sorted(stretches, key=lambda item: -item[0])]


def _parallel_stretches(pool_m: np.ndarray, parallel_to: Wire, *, tolerance_m: float) -> list[np.ndarray]:
    """Masks over ``pool_m`` of its straight stretches (:func:`_straight_stretches`) that run within
    :data:`_WIRE_STRETCH_MAX_TURN_DEG` of ``parallel_to``; longest first."""
    cosine = np.cos(np.radians(_WIRE_STRETCH_MAX_TURN_DEG))
    return [
        members
        for members, direction in _straight_stretches(pool_m, tolerance_m=tolerance_m)
        if abs(float(direction @ parallel_to.direction_xy)) >= cosine
    ]


def _wall_to_wall_lines(
    pool_m: np.ndarray, *, roi_radius_m: float, tolerance_m: float, max_slope: float
) -> list[np.ndarray]:
    """Masks over ``pool_m`` (thin-line cells) of pairs of straight stretches (:func:`_straight_stretches`)
    that lie on one level line through the cylinder of ``roi_radius_m``, each near an end of its chord: a
    wire through a crown seen where it enters and where it leaves, the crown hiding the rest. Each
    stretch runs within :data:`_WIRE_STRETCH_MAX_TURN_DEG` of the line joining them, they stand at least a
    radius apart, and their heights differ by no more than the line's slope allows. Longest pair first.

    The Hough transform's best line through such a wire may take in leaves at the crown's edge with one of
    its stretches and miss the other by tens of centimetres (2058003: 13 degrees askew, W 17 % wide).
    """
    stretches = _straight_stretches(pool_m, tolerance_m=tolerance_m)
    cosine = np.cos(np.radians(_WIRE_STRETCH_MAX_TURN_DEG))
    centres = [pool_m[members].mean(axis=0) for members, _ in stretches]
    pairs: list[tuple[float, np.ndarray]] = []
    for (i, (first, first_direction)), (j, (second, second_direction)) in itertools.combinations(
        enumerate(stretches), 2
    ):
        joining = centres[j][:2] - centres[i][:2]
        apart = float(np.linalg.norm(joining))
        if apart < roi_radius_m:
            continue
        along = joining / apart
        if min(abs(float(first_direction @ along)), abs(float(second_direction @ along))) < cosine:
            continue
        if abs(centres[j][2] - centres[i][2]) > max_slope * apart + tolerance_m:
            continue
        line = Wire(centres[i][:2], along, float(centres[i][2]), 0.0)
        if _seen_at_both_walls(line, pool_m[first | second], roi_radius_m=roi_radius_m):
            pairs.append((apart, first | second))
    return [members for _, members in sorted(pairs, key=lambda item: -item[0])]


def _wall_to_wall_wire(
    pool_m: np.ndarray,
    cells_m: np.ndarray,
    *,
    roi_radius_m: float,
    tolerance_m: float,
    max_slope: float,
    min_coverage: float,
    sight: _SightLines | None,
) -> Wire | None:
    """The wire through the first of the pool's wall-to-wall pairs of stretches (:func:`_wall_to_wall_lines`,
    at most :data:`_FIRST_WIRE_TRIES` tried) that crosses as a wire (:func:`_crosses_as_wire`); None when
    none does. Each view's line of a wire stands off it by that view's mixed
    pixels, so what counts as seen is what lies within :data:`_WIRE_VIEW_OFFSET_M` of the fit (a
    tolerance's width would keep one side)."""
    for pair in _wall_to_wall_lines(
        pool_m, roi_radius_m=roi_radius_m, tolerance_m=tolerance_m, max_slope=max_slope
    )[:_FIRST_WIRE_TRIES]:
        wire, _ = _fit_wire(
            pool_m, pair, roi_radius_m=roi_radius_m, tolerance_m=tolerance_m, direction_xy=None
        )
        if wire is None:
            continue
        stretches = pool_m[pair]
        seen = stretches[wire.distance_m(stretches) < _WIRE_VIEW_OFFSET_M]
        if _crosses_as_wire(
            wire,
            seen,
            cells_m,
            roi_radius_m=roi_radius_m,
            max_slope=max_slope,
            min_coverage=min_coverage,
            first=None,
            sight=sight,
            tolerance_m=tolerance_m,
        ):
            return wire
    return None


def _across_scene_wires(
    beyond_views_m: Sequence[np.ndarray],
    thin_pool_m: np.ndarray,
    cells_m: np.ndarray,
    *,
    roi_radius_m: float,
    tolerance_m: float,
    spread_m: float,
    max_slope: float,
    min_coverage: float,
    sight: _SightLines | None,
) -> list[Wire]:
    """The wires seen beyond the cylinder on both sides of it, in line, that cross the cylinder as wires
    (:func:`_crosses_as_wire`), the most seen first; none when there is no such wire.

    ``beyond_views_m`` holds each view's cells beyond the cylinder's wall; ``thin_pool_m`` the thin-line
    cells inside it. Beyond the wall, between the crown and the neighbours, a wire shows as straight,
    level stretches of thin-line cells (:func:`_straight_stretches`) on either side of the tree; two such
    stretches whose joining line runs through the cylinder, each within
    :data:`_WIRE_STRETCH_MAX_TURN_DEG` of that line and rising along it by at most ``max_slope``, may be one
    line strung across the scene: a wire's, whose direction and slope they fix over metres. Leaves and
    twigs line up by chance over decimetres, inside one crown.

    A stretch of one wire and one of another, a few decimetres higher, pair too, at a slope that a tilted
    floor may make plausible (2082028: two wires 0.4 m apart sloping 2.9 degrees paired at 2.8 degrees the
    other way). So each pair (at most :data:`_SCENE_PAIRS_TRIED`, the longest stretches first) is fitted
    (:func:`_fit_wire`) to the thin-line cells inside and beyond the cylinder, and the fits are tried in
    order of the length they cover (stretches of :data:`_WIRE_BIN_M` holding a point within ``tolerance_m``):
    a wire's fit covers its stretches end to end, a mismatched pair's crosses them. A fit is judged as a
    first wire is (:func:`_crosses_as_wire`, no wire given), on what lies within :data:`_WIRE_VIEW_OFFSET_M`
    of it inside and beyond the cylinder: seen from wall to wall and beyond, it is seen over the open
    span, and a line that stands free inside the cylinder need be seen along only a fifth of its chord
    there. Once one is a wire, its points (within ``spread_m`` across it) leave the search, and the next is
    sought parallel to it, sloping within ``max_slope`` of it and apart from every wire found
    (:func:`_apart_from`: closer, it is one's mixed pixels).
    """
    if not beyond_views_m:
        return []
    beyond = np.concatenate([view[_line_cells(view, tolerance_m)[1]] for view in beyond_views_m])
    pool = np.concatenate([beyond, thin_pool_m])
    is_beyond = np.arange(pool.shape[0]) < beyond.shape[0]
    cosine = np.cos(np.radians(_WIRE_STRETCH_MAX_TURN_DEG))
    wires: list[Wire] = []
    while len(wires) < _WIRE_MAX_LINES:
        stretches = _straight_stretches(pool[is_beyond], tolerance_m=tolerance_m)
        on_beyond = np.flatnonzero(is_beyond)
        centres = [pool[on_beyond[members]].mean(axis=0) for members, _ in stretches]
        lengths = [float(np.ptp(pool[on_beyond[members], :2] @ along)) for members, along in stretches]
        pairs: list[tuple[float, int, int]] = []
        for (i, (_, first_direction)), (j, (_, second_direction)) in itertools.combinations(
            enumerate(stretches), 2
        ):
            joining = centres[j] - centres[i]
            apart = float(np.linalg.norm(joining[:2]))
            along = joining[:2] / apart
            line = Wire(centres[i][:2], along, float(centres[i][2]), float(joining[2]) / apart)
            chord = line.chord(roi_radius_m)
            if chord is None or chord[0] < 0.0 or chord[1] > apart or abs(line.slope) > max_slope:
                continue
            if min(abs(float(first_direction @ along)), abs(float(second_direction @ along))) < cosine:
                continue
            if wires and (
                _askew(line, wires[0]) > _WIRE_STRETCH_MAX_TURN_DEG
                or abs(line.slope * float(along @ wires[0].direction_xy) - wires[0].slope) > max_slope
            ):
                continue
            pairs.append((lengths[i] + lengths[j], i, j))
        fitted: list[tuple[int, Wire]] = []
        for _, i, j in sorted(pairs, key=lambda item: -item[0])[:_SCENE_PAIRS_TRIED]:
            pair = np.zeros(pool.shape[0], dtype=bool)
            pair[on_beyond[stretches[i][0] | stretches[j][0]]] = True
            wire, near = _fit_wire(
                pool,
                pair,
                roi_radius_m=roi_radius_m,
                tolerance_m=tolerance_m,
                direction_xy=wires[0].direction_xy if wires else None,
            )
            if wire is not None:
                along_fit = (pool[near, :2] - wire.origin_xy_m) @ wire.direction_xy
                fitted.append((_distinct(np.floor(along_fit / _WIRE_BIN_M)).size, wire))
        crossing = next(
            (
                wire
                for _, wire in sorted(fitted, key=lambda item: -item[0])
                if (not wires or abs(wire.slope - wires[0].slope) <= max_slope)
                and _apart_from(wire, wires, roi_radius_m=roi_radius_m)
                and _crosses_as_wire(
                    wire,
                    pool[wire.distance_m(pool) < _WIRE_VIEW_OFFSET_M],
                    cells_m,
                    roi_radius_m=roi_radius_m,
                    max_slope=max_slope,
                    min_coverage=min_coverage,
                    first=None,
                    sight=sight,
                    tolerance_m=tolerance_m,
                )
            ),
            None,
        )
        if crossing is None:
            break
        wires.append(crossing)
        kept = ~wire_mask(pool, [crossing], tolerance_m=tolerance_m, spread_m=spread_m)
        pool, is_beyond = pool[kept], is_beyond[kept]
    return wires


def _apart_from(line: Wire, wires: Sequence[Wire], *, roi_radius_m: float) -> bool:
    """Whether ``line`` stays more than :data:`_WIRE_VIEW_OFFSET_M` from each of ``wires`` all along its chord
    through the cylinder of ``roi_radius_m``: closer, it is one of those wires' lines of mixed pixels, which
    a coarse sensor's wide pixels spread farther than the search masks, not another wire: a trellis strings
    its wires decimetres apart. Taken for a wire, such a line takes crown with it (binned Azure Kinect
    2083003: a line 6 cm below the lower wire, with 14 mm pixels, took the crown's base, D 6.7 % low)."""
    chord = line.chord(roi_radius_m)
    if chord is None:
        return True
    on_line = line.at(np.linspace(chord[0], chord[1], int(np.ceil((chord[1] - chord[0]) / _WIRE_BIN_M)) + 1))
    return all(float(wire.distance_m(on_line).min()) > _WIRE_VIEW_OFFSET_M for wire in wires)


def _askew(wire: Wire, other: Wire) -> float:
    """The angle in plan between two wires' lines, degrees (0-90)."""
    return float(np.degrees(np.arccos(min(1.0, abs(float(wire.direction_xy @ other.direction_xy))))))


def _fit_wire(
    pool_m: np.ndarray,
    members: np.ndarray,
    *,
    roi_radius_m: float,
    tolerance_m: float,
    direction_xy: np.ndarray | None,
    slope: float | None = None,
) -> tuple[Wire | None, np.ndarray]:
    """A wire fitted to the ``members`` of ``pool_m`` (along ``direction_xy`` and at ``slope`` when given:
    a stretch of a few decimetres fixes no slope, and the trellis's wires slope alike), then refitted to
    the pool's points within :data:`_WIRE_FIT_REACH` tolerances of it, each weighted down by its distance
    (a Cauchy weight of scale ``tolerance_m``); and the pool's points within ``tolerance_m`` of the result.
    None when fewer than three points remain or the line misses the cylinder.

    The first fit sees the wire where the Hough line found it, often one side of the crown: its slope,
    extrapolated across the chord, misses the wire's far side by a few centimetres. Reaching a little
    farther each round takes in that side, and the weights keep leaves beside the wire from pulling it.
    """
    wire = None
    weights = members.astype(float)
    for _ in range(_WIRE_FIT_ROUNDS):
        used = weights > 0
        points, weight = pool_m[used], weights[used]
        if points.shape[0] < 3:
            return None, members
        origin = np.average(points[:, :2], axis=0, weights=weight)
        direction = (
            direction_xy
            if direction_xy is not None
            else np.linalg.svd((points[:, :2] - origin) * np.sqrt(weight)[:, None], full_matrices=False)[2][0]
        )
        if _chord(origin, direction, roi_radius_m) is None:
            return None, members
        along = (points[:, :2] - origin) @ direction
        if slope is None:
            rise, height = np.polyfit(along, points[:, 2], 1, w=np.sqrt(weight))
        else:
            rise, height = slope, np.average(points[:, 2] - slope * along, weights=weight)
        wire = Wire(origin, direction, float(height), float(rise))
        distance = wire.distance_m(pool_m)
        weights = np.where(
            distance < _WIRE_FIT_REACH * tolerance_m, 1.0 / (1.0 + (distance / tolerance_m) ** 2), 0.0
        )
    assert wire is not None
    return wire, wire.distance_m(pool_m) < tolerance_m


def _turned_to_cover(
    wire: Wire, views_m: Sequence[np.ndarray], *, roi_radius_m: float, tolerance_m: float
) -> Wire:
    """``wire`` turned about its origin, in plan and in slope by at most :data:`_WIRE_MAX_TURN_DEG` each, to
    the direction along which each view sees a line that covers the most of the wire's chord through the
    cylinder of ``roi_radius_m``, then fitted again along that direction (:func:`_fit_wire`) to the
    points of those lines; of directions covering as much, the least turned.

    ``views_m`` holds each view's points that may be a wire's (sparse cells). A view sees a wire as a line
    that stands off it by that view's mixed pixels, up to :data:`_WIRE_VIEW_OFFSET_M`: two views' lines of
    one wire, centimetres apart, are two lines, and a line fitted through one view's on one side of the
    crown and the other's on the other side is turned by degrees. So each view's best line parallel to a
    direction is sought on its own (:func:`_best_parallel_line`, scored by the stretches of
    :data:`_WIRE_BIN_M` it covers) and the views' cover is summed. The trellis's other wires are then sought
    parallel to the turned wire; a degree off, they are 2.5 cm off the search's lines at the cylinder's
    wall.
    """
    step = tolerance_m / roi_radius_m / 2
    turns = np.arange(-np.radians(_WIRE_MAX_TURN_DEG), np.radians(_WIRE_MAX_TURN_DEG) + step / 2, step)
    turns = turns[np.argsort(np.abs(turns), kind="stable")]
    base = float(np.arctan2(wire.direction_xy[1], wire.direction_xy[0]))
    near = [points[_within_turning_reach(wire, points)] for points in views_m]
    best: tuple[int, Wire | None, list[np.ndarray]] = (0, None, [])
    for turn in turns:
        direction = np.array([np.cos(base + turn), np.sin(base + turn)])
        chord = _chord(wire.origin_xy_m, direction, roi_radius_m)
        if chord is None:
            continue
        for tilt in turns:
            slope = float(np.tan(np.arctan(wire.slope) + tilt))
            turned = Wire(wire.origin_xy_m, direction, wire.height_m, slope)
            # A view's best line covers no stretch of the chord that none of its points near the turned
            # wire holds: once what is covered and what the views left could cover is no more than the best
            # so far, this turn and tilt is given up, its remaining views' lines unsought (they are most of
            # the search's time; a tie would not replace the best anyway).
            nearby, bounds = [], []
            for points in near:
                across, rise = turned.offsets_m(points)
                close = points[np.hypot(across, rise) < _WIRE_VIEW_OFFSET_M]
                along = (close[:, :2] - wire.origin_xy_m) @ direction
                nearby.append((close, along))
                bounds.append(int(np.count_nonzero(_stretches_holding(along, *chord))))
            covered, lines = 0, []
            for view, (close, along) in enumerate(nearby):
                if covered + sum(bounds[view:]) <= best[0]:
                    break
                line = _best_parallel_line(close, turned, tolerance_m=tolerance_m, shortest_m=0.0)
                if line is None:
                    continue
                covered += int(np.count_nonzero(_stretches_holding(along[line], *chord)))
                lines.append(close[line])
            if covered > best[0]:
                best = (covered, turned, lines)
    _, along_views, lines = best
    if along_views is None:
        return wire
    seen = np.concatenate(lines)
    refitted, _ = _fit_wire(
        seen,
        np.ones(seen.shape[0], dtype=bool),
        roi_radius_m=roi_radius_m,
        tolerance_m=_WIRE_VIEW_OFFSET_M,
        direction_xy=along_views.direction_xy,
    )
    return refitted or along_views


def _within_turning_reach(wire: Wire, points_m: np.ndarray) -> np.ndarray:
    """Mask of the ``(N, 3)`` points that a view's line of ``wire`` turned about its origin by up to
    :data:`_WIRE_MAX_TURN_DEG` in plan and in slope may hold: within twice :data:`_WIRE_VIEW_OFFSET_M` of
    it, plus what the turn moves the line at their distance along it. A fixed reach left out the far side
    of a wire fitted 5 degrees askew on one side of the crown (2036041: 2.4 m from the origin, 22 cm off),
    and the turn then covered less along the right direction than along a wrong one."""
    along = (points_m[:, :2] - wire.origin_xy_m) @ wire.direction_xy
    reach = 2 * _WIRE_VIEW_OFFSET_M + np.abs(along) * np.tan(np.radians(_WIRE_MAX_TURN_DEG))
    return wire.distance_m(points_m) < reach


def _seen_at_both_walls(wire: Wire, seen_m: np.ndarray, *, roi_radius_m: float) -> bool:
    """Whether ``wire``'s points ``seen_m`` lie within :data:`_WIRE_WALL_M` of both ends of its chord through
    the cylinder of ``roi_radius_m``: it enters and leaves the cylinder through its wall, as a wire does and
    leaves lining up by chance do not (none of the candidate lines of 109 simulated captures did, nor any of
    the lines in open air of 60 more, 96 of them no wire's)."""
    chord = wire.chord(roi_radius_m)
    if chord is None:
        return False
    seen = _stretches_holding((seen_m[:, :2] - wire.origin_xy_m) @ wire.direction_xy, *chord)
    at_wall = int(np.ceil(_WIRE_WALL_M / _WIRE_BIN_M))
    return bool(seen[:at_wall].any() and seen[-at_wall:].any())


def _stands_free(wire: Wire, cells_m: np.ndarray, *, roi_radius_m: float, tolerance_m: float) -> bool:
    """Whether ``wire`` stands in open air across the cylinder of ``roi_radius_m``: of every view's cells
    (``cells_m``) within :data:`_WIRE_NEIGHBOURHOOD_M` of it along its chord, at least
    :data:`_FREE_STANDING_SHARE` lie within ``tolerance_m`` of it. A wire above a crown, against the sky,
    has nothing round it; a line of leaves has the rest of the crown."""
    chord = wire.chord(roi_radius_m)
    if chord is None:
        return False
    along = (cells_m[:, :2] - wire.origin_xy_m) @ wire.direction_xy
    distance = wire.distance_m(cells_m)[(along >= chord[0]) & (along <= chord[1])]
    near = np.count_nonzero(distance < _WIRE_NEIGHBOURHOOD_M)
    return bool(near and np.count_nonzero(distance < tolerance_m) >= _FREE_STANDING_SHARE * near)


def _spans_half_chord(wire: Wire, seen_m: np.ndarray, *, roi_radius_m: float) -> bool:
    """Whether the ``(N, 3)`` points seen of ``wire`` spread along at least :data:`_WIRE_SEEN_ALONE` of its
    chord through the cylinder of ``roi_radius_m``: more of a line than a crown's leaves line up along."""
    chord = wire.chord(roi_radius_m)
    if chord is None or seen_m.shape[0] == 0:
        return False
    along = (seen_m[:, :2] - wire.origin_xy_m) @ wire.direction_xy
    return bool(np.ptp(along) >= _WIRE_SEEN_ALONE * (chord[1] - chord[0]))


def _crosses_as_wire(
    wire: Wire,
    seen_m: np.ndarray,
    cells_m: np.ndarray,
    *,
    roi_radius_m: float,
    max_slope: float,
    min_coverage: float,
    first: Wire | None,
    sight: _SightLines | None = None,
    open_span_m: float = _WIRE_OPEN_SPAN_M,
    tolerance_m: float,
) -> bool:
    """Whether ``wire`` is one: seen (``seen_m``, its points in the search pool) over ``open_span_m``
    (:data:`_WIRE_OPEN_SPAN_M`, or less for a thin stretch already judged a wire's), and either seen in
    :data:`_WIRE_SEEN_ALONE` of its chord through the cylinder (sloping at most
    :data:`_SEEN_WIRE_MAX_SLOPE_DEG`), or crossing the cylinder level within
    ``max_slope``; a wire sought parallel to the ``first`` one found, within ``max_slope`` of that one's
    slope: the trellis's wires are strung between the same posts, so they slope alike in the ground frame,
    which follows the floor around the tree and may tilt by degrees against the row's level (an
    undulating floor, a wire strung along the row's grade).

    It crosses when it covers ``min_coverage`` of its chord: the stretch between the farthest points where
    it is seen (within it, a crown may hide it from every view: an open vase's shell hides its hollow
    centre), and beyond them the stretches where something lies along it, within the neighbourhood radius:
    the crown or a neighbour hiding it. What is left may be out of the cameras' view (a wire above a tall
    crown) or lost to dropout. The first wire, sought in any direction, must also be seen where it crosses
    the cylinder's wall, within :data:`_WIRE_WALL_M` of both ends of its chord, or in
    :data:`_FIRST_WIRE_SEEN` of its chord; wires sought parallel to it need not.

    A level line that stands free (:func:`_stands_free`, ``tolerance_m`` its thickness) crosses without
    covering as much: seen in :data:`_FIRST_WIRE_SEEN` of its chord, between sightings at least
    :data:`_WIRE_SEEN_ALONE` of it apart, or, parallel to the ``first`` wire (whose direction and slope
    it follows: no chance line of specks does), anywhere along it. Against the sky nothing hides a wire,
    dropout takes most of it, and above a tall crown much of it is out of every camera's view (2051046:
    a top wire 0.5 m above the crown, seen in two stretches over 63 % of its chord; 2060057: 0.6 m above
    it, seen by one view along 35 %).
    """
    chord = wire.chord(roi_radius_m)
    if chord is None:
        return False
    start, end = chord
    seen = (seen_m[:, :2] - wire.origin_xy_m) @ wire.direction_xy
    seen_stretches = _stretches_holding(seen, start, end)
    if np.ptp(seen) < open_span_m:
        return False
    if seen_stretches.mean() >= _WIRE_SEEN_ALONE:
        return abs(wire.slope) <= np.tan(np.radians(_SEEN_WIRE_MAX_SLOPE_DEG))
    if abs(wire.slope - (0.0 if first is None else first.slope)) > max_slope:
        return False
    if (
        (first is not None or np.ptp(seen) >= _WIRE_SEEN_ALONE * (end - start))
        and seen_stretches.mean() >= _FIRST_WIRE_SEEN
        and _stands_free(wire, cells_m, roi_radius_m=roi_radius_m, tolerance_m=tolerance_m)
    ):
        return True
    if not (
        first is not None
        or _seen_at_both_walls(wire, seen_m, roi_radius_m=roi_radius_m)
        or seen_stretches.mean() >= _FIRST_WIRE_SEEN
    ):
        return False
    along = (
        cells_m[wire.distance_m(cells_m) < _WIRE_NEIGHBOURHOOD_M, :2] - wire.origin_xy_m
    ) @ wire.direction_xy
    covered = _stretches_holding(along, start, end)
    if sight is not None:
        middles = start + (np.arange(seen_stretches.size) + 0.5) * _WIRE_BIN_M
        covered |= sight.hidden(wire.at(middles))
    held = np.flatnonzero(seen_stretches)
    if held.size:
        covered[held.min() : held.max() + 1] = True
    return bool(covered.mean() >= min_coverage)


def _stretches_holding(along_m: np.ndarray, start_m: float, end_m: float) -> np.ndarray:
    """Which stretches of :data:`_WIRE_BIN_M` from ``start_m`` to ``end_m`` hold one of the positions
    ``along_m``."""
    stretches = max(1, int(np.ceil((end_m - start_m) / _WIRE_BIN_M)))
    inside = along_m[(along_m >= start_m) & (along_m < end_m)]
    held = np.zeros(stretches, dtype=bool)
    held[np.minimum(((inside - start_m) / _WIRE_BIN_M).astype(np.int64), stretches - 1)] = True
    return held
