"""What ``canopy balls`` shows a crew in the field: per view and colour, the ball chosen and why the other
spheres were not, as text, JSON and a picture.

:func:`ball_report` runs the measurement's own selection (:func:`~canopy_core.ball_selection.select_balls`
over all views) for three colours or more; for fewer, and when the selection fails, it describes what each
view shows on its own (:func:`~canopy_core.ball_selection.describe_view`), so the crew sees which ball to
re-lay.
:func:`draw_ball_preview` draws a view's choice on its colour image: each chosen ball as a circle of its
projected size in its colour, labelled with its range, and each rejected sphere as a thin grey circle with
its objection's code.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import cv2
import numpy as np

from canopy_core.backproject import project_points
from canopy_core.ball_selection import BallChoice, describe_view, select_balls
from canopy_core.balls import BallCandidate, ViewBallCandidates
from canopy_core.capture import CameraModel, View
from canopy_core.config import BallConfig
from canopy_core.errors import BallNotFound, MeasurementError, RegistrationFailed
from canopy_core.ground import GroundPlane

__all__ = ["BallReport", "ball_report", "ball_rgb", "draw_ball_preview"]

PREVIEW_WIDTH_PX = 960
"""Previews of wider colour images (Kinect v2's 1920x1080) are scaled down to this width."""

_LISTED_LIKENESS = 0.1
"""Spheres whose mean likelihood of a colour is below this (next to none of their points look like that
ball: the other balls, leaves, bark) are not listed among that colour's rejected candidates."""
_REJECTED_RGB = (225, 225, 225)
_SHADOW_RGB = (0, 0, 0)
_FONT = cv2.FONT_HERSHEY_SIMPLEX


@dataclass(frozen=True)
class BallReport:
    """The balls of every view of a capture as the crew needs them.

    Attributes
    ----------
    choices
        Per view, in order, the balls chosen and the spheres rejected per colour, likeliest first. Listed
        under a colour are the spheres with some of that colour, but not those chosen for another colour,
        unless rejected for being taken (they would have done for this colour too). When ``error`` is set,
        each view is described on its own and may lack balls (``BallChoice.missing`` says why).
    error
        Why the measurement's selection failed, or None.
    """

    choices: tuple[BallChoice, ...]
    error: MeasurementError | None

    def to_dict(self, *, limit: int | None = 5) -> dict[str, Any]:
        """The document of ``canopy balls --json``.

        ``views`` maps each view and colour to the chosen sphere's ``center_m``, ``radius_m``, ``points``
        and ``rms_m`` (and ``found_by_position`` when found where the other views place it, or
        ``placed_unseen`` when the view does not show it and it stands where they put it), or, without one, to
        ``problem`` and ``code``; and to ``rejected``: at most ``limit`` (None: all) spheres, likeliest
        first, each with ``center_m``, ``radius_m``, ``points``, ``reason`` and ``code``. ``error``
        (:meth:`~canopy_core.errors.CanopyError.to_dict`) is there when selection failed.
        """
        views: dict[str, dict[str, Any]] = {}
        for choice in self.choices:
            views[choice.view] = {}
            for color in choice.rejected:
                chosen = choice.chosen.get(color)
                if chosen is not None:
                    entry: dict[str, Any] = chosen.fit.to_dict()
                    if color in choice.found_by_position:
                        entry["found_by_position"] = True
                    if color in choice.placed_unseen:
                        entry["placed_unseen"] = True
                else:
                    entry = {"problem": choice.missing[color].message, "code": choice.missing[color].code}
                entry["rejected"] = [
                    {
                        **{k: v for k, v in rejection.candidate.fit.to_dict().items() if k != "rms_m"},
                        "reason": rejection.objection.message,
                        "code": rejection.objection.code,
                    }
                    for rejection in choice.rejected[color][:limit]
                ]
                views[choice.view][color] = entry
        document: dict[str, Any] = {"views": views}
        if self.error is not None:
            document["error"] = self.error.to_dict()
        return document

    def lines(self, *, limit: int | None = 3) -> list[str]:
        """The text of ``canopy balls``: a line per view and colour (the chosen sphere, or why there is
        none), each followed by indented lines for at most ``limit`` (None: all) rejected spheres."""
        lines = []
        if self.error is not None:
            lines.append("ball selection failed; what each view shows on its own:")
        for choice in self.choices:
            for color, rejected in choice.rejected.items():
                chosen = choice.chosen.get(color)
                if chosen is None:
                    lines.append(f"{choice.view} {color:<7} no ball: {choice.missing[color].message}")
                else:
                    placed = (
                        "  (found where the other views place it)"
                        if color in choice.found_by_position
                        else "  (not seen in this view: placed where the other views put it)"
                        if color in choice.placed_unseen
                        else ""
                    )
                    lines.append(
                        f"{choice.view} {color:<7} {_describe(chosen)}  rms {chosen.fit.rms_m * 1000:.1f} mm"
                        + placed
                    )
                for rejection in rejected[:limit]:
                    lines.append(
                        f"    rejected {_describe(rejection.candidate)}  [{rejection.objection.code}] "
                        f"{rejection.objection.message}"
                    )
                if limit is not None and len(rejected) > limit:
                    lines.append(f"    ... {len(rejected) - limit} more rejected (--all lists them)")
        return lines


def _describe(candidate: BallCandidate) -> str:
    x, y, z = candidate.fit.center_m
    return (
        f"centre ({x:+.3f}, {y:+.3f}, {z:+.3f}) m  radius {candidate.fit.radius_m * 1000:.1f} mm  "
        f"{candidate.fit.points} points"
    )


def ball_report(
    views: Sequence[ViewBallCandidates], config: BallConfig, *, grounds: Sequence[GroundPlane | None]
) -> BallReport:
    """Choose every view's balls as the measurement does, and say why each other sphere was not taken.

    Parameters
    ----------
    views
        The spheres found in each view (:func:`~canopy_core.balls.find_ball_candidates`), in order.
    config
        The balls' size, colours and thresholds.
    grounds
        Each view's ground plane (:func:`~canopy_core.ground.view_ground_plane`), or None where none was
        found; unused for fewer than three colours (each view is described on its own).

    Returns
    -------
    BallReport
        With three colours or more, :func:`~canopy_core.ball_selection.select_balls`' choice across views,
        or, when it fails, each view described on its own and the error; with fewer colours, each view
        described on its own, and the first view's missing ball as the error.
    """
    error: MeasurementError | None = None
    if len(config.colors) >= 3:
        try:
            choices = select_balls(views, config, grounds=grounds)
        except (BallNotFound, RegistrationFailed) as exc:
            error = exc
            choices = [describe_view(v, config, ground=g) for v, g in zip(views, grounds, strict=True)]
    else:
        choices = [describe_view(view, config) for view in views]
        for choice in choices:
            for color, objection in choice.missing.items():
                error = error or BallNotFound(
                    objection.message, view=choice.view, color=color, hint=objection.hint
                )
    return BallReport(choices=tuple(_listed(choice) for choice in choices), error=error)


def _listed(choice: BallChoice) -> BallChoice:
    """``choice`` with each colour's rejected list cut to that colour's candidates: without the spheres
    that have next to none of its colour (``_LISTED_LIKENESS``), and without the spheres chosen for another
    colour unless rejected as taken."""
    rejected = {
        color: [
            rejection
            for rejection in rejections
            if rejection.objection.code == "taken"
            or (
                rejection.candidate.color_scores.get(color, 0.0) >= _LISTED_LIKENESS
                and not any(other is rejection.candidate for other in choice.chosen.values())
            )
        ]
        for color, rejections in choice.rejected.items()
    }
    return replace(choice, rejected=rejected)


def ball_rgb(color: str, config: BallConfig) -> tuple[int, int, int]:
    """The RGB a ball colour is drawn in: the middle hue of its HSV range, fully saturated and bright."""
    (low, _, _), (high, _, _) = config.hsv_range(color)
    hue = (low + high + (180 if low > high else 0)) / 2 % 180
    pixel = np.array([[[round(hue), 255, 255]]], dtype=np.uint8)
    red, green, blue = cv2.cvtColor(pixel, cv2.COLOR_HSV2RGB)[0, 0]
    return int(red), int(green), int(blue)


def draw_ball_preview(
    view: View, choice: BallChoice, config: BallConfig, *, max_width_px: int = PREVIEW_WIDTH_PX
) -> np.ndarray:
    """A view's colour image with its balls drawn: the picture of ``canopy balls --preview``.

    Each sphere's centre (in the depth camera's frame) is projected into the colour image: through
    ``depth_to_color`` and the colour intrinsics for a native pair, through the depth intrinsics when
    the colour image is registered to the depth image.

    Parameters
    ----------
    view
        The view, with its colour image and camera.
    choice
        Its balls (from :class:`BallReport` or :func:`~canopy_core.ball_selection.select_balls`).
    config
        The balls' colours (each chosen ball is drawn in :func:`ball_rgb` of its colour).
    max_width_px
        Wider images are scaled down to this width.

    Returns
    -------
    numpy.ndarray
        ``(H, W, 3)`` uint8 RGB image: each chosen ball as a thick circle in its colour round its
        projected outline, labelled with its colour and range ("yellow 3.2 m"; "blue 3.4 m, placed unseen"
        for a ball the view does not show, placed where the other views put it); each rejected sphere, once,
        as a thin light grey circle labelled with its objection's code for its likeliest colour; and
        in the top left corner, "no blue ball" for each colour of ``config`` without a chosen ball.
    """
    height, width = view.color_rgb.shape[:2]
    scale = min(1.0, max_width_px / width)
    size = (max(1, round(width * scale)), max(1, round(height * scale)))
    image = np.ascontiguousarray(
        cv2.resize(view.color_rgb, size, interpolation=cv2.INTER_AREA) if scale < 1.0 else view.color_rgb,
        dtype=np.uint8,
    ).copy()
    chosen_ids = {id(candidate) for candidate in choice.chosen.values()}
    shown: dict[int, tuple[BallCandidate, str, float]] = {}
    for color, rejections in choice.rejected.items():
        for rejection in rejections:
            candidate, likeness = rejection.candidate, rejection.candidate.color_scores.get(color, 0.0)
            known = shown.get(id(candidate))
            if id(candidate) not in chosen_ids and (known is None or likeness > known[2]):
                shown[id(candidate)] = (candidate, rejection.objection.code, likeness)
    for candidate, code, _ in shown.values():
        _draw(image, view.camera, candidate, scale, _REJECTED_RGB, code, thickness=1)
    for color, candidate in choice.chosen.items():
        label = f"{color} {candidate.range_m:.1f} m" + (", placed unseen" if candidate.unseen else "")
        _draw(image, view.camera, candidate, scale, ball_rgb(color, config), label, thickness=3)
    missing = [color for color in config.colors if color not in choice.chosen]
    for row, color in enumerate(missing, start=1):
        _label(image, f"no {color} ball", (8, 22 * row), ball_rgb(color, config), font_scale=0.6)
    return image


def _draw(
    image: np.ndarray,
    camera: CameraModel,
    candidate: BallCandidate,
    scale: float,
    rgb: tuple[int, int, int],
    label: str,
    *,
    thickness: int,
) -> None:
    """Draw a sphere's circle, just outside its outline so that the sphere stays in sight, with a dark
    edge for contrast, and its label above it, in place."""
    projected = _project(camera, candidate.fit.center_m, candidate.fit.radius_m)
    if projected is None:
        return
    u, v, radius_px = (value * scale for value in projected)
    centre, radius = (round(u), round(v)), round(radius_px) + thickness // 2 + 2
    cv2.circle(image, centre, radius, _SHADOW_RGB, thickness + 2, cv2.LINE_AA)
    cv2.circle(image, centre, radius, rgb, thickness, cv2.LINE_AA)
    font_scale = 0.5 if thickness > 1 else 0.4
    (text_width, _), _ = cv2.getTextSize(label, _FONT, font_scale, 1)
    origin = (
        int(np.clip(centre[0] - text_width // 2, 0, max(image.shape[1] - text_width, 0))),
        int(np.clip(centre[1] - radius - 6, 12, image.shape[0] - 2)),
    )
    _label(image, label, origin, rgb, font_scale=font_scale)


def _label(
    image: np.ndarray, text: str, origin: tuple[int, int], rgb: tuple[int, int, int], *, font_scale: float
) -> None:
    """Write ``text`` with its baseline starting at ``origin``, outlined in black, in place."""
    cv2.putText(image, text, origin, _FONT, font_scale, _SHADOW_RGB, 3, cv2.LINE_AA)
    cv2.putText(image, text, origin, _FONT, font_scale, rgb, 1, cv2.LINE_AA)


def _project(camera: CameraModel, centre_m: np.ndarray, radius_m: float) -> tuple[float, float, float] | None:
    """A sphere's centre ``(u, v)`` and radius in colour-image pixels; None when it is not in front."""
    if camera.color is not None and camera.depth_to_color is not None:
        intrinsics = camera.color
        point = camera.depth_to_color[:3, :3] @ centre_m + camera.depth_to_color[:3, 3]
    else:
        intrinsics, point = camera.depth, np.asarray(centre_m, dtype=float)
    if point[2] <= radius_m:
        return None
    ((u, v),) = project_points(point[None, :], intrinsics)
    return float(u), float(v), intrinsics.fx * radius_m / float(point[2])
