"""Synthetic captures of simulated apple trees, with their exact dimensions: the product's test bench.

One seed decides everything (tree, orchard, sensor calibration, sun, balls, cameras, noise), through
independent random streams, so the same seed writes the same bytes. A scenario family (:mod:`.scenario`)
dresses the scene; the default, ``green``, is the plain scene, written exactly as before the families
existed.
"""

from __future__ import annotations

from dataclasses import replace
from datetime import UTC, datetime, timedelta
from functools import partial
from pathlib import Path

import numpy as np

from canopy_core.capture import CameraModel
from canopy_core.simulate.camera import Sensor, parse_sensor, random_kinect_rig
from canopy_core.simulate.mesh import merge_meshes
from canopy_core.simulate.placement import NoLayout, place_balls_and_cameras
from canopy_core.simulate.raycast import SceneRaycaster, ShadowCaster
from canopy_core.simulate.scenario import (
    Scenario,
    ScenarioStreams,
    camera_responses,
    dress_orchard,
    fallen_fruit_beside,
    parse_scenario,
    plan_scenario,
    scenario_sunlight,
)
from canopy_core.simulate.scene import build_orchard
from canopy_core.simulate.sensor import capture_frame
from canopy_core.simulate.stake import random_stake
from canopy_core.simulate.tree import random_lean, tree_dimensions
from canopy_core.simulate.writer import CaptureLabels, GroundTruth, SimulatedView, check_empty, write_capture

__all__ = ["simulate_capture", "simulate_captures"]

ORCHARD_NAME = "Simulated block"
ROW_NAME = "R01"
_DEPTH_SCALE = 1000.0
_FIRST_DAY = datetime(2026, 9, 1, 7, 0, tzinfo=UTC)
_STEEPEST_SLOPE_DEG = 30.0
"""Steeper than this, orchards stand on terraces (each level again): no slope the simulator draws."""
_STEEPEST_LEAN_DEG = 45.0
"""The simulator leans a tree by less than this: trellis systems that slant their trees (Tatura,
V-trellis) plant them at up to 30 degrees from vertical, and a free-standing tree pushed over further is
lost."""
_STEEPEST_PITCH_DEG = 30.0
"""A camera held more than this up or down from level shows no ball on the ground or no tree: half a
Kinect v2's vertical field of view."""


def _captured_at(rng: np.random.Generator) -> str:
    moment = _FIRST_DAY + timedelta(days=int(rng.integers(0, 45)), minutes=int(rng.integers(0, 11 * 60)))
    return moment.strftime("%Y-%m-%dT%H:%M:%SZ")


def _simulate(
    out_dir: Path,
    *,
    seed: int,
    tree: str,
    n_views: int,
    native_color: bool,
    sun: float | None,
    scenario: Scenario,
    sensor: Sensor,
    slope_deg: float | None,
    lean_deg: float | None,
    stake: bool,
    pitch_deg: float | None,
    near_posts: bool,
) -> Path:
    check_empty(out_dir)
    # The first six streams are the plain scene's, as they always were; the seventh is the scenario's, the
    # eighth the stake's, the ninth the lean's (spawned children depend only on their index: the others are
    # as they were, and a leaning tree is the same tree as the upright one of its seed).
    streams = np.random.SeedSequence(seed).spawn(9)
    orchard_rng, rig_rng, sun_rng, layout_rng, sensor_rng, label_rng = (
        np.random.default_rng(stream) for stream in streams[:6]
    )
    scenario_streams = ScenarioStreams.spawn(streams[6])
    plan = plan_scenario(scenario, scenario_streams.plan)
    dressing = dress_orchard(
        build_orchard(
            orchard_rng,
            posts=not plan.wires,
            near_posts=near_posts,
            slope_deg=slope_deg,
            foot_lean_per_m=(0.0, 0.0)
            if lean_deg is None
            else random_lean(np.random.default_rng(streams[8]), lean_deg=lean_deg),
        ),
        plan,
        scenario_streams,
        near_posts=near_posts,
    )
    orchard = dressing.orchard
    support = (
        random_stake(
            np.random.default_rng(streams[7]),
            crown_top_z_m=float(orchard.main_tree.mesh.vertices[:, 2].max()),
            trunk_radius_m=orchard.main_tree.shape.trunk_radius_m,
            lean_xy_m=orchard.main_tree.shape.top_offset_m,
        )
        if stake
        else None
    )
    if support is not None:
        orchard = replace(orchard, mesh=merge_meshes([orchard.mesh, support.mesh]))
    rig = random_kinect_rig(rig_rng, sensor)
    sunlight = scenario_sunlight(plan, sun_rng, scenario_streams.light, sun)
    raycaster = SceneRaycaster.build(orchard.mesh, dressing.hanging_apples)
    try:
        layout = place_balls_and_cameras(
            layout_rng,
            orchard,
            raycaster,
            rig,
            n_views=n_views,
            native_color=native_color,
            beside_balls=partial(fallen_fruit_beside, dressing, scenario_streams) if plan.fruit else None,
            pitch_deg=pitch_deg,
        )
    except NoLayout as exc:
        raise NoLayout(f"seed {seed}, {n_views} views: {exc}") from exc
    spheres = (*layout.balls, *dressing.hanging_apples, *layout.beside_balls)
    scene = raycaster.with_spheres(spheres)
    shadows = ShadowCaster.build(orchard.mesh, spheres) if plan.shadows else None
    responses = camera_responses(plan, scenario_streams.camera, n_views)
    camera = (
        CameraModel(
            depth=rig.depth, depth_scale=_DEPTH_SCALE, color=rig.color, depth_to_color=rig.depth_to_color
        )
        if native_color
        else CameraModel(depth=rig.depth, depth_scale=_DEPTH_SCALE)
    )
    views = [
        SimulatedView(
            name=f"views/{number}",
            frame=capture_frame(
                scene,
                pose,
                rig,
                sunlight,
                sensor_rng,
                native_color=native_color,
                shadows=shadows,
                response=response,
            ),
            camera=camera,
            camera_to_world=pose.camera_to_world,
            ball_pixels=ball_pixels,
            ball_clean_shares=clean_shares,
            response=response,
            tree_framed=framed,
        )
        for number, (pose, ball_pixels, clean_shares, response, framed) in enumerate(
            zip(
                layout.poses,
                layout.ball_pixels,
                layout.ball_clean_shares,
                responses,
                layout.tree_framed,
                strict=True,
            ),
            start=1,
        )
    ]
    return write_capture(
        out_dir,
        labels=CaptureLabels(
            orchard=ORCHARD_NAME,
            row=ROW_NAME,
            tree=tree,
            captured_at=_captured_at(label_rng),
            sensor=f"simulated-{sensor.name}",
        ),
        views=views,
        ground_truth=GroundTruth(
            seed=seed,
            dimensions=tree_dimensions(orchard.main_tree, fruit=dressing.hanging_apples),
            orchard=orchard,
            balls=layout.balls,
            sunlight=sunlight,
            dressing=dressing,
            fallen_apples=layout.beside_balls,
            stake=support,
        ),
    )


def _checked(
    n_views: int,
    sun: float | None,
    scenario: Scenario | str,
    slope_deg: float | None,
    lean_deg: float | None,
    pitch_deg: float | None,
) -> Scenario:
    """The scenario named ``scenario``, after checking the options (ValueError if one is wrong)."""
    if n_views < 1:
        raise ValueError(f"n_views must be at least 1, got {n_views}")
    if sun is not None and not 0.0 <= sun <= 1.0:
        raise ValueError(f"sun must be in [0, 1], got {sun}")
    if slope_deg is not None and not 0.0 <= slope_deg < _STEEPEST_SLOPE_DEG:
        raise ValueError(f"slope_deg must be in [0, {_STEEPEST_SLOPE_DEG:g}), got {slope_deg}")
    if lean_deg is not None and not 0.0 <= lean_deg < _STEEPEST_LEAN_DEG:
        raise ValueError(f"lean_deg must be in [0, {_STEEPEST_LEAN_DEG:g}), got {lean_deg}")
    if pitch_deg is not None and not -_STEEPEST_PITCH_DEG <= pitch_deg <= _STEEPEST_PITCH_DEG:
        raise ValueError(
            f"pitch_deg must be in [-{_STEEPEST_PITCH_DEG:g}, {_STEEPEST_PITCH_DEG:g}], got {pitch_deg}"
        )
    return parse_scenario(scenario)


def simulate_capture(
    out_dir: Path,
    *,
    seed: int,
    n_views: int = 2,
    native_color: bool = True,
    sun: float | None = None,
    scenario: Scenario | str = Scenario.GREEN,
    sensor: str = "kinect-v2",
    slope_deg: float | None = None,
    lean_deg: float | None = None,
    stake: bool = False,
    pitch_deg: float | None = None,
    near_posts: bool = False,
) -> Path:
    """Write one synthetic RGB-D capture of a simulated apple tree, with its ``ground_truth.json``.

    Parameters
    ----------
    out_dir
        The capture folder to create; it must not exist or be empty.
    seed
        Decides everything; the same seed and options write byte-identical files.
    n_views
        Number of views: two face each other across the row; more alternate sides and spread over each.
    native_color
        True: 1920x1080 JPEG colour from the colour camera 5.2 cm to the depth camera's right, with
        ``color_intrinsics`` and ``depth_to_color`` in camera.json. False: 512x424 PNG colour registered
        pixel for pixel to the depth image.
    sun
        Direct sunlight strength in [0, 1] (brighter colour, more depth noise and dropout); random if None
        (0.8-1 in harsh light).
    scenario
        The scenario family (:class:`~canopy_core.simulate.scenario.Scenario` or its name): ``green``
        (the plain scene), ``dry``, ``fruit``, ``wires``, ``weeds``, ``harsh`` or ``mixed``.
    sensor
        The sensor's name (:data:`~canopy_core.simulate.camera.SENSORS`): ``kinect-v2``, or an Azure Kinect
        depth mode, ``azure-kinect-nfov-binned`` (320x288) or ``azure-kinect-nfov`` (640x576), with a
        1280x720 colour camera. ``native_color`` False registers colour to the depth image whatever it is.
    slope_deg
        The ground's slope in degrees, downhill in a random direction: a hillside orchard, whose trees and
        posts still stand upright. None: nearly level (at most 0.5 degrees), as every family's default.
    lean_deg
        The tree leans this far from vertical from its foot, trunk and crown, in a random direction: a
        tree planted or trained at a slant, or pushed over by wind and crop. None: its trunk stands
        upright (its crown leans by at most 8 cm), as every family's default. The same seed grows the same
        tree, leaning or not.
    stake
        Stand a support stake beside the trunk (see :mod:`.stake`): a thin pole through the crown whose top
        may stand above it, which is not the tree's.
    pitch_deg
        Hold every camera this many degrees up from level (within 1 degree; negative: down), as a crew that
        does not aim it at the tree: the tree may run out of the image (the balls never do). None: each
        camera is aimed to frame the whole tree, as every family's default.
    near_posts
        Stand a trellis post on each side of the tree 0.5-1.4 m from its trunk, within the crown's reach
        (2.0-3.8 m tall, or as tall as the trellis's), instead of beyond it: the crown may grow round a
        post, which is not the tree's. The same seed grows the same tree.

    Returns
    -------
    Path
        ``out_dir``.

    Raises
    ------
    ValueError
        If ``n_views`` < 1, ``sun`` is outside [0, 1], ``slope_deg`` outside [0, 30), ``lean_deg`` outside
        [0, 45), ``pitch_deg`` outside [-30, 30], or ``scenario`` or ``sensor`` names no such thing.
    FileExistsError
        If ``out_dir`` already holds files.
    NoLayout
        If no placement of the balls and cameras shows every ball to every view (nothing is written).
    """
    family = _checked(n_views, sun, scenario, slope_deg, lean_deg, pitch_deg)
    return _simulate(
        Path(out_dir),
        seed=seed,
        tree="T000",
        n_views=n_views,
        native_color=native_color,
        sun=sun,
        scenario=family,
        sensor=parse_sensor(sensor),
        slope_deg=slope_deg,
        lean_deg=lean_deg,
        stake=stake,
        pitch_deg=pitch_deg,
        near_posts=near_posts,
    )


def simulate_captures(
    out: Path,
    *,
    seed: int,
    count: int,
    n_views: int = 2,
    scenario: Scenario | str = Scenario.GREEN,
    sensor: str = "kinect-v2",
    slope_deg: float | None = None,
    lean_deg: float | None = None,
    stake: bool = False,
    pitch_deg: float | None = None,
    near_posts: bool = False,
) -> list[Path]:
    """Write ``count`` synthetic captures ``out/tree_000``, ``out/tree_001``, ... of different trees.

    Each capture gets its own seed derived from ``seed`` (so tree shape and size, orchard, camera distances
    and heights, noise and sun all vary) and is labelled tree ``T000``, ``T001``, ... of one row; colour is
    native. The same ``seed`` writes byte-identical files.

    Parameters
    ----------
    out
        The folder to write the captures into.
    seed
        The seed the captures' seeds are derived from.
    count
        Number of captures.
    n_views
        Views per capture.
    scenario
        The scenario family of every capture (see :func:`simulate_capture`); in ``mixed`` each capture
        draws its own elements.
    sensor
        The sensor of every capture (see :func:`simulate_capture`).
    slope_deg
        The ground's slope under every tree (see :func:`simulate_capture`); None: nearly level.
    lean_deg
        Every tree's lean from its foot (see :func:`simulate_capture`); None: upright.
    stake
        Stand a support stake beside every tree's trunk (see :func:`simulate_capture`).
    pitch_deg
        Every camera's pitch (see :func:`simulate_capture`); None: aimed to frame the tree.
    near_posts
        Trellis posts within every crown's reach (see :func:`simulate_capture`).

    Returns
    -------
    list of Path
        The capture folders, in order.

    Raises
    ------
    ValueError
        If ``count`` < 0, ``n_views`` < 1, ``slope_deg`` outside [0, 30), ``lean_deg`` outside [0, 45),
        ``pitch_deg`` outside [-30, 30], or ``scenario`` or ``sensor`` names no such thing.
    NoLayout
        If one seed's balls and cameras cannot be placed (the captures before it are written).
    """
    if count < 0:
        raise ValueError(f"count must not be negative, got {count}")
    family = _checked(n_views, None, scenario, slope_deg, lean_deg, pitch_deg)
    model = parse_sensor(sensor)
    seeds = [int(child.generate_state(1)[0]) for child in np.random.SeedSequence(seed).spawn(count)]
    written: list[Path] = []
    for index, tree_seed in enumerate(seeds):
        folder = Path(out) / f"tree_{index:03d}"
        try:
            written.append(
                _simulate(
                    folder,
                    seed=tree_seed,
                    tree=f"T{index:03d}",
                    n_views=n_views,
                    native_color=True,
                    sun=None,
                    scenario=family,
                    sensor=model,
                    slope_deg=slope_deg,
                    lean_deg=lean_deg,
                    stake=stake,
                    pitch_deg=pitch_deg,
                    near_posts=near_posts,
                )
            )
        except NoLayout as exc:
            raise NoLayout(f"{folder.name} ({exc}); the {index} capture(s) before it are written") from exc
    return written
