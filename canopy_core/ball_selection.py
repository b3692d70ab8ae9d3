"""Choosing which sphere is which calibration ball: on the ground, distinct, the same triangle in every view.

Detection (``balls.py``) finds the spheres of a view and scores each for every ball colour; here the balls
are chosen among them. A calibration ball rests on the ground, so a sphere floating above the view's ground
plane (an apple in the crown) is not one. The three balls are three different spheres that do not stand
in a line. And the balls do not move between views, so the distances between their centres are the same
from every side: among the likely spheres of each colour, the combination is chosen whose triangles agree
in every view and whose spheres are likeliest together. The consistency of the triangle is the selector,
not only a check after the fact: a patch of straw taken for the yellow ball in one view, or a fallen apple
beside the red ball, has no partner at the right distances in the other views.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from canopy_core.balls import BallCandidate, ViewBallCandidates
from canopy_core.config import BallConfig
from canopy_core.errors import BallNotFound, RegistrationFailed
from canopy_core.ground import GroundPlane

__all__ = [
    "BallChoice",
    "check_ball_distances",
    "check_ball_spacing",
    "choose_in_view",
    "select_balls",
]

_CANDIDATES_PER_COLOR = 4
"""The likeliest plausible spheres per colour and view that the joint choice considers (4³ triangles)."""


@dataclass(frozen=True)
class BallChoice:
    """The balls chosen in one view, and why each other sphere was not taken, per colour.

    ``rejected`` maps each colour to ``(candidate, reason)`` pairs, likeliest first: its geometry's
    problem, too little of the colour, not resting on the ground, taken for another colour, or not at the
    other views' distances.
    """

    view: str
    chosen: dict[str, BallCandidate]
    rejected: dict[str, list[tuple[BallCandidate, str]]]


def check_ball_spacing(view: str, centres: np.ndarray, colors: Sequence[str], diameter_m: float) -> None:
    """Refuse balls found closer than one diameter apart (one ball taken twice) or standing in a line.

    Raises
    ------
    RegistrationFailed
        Naming the view and the two colours, or the line.
    """
    for first, second in itertools.combinations(range(len(colors)), 2):
        if np.linalg.norm(centres[first] - centres[second]) < diameter_m:
            raise RegistrationFailed(
                f"the {colors[first]} and {colors[second]} balls were found at the same place",
                view=view,
                field="calibration_balls.hsv",
                hint="their colour ranges overlap, or the balls touch; separate them",
            )
    if _in_a_line(centres, diameter_m):
        raise RegistrationFailed(
            "the balls stand in a line, so they do not fix the view's orientation",
            view=view,
            hint="lay the balls in a triangle around the trunk",
        )


def check_ball_distances(
    view: str, centres: np.ndarray, reference: np.ndarray, colors: Sequence[str], *, tolerance_m: float
) -> None:
    """Refuse balls whose mutual distances differ from the reference view's by more than ``tolerance_m``.

    Raises
    ------
    RegistrationFailed
        Naming the view and the colour of the ball in most of the disagreeing pairs (a moved ball, or
        something else of its colour taken for it).
    """
    if _disagreement(centres, reference).max() > tolerance_m:
        raise _distance_error(view, centres, reference, colors, tolerance_m=tolerance_m)


def _distance_error(
    view: str, centres: np.ndarray, reference: np.ndarray, colors: Sequence[str], *, tolerance_m: float
) -> RegistrationFailed:
    disagreement = _disagreement(centres, reference)
    worst = int(np.argmax((disagreement > tolerance_m).sum(axis=1) + disagreement.sum(axis=1) / 10))
    return RegistrationFailed(
        f"the {colors[worst]} ball's distances to the other balls differ from the first view's by up to "
        f"{disagreement[worst].max() * 1000:.0f} mm",
        view=view,
        hint=f"the {colors[worst]} ball was moved between views, something else of its colour was taken for "
        "it, or it was too far or too poorly lit to fit well; check with `canopy balls --preview`",
    )


def choose_in_view(candidates: ViewBallCandidates, config: BallConfig) -> dict[str, BallCandidate]:
    """The likeliest plausible sphere per colour in one view alone, never one sphere for two colours.

    Raises
    ------
    BallNotFound
        For the first colour with no plausible sphere (naming the view, the colour and the likeliest
        sphere's problem).
    """
    shortlist = _shortlist(candidates, config, ground=None)
    triangles = _assignments(shortlist, config)
    if not triangles:
        raise _first_missing(candidates, shortlist, config)
    return dict(zip(config.colors, triangles[0][1], strict=True))


def select_balls(
    views: Sequence[ViewBallCandidates], config: BallConfig, *, grounds: Sequence[GroundPlane | None]
) -> list[BallChoice]:
    """Choose every view's balls jointly: on the ground, distinct, at the same mutual distances everywhere.

    Parameters
    ----------
    views
        The spheres found in each view; the first is the reference.
    config
        The balls' size, colours and thresholds (``max_ground_gap_m``, ``max_distance_mismatch_m``).
    grounds
        Each view's ground plane, or None where none was found (then no sphere is refused for floating).

    Returns
    -------
    list of BallChoice
        Per view, in order, the chosen spheres and every other one with the reason it was not taken.

    Raises
    ------
    BallNotFound
        A view has no plausible sphere for a colour (naming the view, colour and the likeliest problem).
    RegistrationFailed
        No combination of the views' likely spheres agrees in its distances (naming the view and colour
        that disagree most), or a view's only combinations are degenerate.
    """
    shortlists = [
        _shortlist(view, config, ground=ground) for view, ground in zip(views, grounds, strict=True)
    ]
    per_view = []
    for view, shortlist in zip(views, shortlists, strict=True):
        triangles = _assignments(shortlist, config)
        if not triangles:
            raise _first_missing(view, shortlist, config)
        per_view.append(triangles)
    chosen = _consistent_choice(per_view, config)
    if chosen is None:  # then some view's likeliest triangle disagrees with the reference's: name the worst
        best = [np.array([c.fit.center_m for c in triangles[0][1]]) for triangles in per_view]
        worst = 1 + int(np.argmax([_disagreement(centres, best[0]).max() for centres in best[1:]]))
        raise _distance_error(
            views[worst].view, best[worst], best[0], config.colors, tolerance_m=config.max_distance_mismatch_m
        )
    return [
        _describe(view, shortlist, dict(zip(config.colors, triangle, strict=True)), config)
        for view, shortlist, triangle in zip(views, shortlists, chosen, strict=True)
    ]


@dataclass(frozen=True)
class _Shortlist:
    """Per colour, the plausible spheres (likeliest first, at most ``_CANDIDATES_PER_COLOR``) and the
    others with why each was refused."""

    plausible: dict[str, list[BallCandidate]]
    refused: dict[str, list[tuple[BallCandidate, str]]]


def _shortlist(view: ViewBallCandidates, config: BallConfig, *, ground: GroundPlane | None) -> _Shortlist:
    plausible: dict[str, list[BallCandidate]] = {}
    refused: dict[str, list[tuple[BallCandidate, str]]] = {}
    for color in config.colors:
        plausible[color], refused[color] = [], []
        for candidate in view.ranked(color, config):
            problem = candidate.problem_as(color, config) or _floating(candidate, ground, config)
            if problem is None and len(plausible[color]) < _CANDIDATES_PER_COLOR:
                plausible[color].append(candidate)
            elif problem is not None:
                refused[color].append((candidate, problem))
    return _Shortlist(plausible=plausible, refused=refused)


def _floating(candidate: BallCandidate, ground: GroundPlane | None, config: BallConfig) -> str | None:
    """Why a sphere is not resting on the ground, or None when it is (or no ground is known)."""
    if ground is None:
        return None
    gap_m = ground.height_of(candidate.fit.center_m) - config.radius_m
    if gap_m <= config.max_ground_gap_m:
        return None
    return (
        f"a sphere {candidate.range_m:.1f} m away stands {gap_m:.2f} m above the ground, where a calibration "
        "ball rests on it (an apple in the crown?)"
    )


def _first_missing(
    view: ViewBallCandidates, shortlist: _Shortlist, config: BallConfig
) -> BallNotFound | RegistrationFailed:
    """The error for a view without a plausible combination: the first colour lacking a sphere, or the
    spheres' spacing when every colour has one."""
    for color in config.colors:
        if shortlist.plausible[color]:
            continue
        floating = [
            reason
            for candidate, reason in shortlist.refused[color]
            if not candidate.problem_as(color, config)
        ]
        if floating:
            return BallNotFound(
                floating[0], view=view.view, color=color, hint="Lay the ball on the ground, in view"
            )
        return view.not_found(color, config)
    centres = np.array([shortlist.plausible[color][0].fit.center_m for color in config.colors])
    try:
        check_ball_spacing(view.view, centres, config.colors, config.diameter_m)
    except RegistrationFailed as error:
        return error
    return RegistrationFailed("no combination of the balls found is usable", view=view.view)


def _assignments(shortlist: _Shortlist, config: BallConfig) -> list[tuple[float, tuple[BallCandidate, ...]]]:
    """Every combination of one plausible sphere per colour, distinct and not in a line, with its score
    (the sum of its spheres' scores for their colours), likeliest first."""
    options = [shortlist.plausible[color] for color in config.colors]
    found = []
    for combination in itertools.product(*options):
        centres = np.array([candidate.fit.center_m for candidate in combination])
        distances = np.linalg.norm(centres[:, None] - centres[None, :], axis=2)
        if (distances[np.triu_indices(len(combination), 1)] < config.diameter_m).any():
            continue
        if len(combination) >= 3 and _in_a_line(centres, config.diameter_m):
            continue
        score = sum(
            candidate.score(color, radius_m=config.radius_m)
            for color, candidate in zip(config.colors, combination, strict=True)
        )
        found.append((score, combination))
    found.sort(key=lambda item: -item[0])
    return found


def _consistent_choice(
    per_view: list[list[tuple[float, tuple[BallCandidate, ...]]]], config: BallConfig
) -> list[tuple[BallCandidate, ...]] | None:
    """The combination per view, one for every view, whose distances agree with the first view's and whose
    total score is highest; None when there is none."""
    best: tuple[float, list[tuple[BallCandidate, ...]]] | None = None
    for reference_score, reference in per_view[0]:
        reference_centres = np.array([c.fit.center_m for c in reference])
        total, chosen = reference_score, [reference]
        for triangles in per_view[1:]:
            match = next(
                (
                    (score, triangle)
                    for score, triangle in triangles
                    if _disagreement(np.array([c.fit.center_m for c in triangle]), reference_centres).max()
                    <= config.max_distance_mismatch_m
                ),
                None,
            )
            if match is None:
                break
            total += match[0]
            chosen.append(match[1])
        else:
            if best is None or total > best[0]:
                best = (total, chosen)
    return None if best is None else best[1]


def _describe(
    view: ViewBallCandidates, shortlist: _Shortlist, chosen: dict[str, BallCandidate], config: BallConfig
) -> BallChoice:
    rejected: dict[str, list[tuple[BallCandidate, str]]] = {}
    for color in config.colors:
        others = []
        for candidate in shortlist.plausible[color]:
            if candidate is chosen[color]:
                continue
            taken_as = next((c for c, other in chosen.items() if other is candidate), None)
            others.append(
                (
                    candidate,
                    f"taken for the {taken_as} ball"
                    if taken_as
                    else "not at the same distances from the other balls as in the other views",
                )
            )
        rejected[color] = others + shortlist.refused[color]
    return BallChoice(view=view.view, chosen=chosen, rejected=rejected)


def _disagreement(centres: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """``(B, B)`` absolute differences between the balls' mutual distances here and in the reference."""
    here = np.linalg.norm(centres[:, None] - centres[None, :], axis=2)
    there = np.linalg.norm(reference[:, None] - reference[None, :], axis=2)
    return np.abs(here - there)


def _in_a_line(centres: np.ndarray, diameter_m: float) -> bool:
    spread = np.linalg.svd(centres - centres.mean(axis=0), compute_uv=False)
    return bool(spread[1] < 0.2 * diameter_m)
