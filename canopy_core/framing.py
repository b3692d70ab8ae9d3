"""Where the tree runs out of the cameras' images: a crown cut off by a frame's edge reads short.

A depth camera sees only what falls inside its image. A crown that reaches an edge of a view's image may
go on beyond it, out of that view: the top, an end of W or the lowest leaves that view shows are where its
frame cut the crown, not where the crown ends, and nothing in the numbers says so (a crew standing close
to a tall tree, or holding the camera level). Another view may look beyond that edge: had the crown gone
on there, that view would have seen it, and its own points would carry the measurement on (and, if they
in turn run out of its image, must be looked beyond by yet another view). Only where no view looked
beyond is a measurement cut by the frame. This is geometry of the cameras alone, whatever the colours.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from canopy_core.backproject import project_points
from canopy_core.capture import Intrinsics
from canopy_core.register import apply, invert

__all__ = ["FrameCut", "FrameCuts", "ViewFrame", "cut_metrics", "frame_cuts"]

_CUT_BY_FACING = {
    "up": ("height_m", "thickness_m", "thickness_kde_m"),
    "down": ("crown_base_m", "crown_base_kde_m", "thickness_m", "thickness_kde_m"),
    "sideways": ("width_m", "diameter_along_row_m", "diameter_across_row_m"),
}
"""The metrics a tree cut by an edge facing each way may read wrong: lengths short, the crown base high
(see ``up_within_deg`` of :func:`frame_cuts`)."""
_CUT_BY_ANY_EDGE = ("projected_area_m2", "volume_hull_m3", "volume_voxel_m3")
"""The metrics a cut at any edge may make read short: the crown's area and volumes."""


@dataclass(frozen=True, eq=False)
class ViewFrame:
    """What one view's depth image covers: its camera's intrinsics and pose (``world_from_view``, 4x4), the
    farthest depth it reads (``max_depth_m``: beyond it the view sees nothing, in frame or not), and what
    it read (``depth_m``: the depth image in metres along its optical axis, 0 where nothing)."""

    name: str
    intrinsics: Intrinsics
    world_from_view: np.ndarray
    max_depth_m: float
    depth_m: np.ndarray


@dataclass(frozen=True)
class FrameCut:
    """``points`` points of the tree at ``edge`` of view ``view``'s depth image (``top``, ``bottom``,
    ``left`` or ``right``, as its rows and columns run) that no other view looked beyond: the tree may go
    on there, out of every view, ``facing`` the way out through that edge (``up``, ``down`` or
    ``sideways`` in the world)."""

    view: str
    edge: str
    facing: str
    points: int

    def describe(self) -> str:
        """The cut in words, for an error message or a report."""
        return f"{self.view}'s {self.edge} edge ({self.points} points)"


@dataclass(frozen=True)
class FrameCuts:
    """Where the tree runs out of the views' images: ``across_views``, the cuts no other view looked beyond
    (the merged measurement's); ``by_view``, per view, every edge its own image cuts the tree at (its own
    metrics', judged as if it were alone)."""

    across_views: tuple[FrameCut, ...]
    by_view: tuple[tuple[FrameCut, ...], ...]


def frame_cuts(
    points_by_view: Sequence[np.ndarray],
    frames: Sequence[ViewFrame],
    *,
    margin_px: float,
    min_points: int,
    hidden_margin_m: float,
    up_within_deg: float,
    bottom_masks: Sequence[np.ndarray] | None = None,
) -> FrameCuts:
    """Where the tree runs out of a view's image, and where no other view looked beyond it.

    Another view looked beyond a point at an edge if the point, moved out through that edge (along the
    normal of the plane the edge and the camera's centre span) until it stands about ``margin_px`` of its
    own view's pixels beyond the edge, falls at least ``margin_px`` inside the other view's image (beyond
    that view's own edge band, where its points would carry the tree on), in front of it and within its
    depth range, and, unless the other
    view frames the tree whole (none of its own points at an edge), that view saw there: its depth image
    reads no nearer than the moved point less ``hidden_margin_m`` at its pixel, or reads nothing (sky).
    Where both views are cut, each sees the other's cut stretch across the crown, which hides what stands
    beyond it (a tree's top behind its near shoulder); a view that frames the whole tree shows all of its
    outline, and what it does not see is behind the crown it shows.

    Parameters
    ----------
    points_by_view
        Per view, its points of the tree (world frame, ``(N, 3)``), in the order of ``frames``.
    frames
        What each view's image covers, and what it read.
    margin_px
        A point within this many pixels of an edge (pixel centres) is at that edge; how far beyond the edge
        it is moved, and how far inside another view's image it must then fall, to be looked at by it.
    min_points
        Fewer points than this at an edge, unexplained, are specks (a flying pixel), not the tree.
    hidden_margin_m
        A view that reads nearer than the moved point by more than this sees something in front of it.
    up_within_deg
        An edge faces up (down) when the image's outward axis across it points within this angle of the
        vertical (of straight down); otherwise sideways.
    bottom_masks
        Per view, the mask of its points judged at an edge facing down: the crown alone, since a trunk cut
        at its foot changes no metric (H is read from the ground frame). None: every point.

    Returns
    -------
    FrameCuts
        Across the views, one cut per view and edge where at least ``min_points`` points are looked beyond
        by no other view (none when every view frames the tree, or another view looked beyond wherever one
        does not); and per view, one per edge where at least ``min_points`` points are at it.
    """
    at_edges = [
        _edge_probes(
            points,
            frame,
            margin_px=margin_px,
            up_within_deg=up_within_deg,
            bottom=None if bottom_masks is None else bottom_masks[i],
        )
        for i, (points, frame) in enumerate(zip(points_by_view, frames, strict=True))
    ]
    by_view = tuple(
        tuple(
            FrameCut(view=frame.name, edge=edge, facing=facing, points=probes.shape[0])
            for edge, (facing, probes) in edges.items()
            if probes.shape[0] >= min_points
        )
        for frame, edges in zip(frames, at_edges, strict=True)
    )
    cuts = []
    for index, frame in enumerate(frames):
        for edge, (facing, probes) in at_edges[index].items():
            if probes.shape[0] < min_points:
                continue
            looked_beyond = np.zeros(probes.shape[0], dtype=bool)
            for other, other_cuts in zip(frames, by_view, strict=True):
                if other is not frame:
                    looked_beyond |= _inside(
                        probes,
                        other,
                        margin_px=margin_px,
                        hidden_margin_m=hidden_margin_m if other_cuts else None,
                    )
            unexplained = int(np.count_nonzero(~looked_beyond))
            if unexplained >= min_points:
                cuts.append(FrameCut(view=frame.name, edge=edge, facing=facing, points=unexplained))
    return FrameCuts(across_views=tuple(cuts), by_view=by_view)


def cut_metrics(cuts: Sequence[FrameCut]) -> tuple[str, ...]:
    """The names of the metrics (``CanopyMetrics`` fields) that ``cuts`` may make read wrong (lengths, areas
    and volumes short, the crown base high), sorted; empty without cuts."""
    if not cuts:
        return ()
    names = [name for cut in cuts for name in _CUT_BY_FACING[cut.facing]] + list(_CUT_BY_ANY_EDGE)
    return tuple(dict.fromkeys(sorted(names)))


def _edge_probes(
    points_m: np.ndarray,
    frame: ViewFrame,
    *,
    margin_px: float,
    up_within_deg: float,
    bottom: np.ndarray | None,
) -> dict[str, tuple[str, np.ndarray]]:
    """Per edge of the frame's image, which way it faces in the world and its points within ``margin_px``
    of it (at an edge facing down, only those of ``bottom``), each moved out through the edge until it
    stands about ``margin_px`` beyond it (world frame): by its distance inside plus ``margin_px``, in pixel
    pitches, along the outward normal of the edge's plane (a pitch there moves it a pixel or more across
    the edge)."""
    intrinsics = frame.intrinsics
    camera_points = apply(invert(frame.world_from_view), points_m)
    columns, rows = project_points(camera_points, intrinsics).T
    last_column, last_row = intrinsics.width - 1, intrinsics.height - 1
    # Each edge as (distance inside the image in pixels, focal length across it, the image's outward axis
    # across it and the outward normal of the plane through the camera's centre and the edge, both in the
    # camera's axes).
    edges = {
        "top": (rows, intrinsics.fy, (0.0, -1.0, 0.0), (0.0, -intrinsics.fy, -intrinsics.cy)),
        "bottom": (
            last_row - rows,
            intrinsics.fy,
            (0.0, 1.0, 0.0),
            (0.0, intrinsics.fy, intrinsics.cy - last_row),
        ),
        "left": (columns, intrinsics.fx, (-1.0, 0.0, 0.0), (-intrinsics.fx, 0.0, -intrinsics.cx)),
        "right": (
            last_column - columns,
            intrinsics.fx,
            (1.0, 0.0, 0.0),
            (intrinsics.fx, 0.0, intrinsics.cx - last_column),
        ),
    }
    rotation = frame.world_from_view[:3, :3]
    up_component = float(np.cos(np.radians(up_within_deg)))
    probes = {}
    for edge, (inside_px, focal, axis, normal) in edges.items():
        vertical = float((rotation @ np.array(axis))[2])
        facing = "up" if vertical >= up_component else "down" if vertical <= -up_component else "sideways"
        near = inside_px < margin_px
        if facing == "down" and bottom is not None:
            near &= bottom
        outward = rotation @ (np.array(normal) / np.linalg.norm(normal))
        step_m = (inside_px[near] + margin_px) * camera_points[near, 2] / focal
        probes[edge] = (facing, points_m[near] + np.outer(step_m, outward))
    return probes


def _inside(
    points_m: np.ndarray, frame: ViewFrame, *, margin_px: float, hidden_margin_m: float | None
) -> np.ndarray:
    """Mask of the points that fall at least ``margin_px`` inside the frame's image (pixel centres), in
    front of its camera and no farther than it reads; with ``hidden_margin_m``, only those it saw there: its
    depth at their pixel reads nothing, or no nearer than they stand less that margin."""
    camera_points = apply(invert(frame.world_from_view), points_m)
    depth = camera_points[:, 2]
    ahead = (depth > 0) & (depth <= frame.max_depth_m)
    pixels = project_points(np.where(ahead[:, None], camera_points, 1.0), frame.intrinsics)
    inside = (
        ahead
        & (pixels[:, 0] >= margin_px)
        & (pixels[:, 0] <= frame.intrinsics.width - 1 - margin_px)
        & (pixels[:, 1] >= margin_px)
        & (pixels[:, 1] <= frame.intrinsics.height - 1 - margin_px)
    )
    if hidden_margin_m is None:
        return inside
    columns, rows = np.rint(pixels[inside]).astype(np.int64).T
    read = frame.depth_m[rows, columns]
    seen = inside.copy()
    seen[inside] = (read == 0) | (read >= depth[inside] - hidden_margin_m)
    return seen
