"""The Kinect v2 as a sensor: depth readings with its noise, flying pixels and dropout, and shaded colour.
Every simulated sensor (:data:`~canopy_core.simulate.camera.SENSORS`) reads depth by this model; only
their intrinsics differ.

Depth model (a time-of-flight camera; sources and assumptions):

- **Mixed pixels.** Each depth pixel is sampled by 3x3 rays. A ToF pixel integrates the light returned from
  everything in its footprint, so where the rays hit surfaces at different depths (every silhouette, and a
  leafy crown is mostly silhouettes) the reading is a blend between foreground and background: the flying
  pixels of Sarbolandi, Lefloch & Kolb, "Kinect range sensing: structured-light versus time-of-flight
  Kinect", CVIU 139 (2015). The blend weights each ray by its return amplitude (cos(incidence) / depth^2)
  times a random factor (log-normal, sigma 0.5), so mixed depths spread randomly between the surfaces,
  weighted by how much of the pixel each covers. Where some rays see sky, the pixel reads the depth of
  what the others hit with probability equal to their share, else nothing. The sensor's own edge filter
  removes a quarter of the mixed pixels.
- **Axial noise.** Gaussian, sigma(z, theta) = 1.5 - 0.5 z + 0.3 z^2 + 0.1 z^1.5 theta^2 / (pi/2 - theta)^2
  millimetres (z in metres, theta the incidence angle): the form of Nguyen, Izadi & Lovell (3DIMPVT 2012)
  fitted to Kinect v2 by Fankhauser et al., "Kinect v2 for mobile robot navigation: evaluation and
  modeling", ICAR 2015; about 1.3 mm at 1 m and 4.3 mm at 4 m head-on, growing quickly past 60 degrees.
- **Sunlight** (``Sunlight.strength`` in [0, 1]) adds ambient infrared that lowers the signal-to-noise ratio
  (Fankhauser et al.): noise is multiplied by 1 + strength * (0.5 + 1.5 * cos(sun on the surface)) and
  dropout grows by 4 % overall and 10 % more on sunlit surfaces.
- **Dropout.** 1.5 % of pixels at random; at grazing incidence, growing from 70 to 88 degrees to all;
  beyond 4.5 m (the supported range), growing to 55-90 % at 8 m; nothing outside 0.5-8 m. No reading is 0.
- **Quantisation.** Depth along the optical axis in millimetres (depth_scale 1000), rounded.

Colour model: Lambertian reflectance lit by a sky term (brighter on upward-facing surfaces) plus the sun,
leaves also lit through from behind, the sky a pale blue gradient; then Gaussian brightness noise per
pixel. Shading only scales a colour, so the balls keep their hue and saturation (their shaded side is
darker). Optionally (the scenario families of :mod:`.scenario`):

- **Cast shadows.** A :class:`~canopy_core.simulate.raycast.ShadowCaster` tells which hit points see the
  sun; the others get sky light only, in colour and in the depth noise the sun causes.
- **Hard light.** ``Sunlight.skylight_scale`` and ``direct_scale`` weaken the sky and strengthen the sun
  (a clear sky), so that shadows are deep.
- **The colour camera's automatic exposure and white balance** (:class:`CameraResponse`): per-channel gains
  and an exposure scale on the linear colour, then a contrast curve about mid grey, then 8-bit clipping,
  so that highlights burn out and shadows sink towards black.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from canopy_core.simulate.camera import CameraPose, KinectRig
from canopy_core.simulate.mesh import SurfaceKind
from canopy_core.simulate.raycast import RayHits, SceneRaycaster, ShadowCaster

__all__ = [
    "DEPTH_SUBPIXEL_OFFSETS",
    "CameraResponse",
    "SensorFrame",
    "Sunlight",
    "axial_noise_sigma_m",
    "capture_frame",
    "color_image",
    "depth_image",
    "random_sunlight",
]

DEPTH_SUBPIXEL_OFFSETS = np.array([[dx, dy] for dy in (-1 / 3, 0.0, 1 / 3) for dx in (-1 / 3, 0.0, 1 / 3)])
"""The 3x3 rays cast through each depth pixel, at the centres of its ninths (columns, rows; pixels)."""

_MIN_RANGE_M, _MAX_RANGE_M = 0.5, 8.0
_SUPPORTED_RANGE_M = 4.5
_RANDOM_DROPOUT = 0.015
_GRAZING_DEG = (70.0, 88.0)
_EDGE_FILTER_DROPOUT = 0.25
_MIXED_DEPTH_SPREAD = (0.03, 0.01)
"""A pixel mixes surfaces when its rays' depths spread over more than 3 cm plus 1 % of the depth."""
_WEIGHT_SIGMA = 0.5
_MAX_INCIDENCE_RAD = np.radians(89.0)

_SKY_HORIZON = np.array([0.80, 0.86, 0.92], dtype=np.float32)
_SKY_ZENITH = np.array([0.55, 0.69, 0.88], dtype=np.float32)
_SKYLIGHT = (0.45, 0.25)
"""Sky irradiance on a surface facing down, and what it gains facing up."""
_SUN_GAIN = 0.55
_LEAF_TRANSMISSION = 0.3
_COLOR_NOISE = 0.008
_MID_GREY = 0.5
"""The contrast curve of :class:`CameraResponse` leaves this linear level unchanged."""


@dataclass(frozen=True, eq=False)
class SensorFrame:
    """What the sensor delivers for one view: raw depth (uint16, millimetres) and RGB colour (uint8)."""

    depth_raw: np.ndarray
    color_rgb: np.ndarray


@dataclass(frozen=True)
class Sunlight:
    """Direct sunlight: ``strength`` 0 (overcast) to 1 (full sun), ``direction`` the unit vector to it.

    ``skylight_scale`` and ``direct_scale`` multiply the sky's and the sun's irradiance in the colour
    image (1: the usual hazy summer light; a clear sky gives less sky light and a harder sun).
    """

    strength: float
    direction: tuple[float, float, float]
    skylight_scale: float = 1.0
    direct_scale: float = 1.0


@dataclass(frozen=True)
class CameraResponse:
    """How the colour camera turned light into pixel values in one view: automatic white balance and
    exposure, and its tone curve.

    Linear RGB is multiplied by ``gains`` (red, green, blue) and by ``exposure``; then a level x becomes
    0.5 * (x / 0.5) ** ``contrast`` (above 1: darker shadows and brighter highlights), clipped to 8 bits.
    """

    gains: tuple[float, float, float]
    exposure: float
    contrast: float = 1.0


def random_sunlight(rng: np.random.Generator, *, strength: float | None = None) -> Sunlight:
    """Sun 20-65 degrees high at a random azimuth; its strength random in [0, 1] unless given."""
    elevation = np.radians(rng.uniform(20.0, 65.0))
    azimuth = rng.uniform(0.0, 2 * np.pi)
    chosen = float(rng.uniform(0.0, 1.0)) if strength is None else float(strength)
    direction = (
        float(np.cos(elevation) * np.cos(azimuth)),
        float(np.cos(elevation) * np.sin(azimuth)),
        float(np.sin(elevation)),
    )
    return Sunlight(strength=chosen, direction=direction)


def axial_noise_sigma_m(depth_m: np.ndarray, incidence_rad: np.ndarray) -> np.ndarray:
    """Standard deviation of Kinect v2 depth noise along the ray at depth ``depth_m`` and incidence angle."""
    theta = np.minimum(incidence_rad, _MAX_INCIDENCE_RAD)
    sigma_mm = (
        1.5 - 0.5 * depth_m + 0.3 * depth_m**2 + 0.1 * depth_m**1.5 * theta**2 / (np.pi / 2 - theta) ** 2
    )
    return sigma_mm / 1000.0


def _lengths(vectors: np.ndarray) -> np.ndarray:
    return np.sqrt(np.einsum("...i,...i->...", vectors, vectors))


def _normal_dot_ray(hits: RayHits) -> np.ndarray:
    return np.einsum("...i,...i->...", hits.normals, hits.directions)


def _facing_sign(normal_dot_ray: np.ndarray) -> np.ndarray:
    """+1 where a normal faces the camera, -1 where it faces away: every surface is seen from both sides."""
    return np.where(normal_dot_ray > 0, np.float32(-1.0), np.float32(1.0))


def _sun_cosine(normals: np.ndarray, sign: np.ndarray, sunlight: Sunlight) -> np.ndarray:
    """Cosine between the camera-facing normals and the direction to the sun."""
    return sign * (normals @ np.asarray(sunlight.direction, dtype=np.float32))


def depth_image(
    hits: RayHits,
    sunlight: Sunlight,
    rng: np.random.Generator,
    *,
    depth_scale: float = 1000.0,
    sunlit: np.ndarray | None = None,
) -> np.ndarray:
    """The depth image (uint16, ``depth_scale`` units per metre, 0 = no reading) a Kinect v2 reads.

    Parameters
    ----------
    hits
        The depth camera's rays, several per pixel (:data:`DEPTH_SUBPIXEL_OFFSETS`).
    sunlight
        Raises noise and dropout.
    rng
        Source of every random draw.
    sunlit
        Shaped as ``hits.surface``: False where the hit point lies in a cast shadow (no sun on it); no
        cast shadows when omitted.
    """
    hit = hits.hit
    depth = np.where(hit, hits.depth_m, 0.0).astype(np.float32)
    normal_dot_ray = _normal_dot_ray(hits)
    sign = _facing_sign(normal_dot_ray)
    cosine = np.clip(np.abs(normal_dot_ray) / _lengths(hits.directions), 1e-3, 1.0)
    amplitude = np.where(hit, cosine / np.maximum(depth, 0.1) ** 2, 0.0)
    amplitude *= np.exp(_WEIGHT_SIGMA * rng.standard_normal(amplitude.shape, dtype=np.float32))
    total = amplitude.sum(axis=-1)
    any_hit = total > 0
    safe_total = np.where(any_hit, total, 1.0)
    mixed_m = (amplitude * depth).sum(axis=-1) / safe_total
    incidence = np.arccos(np.clip((amplitude * cosine).sum(axis=-1) / safe_total, 0.0, 1.0))
    sun_on_ray = np.clip(_sun_cosine(hits.normals, sign, sunlight), 0.0, None)
    if sunlit is not None:
        sun_on_ray = np.where(sunlit, sun_on_ray, np.float32(0.0))
    sun_on_pixel = sunlight.strength * np.clip((amplitude * sun_on_ray).sum(axis=-1) / safe_total, 0.0, 1.0)

    sigma_m = axial_noise_sigma_m(mixed_m, incidence) * (1.0 + sunlight.strength * 0.5 + 1.5 * sun_on_pixel)
    reading_m = mixed_m + sigma_m * rng.standard_normal(mixed_m.shape, dtype=np.float32)

    nearest = np.where(hit, depth, np.inf).min(axis=-1)
    farthest = depth.max(axis=-1)
    mixed_surfaces = farthest - nearest > _MIXED_DEPTH_SPREAD[0] + _MIXED_DEPTH_SPREAD[1] * nearest
    dropout = (
        _RANDOM_DROPOUT
        + 0.04 * sunlight.strength
        + 0.1 * sun_on_pixel
        + np.clip((np.degrees(incidence) - _GRAZING_DEG[0]) / (_GRAZING_DEG[1] - _GRAZING_DEG[0]), 0.0, 1.0)
        + np.clip((reading_m - _SUPPORTED_RANGE_M) / (_MAX_RANGE_M - _SUPPORTED_RANGE_M), 0.0, 1.0)
        * (0.55 + 0.35 * sunlight.strength)
        + _EDGE_FILTER_DROPOUT * mixed_surfaces
    )
    keep_probability = np.clip(1.0 - dropout, 0.0, 1.0) * hit.mean(axis=-1)
    valid = (
        any_hit
        & (rng.random(mixed_m.shape, dtype=np.float32) < keep_probability)
        & (reading_m >= _MIN_RANGE_M)
        & (reading_m <= _MAX_RANGE_M)
    )
    return np.where(valid, np.round(reading_m * depth_scale), 0).astype(np.uint16)


def _sky(directions: np.ndarray, sunlight: Sunlight) -> np.ndarray:
    elevation = np.clip(directions[:, 2] / _lengths(directions), 0.0, 1.0)[:, None]
    return (_SKY_HORIZON + (_SKY_ZENITH - _SKY_HORIZON) * elevation) * np.float32(
        0.92 + 0.12 * sunlight.strength
    )


def _radiance(
    hits: RayHits, raycaster: SceneRaycaster, sunlight: Sunlight, sunlit: np.ndarray | None
) -> np.ndarray:
    """Linear RGB reaching the camera along each ray, (..., 3) float32; no sun where ``sunlit`` is False."""
    hit = hits.hit
    surface = np.where(hit, hits.surface, 0)
    sign = _facing_sign(_normal_dot_ray(hits))
    sun_cosine = _sun_cosine(hits.normals, sign, sunlight)
    through_leaf = np.where(
        raycaster.surface_kinds[surface] == SurfaceKind.LEAF,
        np.float32(-_LEAF_TRANSMISSION) * sun_cosine,
        0.0,
    )
    direct = np.maximum(np.maximum(sun_cosine, through_leaf), 0.0)
    if sunlit is not None:
        direct = np.where(sunlit, direct, np.float32(0.0))
    sky_light = _SKYLIGHT[0] + (_SKYLIGHT[1] / 2) * (sign * hits.normals[..., 2] + 1.0)
    irradiance = (
        np.float32(sunlight.skylight_scale) * sky_light
        + np.float32(_SUN_GAIN * sunlight.strength * sunlight.direct_scale) * direct
    )
    radiance = raycaster.reflectance(surface, hits.normals)
    radiance *= irradiance[..., None]
    sky = np.flatnonzero(~hit)
    radiance.reshape(-1, 3)[sky] = _sky(hits.directions.reshape(-1, 3)[sky], sunlight)
    return radiance


def color_image(
    hits: RayHits,
    raycaster: SceneRaycaster,
    sunlight: Sunlight,
    rng: np.random.Generator,
    *,
    sunlit: np.ndarray | None = None,
    response: CameraResponse | None = None,
) -> np.ndarray:
    """An 8-bit RGB image (rows, columns, 3): the mean radiance of each pixel's rays, with pixel noise
    (brightness only: the colour sensor's chroma noise is small after demosaicing and compression).

    ``sunlit`` (shaped as ``hits.surface``) is False where a hit point lies in a cast shadow; ``response``
    applies white balance, exposure and contrast. Without them: no cast shadows, a neutral camera.
    """
    radiance = _radiance(hits, raycaster, sunlight, sunlit).mean(axis=2)
    if response is not None:
        radiance *= np.asarray(response.gains, dtype=np.float32) * np.float32(response.exposure)
    radiance += np.float32(_COLOR_NOISE) * rng.standard_normal((*radiance.shape[:2], 1), dtype=np.float32)
    if response is not None:
        radiance = np.float32(_MID_GREY) * (
            np.clip(radiance, 0.0, None) / np.float32(_MID_GREY)
        ) ** np.float32(response.contrast)
    return np.clip(np.round(radiance * 255.0), 0, 255).astype(np.uint8)


def capture_frame(
    raycaster: SceneRaycaster,
    pose: CameraPose,
    rig: KinectRig,
    sunlight: Sunlight,
    rng: np.random.Generator,
    *,
    native_color: bool,
    shadows: ShadowCaster | None = None,
    response: CameraResponse | None = None,
) -> SensorFrame:
    """Render one view: depth from the depth camera at ``pose``, colour from the colour camera beside it
    (``native_color``) or registered pixel for pixel to the depth image (the mean colour of each depth
    pixel's rays). ``shadows`` (the same scene) casts shadows; ``response`` is the colour camera's white
    balance, exposure and contrast (neutral when omitted)."""
    depth_hits = raycaster.cast_camera(pose, rig.depth, subpixel_offsets=DEPTH_SUBPIXEL_OFFSETS)
    depth_sunlit = None if shadows is None else shadows.sunlit(depth_hits, sunlight.direction)
    depth_raw = depth_image(depth_hits, sunlight, rng, sunlit=depth_sunlit)
    color_hits, color_sunlit = depth_hits, depth_sunlit
    if native_color:
        color_hits = raycaster.cast_camera(pose.moved_by(rig.depth_to_color), rig.color)
        color_sunlit = None if shadows is None else shadows.sunlit(color_hits, sunlight.direction)
    color_rgb = color_image(color_hits, raycaster, sunlight, rng, sunlit=color_sunlit, response=response)
    return SensorFrame(depth_raw=depth_raw, color_rgb=color_rgb)
