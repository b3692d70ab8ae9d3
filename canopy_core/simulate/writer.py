"""Writing a simulated capture folder in the format canopy-capture/1, with its ``ground_truth.json``.

Depth is written as a 16-bit PNG (millimetres), colour as JPEG (quality 92) for native 1920x1080 pairs and
as PNG when it is registered to the depth image. Nothing depends on the clock or the machine, so equal
captures are equal byte for byte.

A capture of a scenario family other than ``green`` also records in ``ground_truth.json`` the family, which
elements it holds and what was placed (floor palette, fallen leaves, apples, wires, weeds, lighting) and
each view's colour camera response; a ``green`` capture's file has none of these keys (it is the file the
simulator always wrote), so a missing ``scenario`` key means ``green``.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from canopy_core.capture import CAPTURE_FORMAT, CameraModel
from canopy_core.simulate.raycast import Sphere
from canopy_core.simulate.scenario import Dressing, Scenario
from canopy_core.simulate.scene import BALL_COLORS, BALL_DIAMETER_M, Orchard
from canopy_core.simulate.sensor import CameraResponse, SensorFrame, Sunlight
from canopy_core.simulate.stake import Stake
from canopy_core.simulate.tree import TreeDimensions

__all__ = ["CaptureLabels", "GroundTruth", "SimulatedView", "check_empty", "write_capture"]

_JPEG_QUALITY = 92


@dataclass(frozen=True)
class CaptureLabels:
    """Who and when, as capture.json names them."""

    orchard: str
    row: str
    tree: str
    captured_at: str
    sensor: str
    """``simulated-`` and the sensor's name (``simulated-kinect-v2``)."""


@dataclass(frozen=True, eq=False)
class SimulatedView:
    """One rendered view: its name (``views/1``), images, calibration, depth-camera-to-world pose, each
    ball's pixels and share of its disc seen clean (see :mod:`.placement`), colour camera response (None:
    neutral) and whether its depth image frames the whole tree."""

    name: str
    frame: SensorFrame
    camera: CameraModel
    camera_to_world: np.ndarray
    ball_pixels: tuple[int, ...]
    ball_clean_shares: tuple[float, ...]
    tree_framed: bool
    """The whole main tree (every vertex of its hull) falls inside the depth image, 4 px from its edges, as
    a camera aimed at the tree frames it."""
    response: CameraResponse | None = None


@dataclass(frozen=True, eq=False)
class GroundTruth:
    """What the simulation knows exactly, for ``ground_truth.json``: ``dressing`` is the scenario's (None
    or a ``green`` one: nothing added), ``fallen_apples`` the apples laid on the ground, ``stake`` the
    support stake beside the trunk (None: none)."""

    seed: int
    dimensions: TreeDimensions
    orchard: Orchard
    balls: tuple[Sphere, ...]
    sunlight: Sunlight
    dressing: Dressing | None = None
    fallen_apples: tuple[Sphere, ...] = ()
    stake: Stake | None = None


def _write_json(path: Path, content: dict[str, Any]) -> None:
    path.write_text(json.dumps(content, indent=2) + "\n", encoding="utf-8")


def _camera_json(camera: CameraModel) -> dict[str, Any]:
    content: dict[str, Any] = {
        "depth_intrinsics": dataclasses.asdict(camera.depth),
        "depth_scale": camera.depth_scale,
    }
    if camera.color is not None and camera.depth_to_color is not None:
        content["color_intrinsics"] = dataclasses.asdict(camera.color)
        content["depth_to_color"] = camera.depth_to_color.tolist()
    return content


def _manifest_json(labels: CaptureLabels, views: Sequence[SimulatedView]) -> dict[str, Any]:
    return {
        "format": CAPTURE_FORMAT,
        **dataclasses.asdict(labels),
        "calibration_balls": {"diameter_m": BALL_DIAMETER_M, "colors": list(BALL_COLORS)},
        "views": [view.name for view in views],
    }


def _rgb(color: np.ndarray) -> list[float]:
    return [round(float(c), 4) for c in color]


def _apple_json(apple: Sphere, where: str) -> dict[str, Any]:
    content: dict[str, Any] = {
        "center_m": apple.centre.tolist(),
        "diameter_m": 2 * apple.radius_m,
        "variety": apple.label,
        "rgb": _rgb(apple.color),
        "where": where,
    }
    if apple.second_color is not None and apple.second_side is not None:
        content["blush_rgb"] = _rgb(apple.second_color)
        content["blush_side"] = apple.second_side.tolist()
    return content


def _scenario_json(truth: GroundTruth, dressing: Dressing) -> dict[str, Any]:
    """The scenario's keys of ``ground_truth.json``."""
    palette, trellis, weeds = dressing.palette, dressing.trellis, dressing.weeds
    return {
        "scenario": dressing.plan.scenario.value,
        "elements": {
            key: value for key, value in dataclasses.asdict(dressing.plan).items() if key != "scenario"
        },
        "ground_palette": None if palette is None else dataclasses.asdict(palette),
        "fallen_leaves": dressing.fallen_leaves,
        "apples": [_apple_json(apple, "crown") for apple in dressing.hanging_apples]
        + [_apple_json(apple, "ground") for apple in truth.fallen_apples],
        "apple_variety": dressing.apple_variety,
        "wires": [] if trellis is None else [dataclasses.asdict(wire) for wire in trellis.wires],
        "weeds": {
            "clumps": [] if weeds is None else [dataclasses.asdict(clump) for clump in weeds.clumps],
            "suckers": [] if weeds is None else [dataclasses.asdict(sucker) for sucker in weeds.suckers],
        },
        "shadows": dressing.plan.shadows,
    }


def _ground_truth_json(truth: GroundTruth, views: Sequence[SimulatedView]) -> dict[str, Any]:
    orchard = truth.orchard
    main = orchard.main_tree
    content: dict[str, Any] = {
        **dataclasses.asdict(truth.dimensions),
        "world_frame": "metres; z up, x along the row, y across it; origin on the ground at the trunk's base",
        "views": {
            view.name: {
                "camera_to_world": view.camera_to_world.tolist(),
                "ball_pixels": dict(zip(BALL_COLORS, view.ball_pixels, strict=True)),
                "ball_clean_shares": {
                    color: round(share, 3)
                    for color, share in zip(BALL_COLORS, view.ball_clean_shares, strict=True)
                },
                "tree_framed": view.tree_framed,
            }
            for view in views
        },
        "balls": {
            color: {"center_m": ball.centre.tolist(), "diameter_m": 2 * ball.radius_m}
            for color, ball in zip(BALL_COLORS, truth.balls, strict=True)
        },
        "tree": {
            "form": main.shape.form.value,
            "trunk_radius_m": main.shape.trunk_radius_m,
            "leaves": main.leaves.triangle_count,
            "triangles": main.mesh.triangle_count,
        },
        "neighbours": [
            {"trunk_base_m": tree.base.tolist(), "form": tree.shape.form.value} for tree in orchard.neighbours
        ],
        "posts": [list(position) for position in orchard.post_positions],
        "ground": {
            "tilt_deg": orchard.ground.tilt_deg,
            "herbicide_strip_width_m": 2 * orchard.ground.strip_half_width_m,
        },
        "sun": {"strength": truth.sunlight.strength, "direction": list(truth.sunlight.direction)},
        "scene_triangles": orchard.mesh.triangle_count,
        "seed": truth.seed,
    }
    if main.shape.foot_lean_per_m != (0.0, 0.0):
        content["tree"]["foot_lean_per_m"] = list(main.shape.foot_lean_per_m)
    if truth.stake is not None:
        content["stake"] = {
            "xy_m": list(truth.stake.xy_m),
            "top_m": truth.stake.top_m,
            "radius_m": truth.stake.radius_m,
        }
    dressing = truth.dressing
    if dressing is None or dressing.plan.scenario is Scenario.GREEN:
        return content
    content["sun"].update(
        skylight_scale=truth.sunlight.skylight_scale, direct_scale=truth.sunlight.direct_scale
    )
    for view in views:
        if view.response is not None:
            content["views"][view.name]["camera_response"] = {
                "white_balance_gains": list(view.response.gains),
                "exposure": view.response.exposure,
                "contrast": view.response.contrast,
            }
    return {**content, **_scenario_json(truth, dressing)}


def check_empty(out_dir: Path) -> None:
    """Refuse a folder that holds files: a simulation never overwrites a capture.

    Raises
    ------
    FileExistsError
        If ``out_dir`` exists and is not empty.
    """
    if out_dir.exists() and any(out_dir.iterdir()):
        raise FileExistsError(f"{out_dir} is not empty; simulated captures are written to new folders")


def write_capture(
    out_dir: Path, *, labels: CaptureLabels, views: Sequence[SimulatedView], ground_truth: GroundTruth
) -> Path:
    """Write a capture folder at ``out_dir`` (created if missing; see :func:`check_empty`) and return it."""
    out_dir.mkdir(parents=True, exist_ok=True)
    for view in views:
        view_dir = out_dir / view.name
        view_dir.mkdir(parents=True)
        Image.fromarray(view.frame.depth_raw).save(view_dir / "depth.png")
        color = Image.fromarray(view.frame.color_rgb)
        if view.camera.registered:
            color.save(view_dir / "color.png")
        else:
            color.save(view_dir / "color.jpg", quality=_JPEG_QUALITY)
        _write_json(view_dir / "camera.json", _camera_json(view.camera))
    _write_json(out_dir / "capture.json", _manifest_json(labels, views))
    _write_json(out_dir / "ground_truth.json", _ground_truth_json(ground_truth, views))
    return out_dir
