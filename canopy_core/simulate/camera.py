"""The simulated RGB-D sensor: its two cameras' intrinsics, the rigid map between them, and camera poses.

The sensor is a Kinect v2 by default; :data:`SENSORS` also holds Azure Kinect depth modes, whose other
resolution and field of view (the balls a third or twice as many pixels) the detector must meet as well.
Only the intrinsics differ: every sensor keeps the Kinect v2's time-of-flight noise (:mod:`.sensor`) and
the colour camera's place beside the depth camera.

Camera frames use OpenCV axes (x right, y down, z forward). The colour camera sits 5.2 cm to the right of
the depth camera (+x in the depth camera's frame) with the same orientation, so ``depth_to_color``, which maps
depth-camera coordinates to colour-camera coordinates, is a translation of -0.052 m along x:
``p_color = p_depth + (-0.052, 0, 0)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from canopy_core.capture import Intrinsics

__all__ = [
    "COLOR_BASELINE_M",
    "SENSORS",
    "CameraPose",
    "KinectRig",
    "Sensor",
    "camera_pose",
    "parse_sensor",
    "project",
    "random_kinect_rig",
]

COLOR_BASELINE_M = 0.052
"""Distance from the depth camera to the colour camera, to the depth camera's right."""
_FOCAL_JITTER = 0.02


@dataclass(frozen=True)
class Sensor:
    """A model of RGB-D sensor: the nominal intrinsics of its depth and colour cameras (each simulated
    unit's are jittered round them, as a factory calibration would find them)."""

    name: str
    """As ``capture.json`` names it, after ``simulated-``."""
    depth: Intrinsics
    color: Intrinsics


_AZURE_COLOR = Intrinsics(width=1280, height=720, fx=605.0, fy=605.0, cx=640.0, cy=360.0)
SENSORS = {
    sensor.name: sensor
    for sensor in (
        Sensor(
            "kinect-v2",
            depth=Intrinsics(width=512, height=424, fx=365.0, fy=365.0, cx=256.0, cy=212.0),
            color=Intrinsics(width=1920, height=1080, fx=1060.0, fy=1060.0, cx=960.0, cy=540.0),
        ),
        # The narrow field of view (75 x 65 degrees) binned 2 x 2: 0.69 times the Kinect v2's pixels per
        # degree, so a ball at 3.5 m shows about 40 depth pixels.
        Sensor(
            "azure-kinect-nfov-binned",
            depth=Intrinsics(width=320, height=288, fx=252.0, fy=252.0, cx=160.0, cy=144.0),
            color=_AZURE_COLOR,
        ),
        Sensor(
            "azure-kinect-nfov",
            depth=Intrinsics(width=640, height=576, fx=504.0, fy=504.0, cx=320.0, cy=288.0),
            color=_AZURE_COLOR,
        ),
    )
}
"""The sensors the simulator models, by name; ``kinect-v2`` is the default."""


def parse_sensor(name: str) -> Sensor:
    """The sensor of that name (ValueError naming the known ones otherwise)."""
    try:
        return SENSORS[name]
    except KeyError:
        raise ValueError(f"unknown sensor {name!r}: expected one of {', '.join(SENSORS)}") from None


@dataclass(frozen=True, eq=False)
class KinectRig:
    """One sensor's calibration: depth and colour intrinsics and ``depth_to_color`` (4x4, metres)."""

    depth: Intrinsics
    color: Intrinsics
    depth_to_color: np.ndarray


@dataclass(frozen=True, eq=False)
class CameraPose:
    """Where a camera is: ``rotation``'s columns are the camera's x, y, z axes in world coordinates."""

    rotation: np.ndarray
    position: np.ndarray

    @property
    def camera_to_world(self) -> np.ndarray:
        """The 4x4 matrix mapping camera coordinates to world coordinates."""
        matrix = np.eye(4)
        matrix[:3, :3] = self.rotation
        matrix[:3, 3] = self.position
        return matrix

    def to_camera(self, points_world: np.ndarray) -> np.ndarray:
        """World points (n, 3) in this camera's frame."""
        return (np.asarray(points_world) - self.position) @ self.rotation

    def moved_by(self, this_to_other: np.ndarray) -> CameraPose:
        """The pose of another camera, given the 4x4 map from this camera's coordinates to the other's."""
        other_to_world = self.camera_to_world @ np.linalg.inv(this_to_other)
        return CameraPose(rotation=other_to_world[:3, :3], position=other_to_world[:3, 3])


def _jittered(nominal: Intrinsics, rng: np.random.Generator, *, centre_jitter_px: float) -> Intrinsics:
    focal = nominal.fx * (1.0 + rng.uniform(-_FOCAL_JITTER, _FOCAL_JITTER))
    return Intrinsics(
        width=nominal.width,
        height=nominal.height,
        fx=round(focal, 3),
        fy=round(focal, 3),
        cx=round(nominal.cx + rng.uniform(-centre_jitter_px, centre_jitter_px), 3),
        cy=round(nominal.cy + rng.uniform(-centre_jitter_px, centre_jitter_px), 3),
    )


def random_kinect_rig(rng: np.random.Generator, sensor: Sensor = SENSORS["kinect-v2"]) -> KinectRig:
    """One unit of ``sensor`` (a Kinect v2 by default), its focal lengths within 2 % and principal points
    within a few pixels of nominal."""
    depth_to_color = np.eye(4)
    depth_to_color[0, 3] = -COLOR_BASELINE_M
    return KinectRig(
        depth=_jittered(sensor.depth, rng, centre_jitter_px=3.0),
        color=_jittered(sensor.color, rng, centre_jitter_px=8.0),
        depth_to_color=depth_to_color,
    )


def camera_pose(position: np.ndarray, *, yaw_rad: float, pitch_rad: float, roll_rad: float) -> CameraPose:
    """An upright camera at ``position`` looking along azimuth ``yaw_rad`` (from +x towards +y), tilted up by
    ``pitch_rad`` and rolled clockwise (as seen from behind) by ``roll_rad``."""
    forward = np.array(
        [np.cos(pitch_rad) * np.cos(yaw_rad), np.cos(pitch_rad) * np.sin(yaw_rad), np.sin(pitch_rad)]
    )
    right = np.array([np.sin(yaw_rad), -np.cos(yaw_rad), 0.0])
    down = np.cross(forward, right)
    rolled_right = np.cos(roll_rad) * right + np.sin(roll_rad) * down
    rolled_down = np.cross(forward, rolled_right)
    return CameraPose(
        rotation=np.column_stack([rolled_right, rolled_down, forward]), position=np.asarray(position)
    )


def project(
    pose: CameraPose, intrinsics: Intrinsics, points_world: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates (n, 2), as (column, row), of world points and their depths (n,) along the axis."""
    points = pose.to_camera(points_world)
    depth = points[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        pixels = np.column_stack(
            [
                intrinsics.fx * points[:, 0] / depth + intrinsics.cx,
                intrinsics.fy * points[:, 1] / depth + intrinsics.cy,
            ]
        )
    return pixels, depth
