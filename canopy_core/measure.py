"""The measurement pipeline: a capture's views in, one registered tree cloud and its metrics out.

Stages, each reported to the progress callback by name: ``load`` (capture read and checked), ``balls``
(each view back-projected without flying pixels and searched for balls, views at once), ``register`` (ball
registration into the first view's frame, and the world frame from the ground and the trunk), ``refine``
(gated ICP), ``metrics`` (per view and merged: the paper's V1, V2 and V1+V2 modes) and ``done``.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import ValidationError

from canopy_core.alignment import align_views
from canopy_core.backproject import ViewCloud, backproject
from canopy_core.ball_selection import BallChoice
from canopy_core.balls import ViewBallCandidates, find_ball_candidates
from canopy_core.capture import Capture, CaptureManifest, View, load_capture
from canopy_core.cloud_io import Cloud, PointClass
from canopy_core.config import FilterConfig, MeasureConfig
from canopy_core.errors import CaptureError, ConfigError, MeasurementError, RegistrationFailed
from canopy_core.filters import reliable_depth_mask
from canopy_core.foliage import foliage_mask
from canopy_core.framing import FrameCut, ViewFrame, cut_metrics, frame_cuts
from canopy_core.ground import (
    CAMERA_UP,
    GroundFrame,
    GroundPlane,
    ground_height_map,
    view_ground_plane,
)
from canopy_core.metrics import (
    CanopyMetrics,
    canopy_metrics,
    crown_candidates,
    crown_mask,
    measured_points,
)
from canopy_core.poles import find_poles, pole_mask
from canopy_core.processes import on_each
from canopy_core.refine import IcpRefinement
from canopy_core.register import apply
from canopy_core.segment import find_wires, tree_component, wire_mask
from canopy_core.spheres import SphereFit
from canopy_core.trunk_axis import TrunkAxis, follow_trunk
from canopy_core.validation import validation_problems
from canopy_core.visibility import seen_through

__all__ = [
    "STAGES",
    "Measurement",
    "Progress",
    "ViewDiagnostics",
    "ViewEvidence",
    "config_for",
    "depth_footprint_m",
    "filtered_cloud",
    "measure",
    "view_evidence",
]

Progress = Callable[[str, float], None]
"""Called with a stage name and the overall progress in [0, 1] as each stage starts."""

STAGES = ("load", "balls", "register", "refine", "metrics", "done")

MERGED = "merged"
_GROUND_SAMPLE = 60_000
_HEADLINE_METRICS = ("height_m", "width_m", "thickness_m", "crown_base_m")
_TREE_CLEARANCE_M = 0.12
"""Tree points start this high above the ground: below it are the ground, grass and the balls."""


@dataclass(frozen=True)
class ViewDiagnostics:
    """What happened to one view: points kept, balls found, how it registered.

    ``unreliable_pixels_removed`` counts depth readings out of range or flying; ``sparse_points_removed``
    the points inside the region of interest dropped as strays; ``balls_found_by_position`` the colours
    whose ball was found where the other views placed it, having shown too little of its colour;
    ``balls_placed_unseen`` those whose ball the view does not show at all, placed there (its ``balls``
    entry has no point).
    """

    view: str
    depth_pixels: int
    unreliable_pixels_removed: int
    roi_points: int
    sparse_points_removed: int
    tree_points: int
    balls: dict[str, SphereFit]
    balls_found_by_position: tuple[str, ...]
    balls_placed_unseen: tuple[str, ...]
    ball_residual_m: float
    world_from_view: np.ndarray
    icp: IcpRefinement | None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict."""
        return {
            "depth_pixels": self.depth_pixels,
            "unreliable_pixels_removed": self.unreliable_pixels_removed,
            "roi_points": self.roi_points,
            "sparse_points_removed": self.sparse_points_removed,
            "tree_points": self.tree_points,
            "balls": {color: fit.to_dict() for color, fit in self.balls.items()},
            "balls_found_by_position": list(self.balls_found_by_position),
            "balls_placed_unseen": list(self.balls_placed_unseen),
            "ball_residual_m": self.ball_residual_m,
            "world_from_view": self.world_from_view.round(6).tolist(),
            "icp": self.icp.to_dict() if self.icp else None,
        }


@dataclass(frozen=True)
class Measurement:
    """The result of measuring one capture: metrics per mode, diagnostics, the fused cloud, the config."""

    manifest: CaptureManifest
    modes: dict[str, CanopyMetrics]
    views: tuple[ViewDiagnostics, ...]
    ground: GroundFrame
    config: MeasureConfig
    cloud: Cloud = field(repr=False)
    """Every view's points in the region of interest, in the world frame, with the view and class of each."""
    timings_s: dict[str, float]
    ball_choices: tuple[BallChoice, ...] = field(default=(), repr=False)
    """Per view, the balls chosen and the spheres rejected with why: what a report draws on each view."""

    @property
    def merged(self) -> CanopyMetrics:
        """The metrics of all views merged (V1+V2 in the paper)."""
        return self.modes[MERGED]

    def to_dict(self) -> dict[str, Any]:
        """The document of ``canopy measure --json``: merged metrics on top, then modes and diagnostics."""
        ground = self.ground
        return {
            **self.merged.to_dict(),
            "capture": {
                key: getattr(self.manifest, key)
                for key in ("orchard", "row", "tree", "captured_at", "sensor")
            },
            "modes": {name: metrics.to_dict() for name, metrics in self.modes.items()},
            "registration": {
                "method": "balls+icp" if any(v.icp and v.icp.accepted for v in self.views) else "balls",
                "ground": {
                    "points": ground.ground_points,
                    "rms_m": ground.ground_rms_m,
                    "tilt_from_ball_plane_deg": ground.tilt_from_ball_plane_deg,
                    "balls_on_ground": ground.on_ground,
                    "ball_heights_m": dict(zip(self.config.balls.colors, ground.ball_heights_m, strict=True)),
                    "trunk_xy_m": list(ground.trunk_xy_m),
                    "trunk_points": ground.trunk_points,
                    "origin_at_trunk": ground.origin_at_trunk,
                    "ground_height_at_trunk_m": ground.ground_height_at_trunk_m,
                },
                "views": {view.view: view.to_dict() for view in self.views},
            },
            "config": self.config.model_dump(),
            "timings_s": self.timings_s,
        }

    def to_json(self, *, indent: int | None = None) -> str:
        """:meth:`to_dict` as JSON text: numpy values become plain numbers; NaN is refused, never written."""
        return json.dumps(self.to_dict(), indent=indent, allow_nan=False, default=_plain)


def _plain(value: Any) -> Any:
    if hasattr(value, "tolist"):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


def config_for(manifest: CaptureManifest, overrides: dict[str, Any] | None = None) -> MeasureConfig:
    """The measurement settings of a capture: defaults, then capture.json's balls and ROI, then overrides."""
    from_capture: dict[str, Any] = {"balls": manifest.calibration_balls.model_dump()}
    if manifest.roi is not None:
        from_capture["roi"] = manifest.roi.model_dump()
    config = MeasureConfig().merged(from_capture)
    if not overrides:
        return config
    try:
        return config.merged(overrides)
    except ValidationError as exc:
        problems = validation_problems(exc, MeasureConfig)
        raise ConfigError(
            problems.message,
            field=problems.field,
            hint="docs/configuration.md lists every setting (`canopy settings` prints it)"
            if problems.unknown_key
            else None,
        ) from exc


class _Stages:
    """Reports stage starts to the progress callback and times each stage."""

    def __init__(self, progress: Progress | None) -> None:
        self._progress = progress
        self._name: str | None = None
        self._started = time.perf_counter()
        self.timings_s: dict[str, float] = {}

    def start(self, name: str) -> None:
        now = time.perf_counter()
        if self._name is not None:
            self.timings_s[self._name] = round(now - self._started, 4)
        self._name, self._started = name, now
        if self._progress is not None:
            self._progress(name, STAGES.index(name) / (len(STAGES) - 1))


def measure(
    capture: Capture | str | Path,
    *,
    overrides: dict[str, Any] | None = None,
    progress: Progress | None = None,
    processes: int | None = 1,
) -> Measurement:
    """Measure the tree of one capture.

    Parameters
    ----------
    capture
        A loaded :class:`Capture` or the path of a capture folder.
    overrides
        Nested settings overriding the defaults and the capture's own (see :class:`MeasureConfig`).
    progress
        Called with each stage's name and the overall progress in [0, 1].
    processes
        How many views are filtered and searched for balls at once, and their regions of interest cut,
        each in a process forked for it (:func:`canopy_core.processes.on_each`): 1 (the default, safe in
        any program), one at a time; None, one per CPU this process may use, as ``canopy measure`` and the
        service's worker do. The result is the same either way.

    Raises
    ------
    CaptureError
        The capture folder is invalid.
    BallNotFound
        A ball is missing or implausible in a view (names the view and colour).
    RegistrationFailed
        The balls do not bring the views together.
    MeasurementError
        Nothing of the tree is left to measure.
    """
    stages = _Stages(progress)
    stages.start("load")
    if not isinstance(capture, Capture):
        capture = load_capture(capture)
    config = config_for(capture.manifest, overrides)

    colors = config.balls.colors
    if len(colors) < 3:
        raise RegistrationFailed(
            f"{len(colors)} ball colour(s) configured; registration and the ground frame need three",
            field="calibration_balls.colors",
        )

    stages.start("balls")
    depth_pixels = [int(np.count_nonzero(view.depth_raw)) for view in capture.views]
    evidence = view_evidence(capture.views, config, processes=processes)
    clouds = [view.cloud for view in evidence]
    candidates, grounds = [view.balls for view in evidence], [view.ground for view in evidence]

    stages.start("register")
    aligned = align_views(
        [view.name for view in capture.views],
        clouds,
        [view.camera.depth.fx for view in capture.views],
        candidates,
        grounds,
        config,
        refining=lambda: stages.start("refine"),
        processes=processes,
    )
    choices, ground, world_from_view = aligned.choices, aligned.ground, aligned.world_from_view
    roi_points, roi_colors = aligned.roi_points_m, aligned.roi_colors_rgb
    balls = [{color: candidate.fit for color, candidate in choice.chosen.items()} for choice in choices]
    centres = [np.array([found[color].center_m for color in colors]) for found in balls]

    stages.start("metrics")
    trunk_xy = np.array(ground.trunk_xy_m)
    tree_masks, point_classes = _tree_masks(
        roi_points,
        [
            _beyond_roi_points(cloud, pose, config)
            for cloud, pose in zip(clouds, world_from_view, strict=True)
        ],
        [pose[:3, 3] for pose in world_from_view],
        apply(ground.world_from_reference, centres[0]),
        trunk_xy,
        ground.trunk_radius_m,
        config,
    )
    modes, measured = _modes(
        capture,
        roi_points,
        roi_colors,
        tree_masks,
        world_from_view,
        trunk_xy,
        ground.trunk_radius_m,
        config,
    )
    for kinds, mask, view_measured in zip(
        point_classes,
        tree_masks,
        np.split(measured, np.cumsum([np.count_nonzero(mask) for mask in tree_masks])[:-1]),
        strict=True,
    ):
        kinds[np.flatnonzero(mask)[~view_measured]] = PointClass.OTHER

    diagnostics = tuple(
        ViewDiagnostics(
            view=view.name,
            depth_pixels=depth_pixels[i],
            unreliable_pixels_removed=depth_pixels[i] - len(clouds[i]),
            roi_points=int(roi_points[i].shape[0]),
            sparse_points_removed=aligned.stray_points_removed[i],
            tree_points=int(np.count_nonzero(tree_masks[i])),
            balls=balls[i],
            balls_found_by_position=choices[i].found_by_position,
            balls_placed_unseen=choices[i].placed_unseen,
            ball_residual_m=_ball_residual(aligned.view_to_reference[i], centres[i], centres[0]),
            world_from_view=world_from_view[i],
            icp=aligned.icp[i],
        )
        for i, view in enumerate(capture.views)
    )
    stages.start("done")
    return Measurement(
        manifest=capture.manifest,
        modes=modes,
        views=diagnostics,
        ground=ground,
        config=config,
        cloud=Cloud(
            np.concatenate(roi_points),
            np.concatenate(roi_colors),
            views=np.concatenate(
                [np.full(len(points), i, dtype=np.uint8) for i, points in enumerate(roi_points)]
            ),
            classes=np.concatenate(point_classes),
        ),
        timings_s=stages.timings_s,
        ball_choices=tuple(choices),
    )


def filtered_cloud(view: View, filters: FilterConfig) -> ViewCloud:
    """A view's points without out-of-range and flying pixels, in its depth camera's frame."""
    keep = reliable_depth_mask(
        view.depth_m,
        min_depth_m=filters.min_depth_m,
        max_depth_m=filters.max_depth_m,
        window_px=filters.flying_window_px,
        jump_ratio=filters.flying_jump_ratio,
        jump_min_m=filters.flying_jump_min_m,
    )
    if not keep.any():
        raise CaptureError(
            f"no depth reading between {filters.min_depth_m} and {filters.max_depth_m} m",
            view=view.name,
            file=f"{view.name}/depth.png",
            hint="check camera.json's depth_scale (depth units per metre)",
        )
    return backproject(view, keep=keep)


@dataclass(frozen=True)
class ViewEvidence:
    """What one view gives the choice of balls (see :func:`view_evidence`)."""

    cloud: ViewCloud
    """Its points without out-of-range and flying pixels, in its depth camera's frame."""
    balls: ViewBallCandidates
    """Every sphere of about the balls' radius found among them."""
    ground: GroundPlane | None
    """Its ground plane; None where none is found."""


def view_evidence(
    views: Sequence[View], config: MeasureConfig, *, processes: int | None = 1
) -> list[ViewEvidence]:
    """Each view filtered (:func:`filtered_cloud`) and searched for balls and its ground plane, as the
    measurement and ``canopy balls`` both need it; up to ``processes`` views at once
    (:func:`canopy_core.processes.on_each`; None: one per CPU), each filtered in its own process too.

    Raises
    ------
    CaptureError
        The first view without a depth reading in range.
    """
    return on_each(partial(_view_evidence, config=config), list(views), processes=processes)


def _view_evidence(view: View, *, config: MeasureConfig) -> ViewEvidence:
    """One view's evidence (see :func:`view_evidence`)."""
    cloud = filtered_cloud(view, config.filters)
    ground = view_ground_plane(
        cloud.points_m, up_hint=CAMERA_UP, tolerance_m=config.ground.inlier_tolerance_m
    )
    return ViewEvidence(cloud, find_ball_candidates(cloud, config.balls, ground=ground), ground)


def _modes(
    capture: Capture,
    roi_points: list[np.ndarray],
    roi_colors: list[np.ndarray],
    tree_masks: list[np.ndarray],
    world_from_view: list[np.ndarray],
    trunk_xy: np.ndarray,
    trunk_radius_m: float | None,
    config: MeasureConfig,
) -> tuple[dict[str, CanopyMetrics], np.ndarray]:
    """The metrics of each view's tree points alone, and of all views merged (the paper's V1, V2, V1+V2);
    and, over the views' tree points one after the other, the mask of those the merged metrics were read
    from (:func:`measured_points`).

    The trunk's axis is followed up from its foot (``trunk_xy``, ``trunk_radius_m``: the ground frame's
    circle) on all views together (:func:`canopy_core.trunk_axis.follow_trunk`), and so is the crown told
    from ground vegetation, suckers, fallen fruit and mixed pixels, where the gaps between them are seen
    best and each view's phantoms are seen through by the others (``world_from_view``: each view's
    depth-camera pose in the world frame).
    """
    points = [view_points[mask] for view_points, mask in zip(roi_points, tree_masks, strict=True)]
    foliage = [
        foliage_mask(colors[mask], min_index=config.metrics.foliage_min_exgr)
        for colors, mask in zip(roi_colors, tree_masks, strict=True)
    ]
    footprints = [
        depth_footprint_m(view_points, world_from_view=pose, focal_px=view.camera.depth.fx)
        for view_points, pose, view in zip(points, world_from_view, capture.views, strict=True)
    ]
    merged, merged_foliage = np.concatenate(points), np.concatenate(foliage)
    trunk = follow_trunk(merged, trunk_xy, foot_radius_m=trunk_radius_m, config=config.metrics)
    crown = crown_mask(
        merged,
        trunk,
        candidates=crown_candidates(
            merged, trunk, foliage=merged_foliage, min_radius_m=config.metrics.crown_base_min_radius_m
        ),
        config=config.metrics,
        seen_through=np.concatenate(
            [
                seen_through(
                    view_points,
                    own_view=i,
                    views=capture.views,
                    world_from_view=world_from_view,
                    margin_m=config.metrics.seen_through_margin_m,
                    window_px=config.metrics.seen_through_window_px,
                    reach_percentile=config.metrics.seen_through_reach_percentile,
                )
                for i, view_points in enumerate(points)
            ]
        ),
    )
    offsets = np.cumsum([view_points.shape[0] for view_points in points])[:-1]
    crowns = np.split(crown, offsets)
    measured = measured_points(merged, trunk, crown=crown, foliage=merged_foliage, config=config.metrics)
    measured_by_view = np.split(measured, offsets)
    kept = [view_points[mask] for view_points, mask in zip(points, measured_by_view, strict=True)]
    kept_crown = [mask[kept_mask] for mask, kept_mask in zip(crowns, measured_by_view, strict=True)]
    frames = [
        ViewFrame(
            view.name, view.camera.depth, pose, max_depth_m=config.filters.max_depth_m, depth_m=view.depth_m
        )
        for view, pose in zip(capture.views, world_from_view, strict=True)
    ]
    cuts = frame_cuts(
        kept,
        frames,
        margin_px=config.metrics.frame_margin_px,
        min_points=config.metrics.frame_min_points,
        hidden_margin_m=config.metrics.frame_hidden_margin_m,
        up_within_deg=config.metrics.frame_up_within_deg,
        bottom_masks=kept_crown,
    )
    _refuse_cut_off(cuts.across_views, np.concatenate(kept), config)
    modes: dict[str, CanopyMetrics] = {}
    for view, view_points, leafy, view_crown, footprint, own_cuts in zip(
        capture.views, points, foliage, crowns, footprints, cuts.by_view, strict=True
    ):
        modes[view.name] = replace(
            _metrics_or_fail(
                view_points, leafy, view_crown, footprint, trunk, config, view=view.name, single_view=True
            ),
            cut_by_frame=cut_metrics(own_cuts),
        )
    modes[MERGED] = _metrics_or_fail(
        merged,
        merged_foliage,
        crown,
        np.concatenate(footprints),
        trunk,
        config,
        view=None,
        single_view=len(capture.views) == 1,
    )
    return modes, measured


def _refuse_cut_off(cuts: tuple[FrameCut, ...], kept: np.ndarray, config: MeasureConfig) -> None:
    """Raise a MeasurementError if the merged tree (``kept``: the points its metrics are read from) may go
    on where nothing was measured: out of every view's image (``cuts``), or out of the region of interest
    (the cylinder of ``roi.radius_m`` round the world's vertical axis, the trunk's, up to
    ``roi.max_height_m``), whose top or wall the points reach within ``metrics.support_radius_m`` (at least
    ``metrics.frame_min_points`` of them)."""
    if cuts:
        affected = [name for name in cut_metrics(cuts) if name in _HEADLINE_METRICS]
        raise MeasurementError(
            f"the tree runs out of the depth image at {', '.join(cut.describe() for cut in cuts)}, and no "
            "other view looks beyond: it may go on out of every view, and "
            f"{', '.join(affected)} would be read where the frame cut it",
            view=cuts[0].view if len({cut.view for cut in cuts}) == 1 else None,
            hint="measure it again with the whole tree, and some sky above its top, inside at least one "
            "view's image (step back, or tilt the camera)",
        )
    near_m, enough = config.metrics.support_radius_m, config.metrics.frame_min_points
    if np.count_nonzero(kept[:, 2] >= config.roi.max_height_m - near_m) >= enough:
        raise MeasurementError(
            f"the tree reaches the region of interest's top, {config.roi.max_height_m:g} m above the ground: "
            "it may go on above, so height_m and thickness_m would read short",
            field="roi.max_height_m",
            hint="raise roi.max_height_m above the tree's height",
        )
    if np.count_nonzero(np.linalg.norm(kept[:, :2], axis=1) >= config.roi.radius_m - near_m) >= enough:
        raise MeasurementError(
            f"the tree reaches the region of interest's wall, {config.roi.radius_m:g} m from its axis (the "
            "trunk's, or the balls' centre where no trunk was found): it may go on beyond (a crown wider "
            "than the region, or joined to a neighbour's), so width_m would read the region's width",
            field="roi.radius_m",
            hint="for a crown that wide, raise roi.radius_m; a crown grown into its neighbours' cannot be "
            "measured alone",
        )


def _ball_residual(pose: np.ndarray, centres: np.ndarray, reference: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((apply(pose, centres) - reference) ** 2, axis=1))))


def _beyond_roi_points(cloud: ViewCloud, world_from_view: np.ndarray, config: MeasureConfig) -> np.ndarray:
    """A view's points beyond the region of interest where a trellis wire may show, in the world frame: from
    the cylinder's wall to ``wires.scene_radius_m`` from its axis, from ``wires.scene_min_height_m`` to
    ``roi.max_height_m`` high. A wire runs on through them from post to post; a line of leaves does not.
    Stray points are not filtered out here as inside the cylinder: only lines of thin-line cells are sought
    among these, and a flying pixel stands alone."""
    world = apply(world_from_view, cloud.points_m)
    reach = np.linalg.norm(world[:, :2], axis=1)
    beyond = (reach >= config.roi.radius_m) & (reach <= config.wires.scene_radius_m)
    beyond &= (world[:, 2] > config.wires.scene_min_height_m) & (world[:, 2] < config.roi.max_height_m)
    return world[beyond]


def _tree_masks(
    roi_points: list[np.ndarray],
    beyond_points: list[np.ndarray],
    cameras_m: list[np.ndarray],
    balls_world: np.ndarray,
    trunk_xy: np.ndarray,
    trunk_radius_m: float | None,
    config: MeasureConfig,
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Per view, the points of the tree: above the local ground's clearance, off the balls, off the trellis
    wires (each view's mixed pixels of a wire lie in the plane through the wire and its camera centre,
    ``cameras_m``, world frame), off the poles standing in the region (trellis posts, found where the
    trunk was found on its bark, ``trunk_radius_m``; see :mod:`canopy_core.poles`), not intruders; and every
    point's :class:`PointClass` (tree, ground, ball, or other). ``beyond_points`` holds each view's points
    beyond the region of interest where the wires run on (:func:`_beyond_roi_points`).

    The ground height map, the wires, the poles and the intruders are decided on all views together, where
    each is most complete. Wires go first: they join the crown to the posts and the neighbours they pass
    through, and would join a post's slabs to what stands beside it.
    """
    ground_map = ground_height_map(
        np.concatenate(roi_points), radius_m=config.roi.radius_m, band_m=config.ground.search_band_m
    )
    masks, classes = [], []
    for points in roi_points:
        above = ground_map.height_above(points) > _TREE_CLEARANCE_M
        off_balls = np.ones(points.shape[0], dtype=bool)
        for centre in balls_world:
            off_balls &= np.linalg.norm(points - centre, axis=1) > config.balls.radius_m * 1.5 + 0.02
        kinds = np.full(points.shape[0], PointClass.OTHER, dtype=np.uint8)
        kinds[~above] = PointClass.GROUND
        kinds[~off_balls] = PointClass.BALL
        masks.append(above & off_balls)
        classes.append(kinds)
    per_view = [points[mask] for points, mask in zip(roi_points, masks, strict=True)]
    candidates = np.concatenate(per_view)
    wires = find_wires(
        per_view,
        beyond_views_m=beyond_points,
        cameras_m=cameras_m,
        roi_radius_m=config.roi.radius_m,
        tolerance_m=config.wires.tolerance_m,
        spread_m=config.wires.spread_m,
        max_slope_deg=config.wires.max_slope_deg,
        min_coverage=config.wires.min_coverage,
    )
    off_wires = ~np.concatenate(
        [
            wire_mask(
                points,
                wires,
                tolerance_m=config.wires.tolerance_m,
                spread_m=config.wires.spread_m,
                camera_m=camera,
            )
            for points, camera in zip(per_view, cameras_m, strict=True)
        ]
    )
    if trunk_radius_m is not None:
        poles = find_poles(
            candidates[off_wires],
            ground_map.height_above(candidates[off_wires]),
            trunk_xy_m=trunk_xy,
            trunk_radius_m=trunk_radius_m,
            foot_below_m=config.metrics.crown_piece_min_bottom_m,
            config=config.poles,
        )
        off_wires &= ~np.concatenate(
            [
                pole_mask(points, poles, camera_m=camera, spread_m=config.poles.spread_m)
                for points, camera in zip(per_view, cameras_m, strict=True)
            ]
        )
    connected = np.zeros(candidates.shape[0], dtype=bool)
    connected[off_wires] = tree_component(
        candidates[off_wires], trunk_xy, roi_radius_m=config.roi.radius_m, link_m=config.roi.link_m
    )
    splits = np.cumsum([np.count_nonzero(mask) for mask in masks])[:-1]
    for mask, keep, kinds in zip(masks, np.split(connected, splits), classes, strict=True):
        mask[mask] = keep
        kinds[mask] = PointClass.TREE
    return masks, classes


def depth_footprint_m(points_m: np.ndarray, *, world_from_view: np.ndarray, focal_px: float) -> np.ndarray:
    """The depth pixel pitch at each of a view's points (world frame): its depth along that view's optical
    axis over the focal length, the size a pixel covers there."""
    depth_m = apply(np.linalg.inv(world_from_view), points_m)[:, 2]
    return depth_m / focal_px


def _metrics_or_fail(
    points: np.ndarray,
    foliage: np.ndarray,
    crown: np.ndarray,
    footprint: np.ndarray,
    trunk: TrunkAxis,
    config: MeasureConfig,
    *,
    view: str | None,
    single_view: bool = False,
) -> CanopyMetrics:
    """The metrics of one mode's tree points, or a MeasurementError naming ``view`` (None: merged); a single
    view's top is not judged for a pole (see :func:`canopy_metrics`)."""
    if points.shape[0] < 50:
        raise MeasurementError(
            f"only {points.shape[0]} tree points inside the region of interest",
            view=view,
            hint="check that the tree stands among the balls and inside roi.radius_m",
        )
    try:
        return canopy_metrics(
            points,
            trunk=trunk,
            foliage=foliage,
            crown=crown,
            pixel_footprint_m=footprint,
            config=config.metrics,
            refuse_pole_top=not single_view,
        )
    except MeasurementError as error:
        error.view = error.view or view
        raise
