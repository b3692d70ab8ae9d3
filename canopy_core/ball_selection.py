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
from dataclasses import dataclass, field, replace

import numpy as np

from canopy_core.balls import BallCandidate, Objection, ViewBallCandidates
from canopy_core.config import BallConfig
from canopy_core.errors import BallNotFound, RegistrationFailed
from canopy_core.ground import CAMERA_UP, GroundFrame, GroundPlane, horizontal_distance

__all__ = [
    "BallChoice",
    "Rejection",
    "ball_off_ground",
    "balls_off_ground",
    "balls_off_trunk",
    "check_ball_spacing",
    "choose_in_view",
    "describe_view",
    "far_ball",
    "no_trunk_round_balls",
    "select_balls",
]

_CANDIDATES_PER_COLOR = 4
"""The likeliest plausible spheres per colour and view that the joint choice considers (4³ triangles)."""
_CIRCLE_STEP_RADII = 0.25
"""Along a circle where a missing ball may lie, the surface support of a ball is weighed every this many ball
radii (a guess this close to a ball's centre finds most of its surface)."""
_CIRCLE_SLACK_M = 0.02
"""A circle's point is also tried this far out, in, up and down."""
_CIRCLE_TRIES = 6
"""Most places along a view's circles for one ball where a sphere is fitted (the best supported)."""
_CARRY_SD_M = 0.01
"""A ball carried onto this view by a pair of balls and the ground's up lands within about this of where it
lies: the views' ground normals agree within a degree, and the balls lie 0.6-1.2 m apart."""
_MAX_SHARED_PAIRS = 32
"""At most this many pairs of spheres that two views show the same distance apart are tried, likeliest first,
by the search where fragments meet. Each costs a sphere fit per place the third ball's colour gathers; a row
with many look-alikes of two colours pairs them by the thousand (13 225 pairs of 32 red and 54 yellow
spheres in one view and 20 and 53 in the other: over a quarter of an hour), where the balls' own pair is
among the likeliest few (at most 15 pairs in all on 30 simulated trees)."""
_ANCHORS_PER_VIEW = _CANDIDATES_PER_COLOR**3
"""The likeliest triangles of each view that place balls in the others (:func:`_anchors`): as many as the
first shortlists make. The searches add spheres to the shortlists, and every triangle of them placing balls
in every other view, which add more, ran away with three views (2099017: 44 198 triangles in one view after
five searches, and the measurement still running after a quarter of an hour)."""
_PLACEMENT_TOLERANCE_M = 0.05
"""A sphere found this close to where the other views place a ball is that ball: the placement errs by the
ground's unevenness under the balls and the plane's error, a few centimetres."""

_SharedPair = tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
"""Two spheres' centres in one view and the same two in another."""


@dataclass(frozen=True)
class Rejection:
    """A sphere not taken for a colour's ball, and why."""

    candidate: BallCandidate
    objection: Objection


@dataclass(frozen=True)
class BallChoice:
    """The balls chosen in one view, and why each other sphere was not taken, per colour.

    ``rejected`` maps each colour to its rejections, likeliest sphere first: its geometry's problem, too
    little of the colour, not resting on the ground (``floating``), the foot of something upright
    (``upright``), taken for another colour (``taken``),
    not at the other views' distances (``inconsistent``) or, in one view alone, less likely than the one
    chosen (``weaker``). A view described on its own (:func:`describe_view`) may lack a colour's ball:
    ``missing`` says why.
    """

    view: str
    chosen: dict[str, BallCandidate]
    rejected: dict[str, list[Rejection]]
    found_by_position: tuple[str, ...] = ()
    """Colours whose ball was found where the other views placed it, not by its own colour's votes."""
    placed_unseen: tuple[str, ...] = ()
    """Colours whose ball this view does not show at all: placed where the other views put it."""
    missing: dict[str, Objection] = field(default_factory=dict)


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


def far_ball(
    centres_m: np.ndarray, trunk_xy_m: np.ndarray, colors: Sequence[str], max_distance_m: float
) -> str | None:
    """The colour of the ball farthest from the trunk when it lies farther than ``max_distance_m`` from it
    (``centres_m`` and ``trunk_xy_m`` in the world frame), else None."""
    distance = np.linalg.norm(centres_m[:, :2] - trunk_xy_m, axis=1)
    far = int(np.argmax(distance))
    return colors[far] if distance[far] > max_distance_m else None


def balls_off_trunk(
    centres_m: np.ndarray, trunk_xy_m: np.ndarray, colors: Sequence[str], far: str
) -> RegistrationFailed:
    """The failure of balls that do not lie round the trunk, ``far`` (see :func:`far_ball`) the farthest.

    A look-alike that every view sees (an apple lying on the ground two metres away) agrees with itself
    across views, so the triangle check passes it; registration would still be sound, but the region of
    interest and the ground frame are centred on the balls, and the tree would be measured cut off.
    """
    distance = np.linalg.norm(centres_m[:, :2] - trunk_xy_m, axis=1)
    others = ", ".join(f"{color} {distance[i]:.2f} m" for i, color in enumerate(colors) if color != far)
    return RegistrationFailed(
        f"the {far} ball was found {distance[list(colors).index(far)]:.2f} m from the trunk ({others}), "
        "where the balls lie 0.3-0.8 m from it: something else of its colour was probably taken for it in "
        "every view, and no other sphere of its colour lies round the trunk",
        field="balls.max_trunk_distance_m",
        hint=f"check with `canopy balls --preview` what was taken for the {far} ball; lay the balls "
        "0.3-0.8 m from the trunk, in open view, and capture again",
    )


def no_trunk_round_balls(frame: GroundFrame) -> RegistrationFailed | None:
    """The failure of balls round which no trunk stands, or None when one does.

    The crew lays the balls round the trunk, so the trunk's low slice near their centre holds its bark,
    or the grass and weeds that hide it. When the slice there holds nothing at all
    (:attr:`GroundFrame.trunk_points` 0), the spheres taken for the balls lie out in the open, away from
    the tree: look-alikes on the ground that every view saw (straw or soil bumps a low-resolution camera
    sees as spheres). Their triangle agrees across the views and each lies near their own centre, which
    stands in for the trunk; the region of interest centred there cuts the tree off (a camera of 252 px
    focal length, 2080010: two look-alikes 1.1 and 2.4 m from the trunk, W 31 % narrow).
    """
    if frame.trunk_points > 0:
        return None
    return RegistrationFailed(
        "no trunk stands round the spheres taken for the balls (nothing rises at a trunk's height near "
        "their centre): they are probably things of the balls' colours lying away from the tree, which "
        "every view saw, and no other choice of spheres lies round the trunk",
        field="balls.max_trunk_distance_m",
        hint="check with `canopy balls --preview` what was taken for each ball; lay the balls 0.3-0.8 m "
        "from the trunk, in open view, and capture again",
    )


def ball_off_ground(frame: GroundFrame, colors: Sequence[str], radius_m: float) -> str | None:
    """The colour of the ball that lies off the ground round the balls, or None when they rest on it.

    The balls rest on the ground, so their centres' plane is the ground's, one radius up. When the ground
    found round them tilts from that plane by more than a slope between the balls allows and some ball's
    centre does not stand one radius above the floor right round it (:attr:`GroundFrame.on_ground`), a
    sphere taken for a ball is not resting there: a fallen apple or a fragment of one, whose centre stands
    lower than a ball's, tilts a plane through balls a few decimetres apart by tens of degrees. The ball
    named is the one whose height above its floor is farthest from a ball's (``radius_m``).
    """
    if frame.on_ground:
        return None
    off = np.abs(np.array(frame.ball_heights_m) - radius_m)
    return colors[int(np.argmax(off))]


def balls_off_ground(
    frame: GroundFrame, colors: Sequence[str], radius_m: float, off: str
) -> RegistrationFailed:
    """The failure of balls that do not rest on the ground round them, ``off`` (see
    :func:`ball_off_ground`) the one farthest from it."""
    height = frame.ball_heights_m[list(colors).index(off)]
    return RegistrationFailed(
        f"the balls do not rest on the ground round them (their plane tilts "
        f"{frame.tilt_from_ball_plane_deg:.0f} degrees from it): the {off} ball's centre stands "
        f"{height:.2f} m above the floor round it, where a ball's stands {radius_m:.2f} m. Something else of "
        "its colour (a "
        "fallen apple?) was probably taken for it, and no other sphere of its colour rests on the ground "
        "round the trunk",
        field="ground.max_tilt_from_balls_deg",
        hint=f"check with `canopy balls --preview` what was taken for the {off} ball; lay the balls on open "
        "ground, apart from fallen fruit, and capture again",
    )


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


def describe_view(
    view: ViewBallCandidates, config: BallConfig, *, ground: GroundPlane | None = None
) -> BallChoice:
    """One view's balls on its own, as far as they go: the likeliest combination of distinct plausible
    spheres if there is one, else per colour in turn its likeliest plausible sphere no earlier colour
    took; every other sphere with its reason, and why each colour without a ball has none. What
    ``canopy balls`` shows of a view when the views cannot be registered together."""
    shortlist = _shortlist(view, config, ground=ground)
    triangles = _assignments(shortlist, config)
    if triangles:
        chosen = dict(zip(config.colors, triangles[0][1], strict=True))
    else:
        chosen = {}
        for color in config.colors:
            free = [c for c in shortlist.plausible[color] if all(c is not o for o in chosen.values())]
            if free:
                chosen[color] = free[0]
    described = _describe(view, shortlist, chosen, config, [], alternative=_weaker())
    missing = {
        color: _missing_objection(view, shortlist, color, config)
        for color in config.colors
        if color not in chosen
    }
    return replace(described, missing=missing)


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
    views: Sequence[ViewBallCandidates],
    config: BallConfig,
    *,
    grounds: Sequence[GroundPlane | None],
    shared_ball_first: bool = False,
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
    shared_ball_first
        Seek two views' missing balls together about the ball they share (:func:`_search_about_shared_ball`)
        before any search that takes one view's evidence alone, not after them all: a second hypothesis,
        for when the surfaces refused the balls chosen first (the circles' fragments of clutter closing a
        triangle before the shared ball's turn was tried).

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
    per_view = [_assignments(shortlist, config) for shortlist in shortlists]
    rescued: list[list[BallCandidate]] = [[] for _ in views]
    # The likeliest triangles of each view place the balls in the others first, even where some combination
    # agrees already: a look-alike that both views see (an apple lying on the ground) agrees too, and must
    # compete with a ball one view sees whole and another only in part. Only if no combination agrees then,
    # each ball is sought at the distance another view puts it from a ball this view has (which may
    # complete a triangle that places the rest), even where look-alikes of its colour were found; if that
    # fails too, where the trunk and the one ball two views share place it; then a ball a view does not
    # show at all is placed, unseen, where two balls it shows and another view's triangle put it; then,
    # where no view has a triangle, a ball is sought where fragments of it in two views meet. The last
    # searches rescue captures every search before failed, and come last so that they cannot pre-empt one
    # that succeeds: two views' missing balls sought together where a turn about the one ball both show
    # lands each view's other ball on a ball of its colour in the other; and the balls sought at the
    # distances the other views' less likely pairs show (a look-alike may outscore a ball there).
    shared_ball = (_search_about_shared_ball, _search_where_placed)
    searches = (
        (
            _search_where_placed,
            *(shared_ball if shared_ball_first else ()),
            _search_on_circles,
            _search_where_placed,
            _search_round_trunk,
            _search_where_placed,
            _place_hidden,
            _search_by_pair,
            _search_where_placed,
            *(() if shared_ball_first else shared_ball),
            _search_on_circles_of_look_alikes,
            _search_where_placed,
        )
        if len(views) > 1 and len(config.colors) >= 3
        else ()
    )
    ups = [CAMERA_UP if ground is None else ground.normal for ground in grounds]
    placed: set[int] = set()  # ids of the spheres sought where other views' balls put them
    chosen = None if searches or not all(per_view) else _consistent_choice(per_view, ups, placed, config)
    for search in searches:
        found = search(views, shortlists, per_view, grounds, config)
        rescued = [before + more for before, more in zip(rescued, found, strict=True)]
        if search is not _search_by_pair:  # which finds a ball where two views' own fragments meet
            placed.update(id(candidate) for more in found for candidate in more)
        per_view = [_assignments(shortlist, config) for shortlist in shortlists]
        chosen = _consistent_choice(per_view, ups, placed, config) if all(per_view) else None
        if chosen is not None:
            break
    for view, shortlist, triangles in zip(views, shortlists, per_view, strict=True):
        if not triangles:
            raise _first_missing(view, shortlist, config)
    if chosen is None:  # then some view's likeliest triangle disagrees with the reference's: name the worst
        best = [np.array([c.fit.center_m for c in triangles[0][1]]) for triangles in per_view]
        worst = 1 + int(np.argmax([_disagreement(centres, best[0]).max() for centres in best[1:]]))
        raise _distance_error(
            views[worst].view, best[worst], best[0], config.colors, tolerance_m=config.max_distance_mismatch_m
        )
    return [
        _describe(
            view,
            shortlist,
            dict(zip(config.colors, triangle, strict=True)),
            config,
            found,
            alternative=Objection(
                "inconsistent", "not at the same distances from the other balls as in the other views"
            ),
        )
        for view, shortlist, triangle, found in zip(views, shortlists, chosen, rescued, strict=True)
    ]


def _search_where_placed(
    views: Sequence[ViewBallCandidates],
    shortlists: list[_Shortlist],
    per_view: list[list[tuple[float, tuple[BallCandidate, ...]]]],
    grounds: Sequence[GroundPlane | None],
    config: BallConfig,
) -> list[list[BallCandidate]]:
    """Look for each view's balls where the other views place them (:func:`_placements`): the likeliest
    ``_ANCHORS_PER_VIEW`` triangles of each other view do, not only the likeliest one (apples and straw may
    score above the balls themselves, and a triangle holding one places the missing ball wrong). A sphere
    found there (:meth:`ViewBallCandidates.sphere_near`) joins that colour's shortlist however little of its
    colour it showed. Each call adds at most ``_CANDIDATES_PER_COLOR`` spheres per view and colour, the
    likeliest anchors' first (:func:`_anchors`). Returns, per view, the spheres added."""
    added: list[list[BallCandidate]] = [[] for _ in views]
    anchors = _anchors(per_view, grounds)
    for target, (view, shortlist, ground) in enumerate(zip(views, shortlists, grounds, strict=True)):
        if ground is None:
            continue
        others = [(triangle, anchor_ground) for a, triangle, anchor_ground in anchors if a != target]
        for missing, color in enumerate(config.colors):
            known, found_here = shortlist.plausible[color], 0
            for estimate, _ in _placements(shortlist, ground, others, missing, config):
                if found_here == _CANDIDATES_PER_COLOR:
                    break
                if _listed_near(estimate, known, config.radius_m):
                    continue
                found = _sphere_where_placed(view, estimate, color, config)
                if found is not None:
                    known.append(found)
                    added[target].append(found)
                    found_here += 1
    return added


def _anchors(
    per_view: list[list[tuple[float, tuple[BallCandidate, ...]]]], grounds: Sequence[GroundPlane | None]
) -> list[tuple[int, tuple[BallCandidate, ...], GroundPlane | None]]:
    """The triangles that place balls in the other views: each view's likeliest ``_ANCHORS_PER_VIEW`` (the
    triangles come likeliest first), with the view's index and ground, rank by rank across the views (every
    view's likeliest, then every view's second...), so that with three views or more a cap on what one
    search adds is not spent on one view's weaker triangles before another view's likeliest."""
    return [
        (a, per_view[a][rank][1], grounds[a])
        for rank in range(_ANCHORS_PER_VIEW)
        for a in range(len(per_view))
        if rank < len(per_view[a])
    ]


def _search_on_circles(
    views: Sequence[ViewBallCandidates],
    shortlists: list[_Shortlist],
    per_view: list[list[tuple[float, tuple[BallCandidate, ...]]]],
    grounds: Sequence[GroundPlane | None],
    config: BallConfig,
    *,
    likeliest: bool = True,
) -> list[list[BallCandidate]]:
    """Look for each of a view's balls at the distance another view shows between it and a ball this view
    has: on a circle round that ball, at its height above the ground plane (:func:`_circles`, drawn from
    the other view's ``likeliest`` pair of spheres, or else its next likeliest pairs). A sphere
    found there (:meth:`ViewBallCandidates.sphere_near`, where the circle's points have the most surface
    support, :func:`_likeliest_on_circles`) joins the colour's shortlist.

    For views that share too few balls for any to hold a whole triangle (so nothing places the rest):
    the sphere found on the circle completes a triangle, which must then agree with the other views, or
    place their missing balls where spheres must be found in turn. A colour whose likely spheres are all
    look-alikes (apples, straw) is sought too: the ball itself may be the fragment no search found; but
    then the sphere must show the colour's hue (``min_color_score``), as a ball in shade does, where a
    colour with no likely sphere at all takes any sphere (a ball nearly black in deep shade).
    Returns, per view, the spheres added.
    """
    del per_view  # the circles need pairs of balls, not whole triangles
    added: list[list[BallCandidate]] = [[] for _ in views]
    for target, (view, shortlist, ground) in enumerate(zip(views, shortlists, grounds, strict=True)):
        if ground is None:
            continue
        for color in config.colors:
            look_alikes = bool(shortlist.plausible[color])
            tries = [
                found
                for circle in _circles(
                    target, color, shortlists, grounds, ground, config, likeliest=likeliest
                )
                for found in _likeliest_on_circles(view, circle, color, ground, config)
            ]
            for estimate, reach, centre in tries:
                found = view.sphere_near(estimate, color, config)
                if found is None or (look_alikes and found.color_scores[color] < config.min_color_score):
                    continue
                if _listed_near(found.fit.center_m, shortlist.plausible[color], config.radius_m):
                    continue
                if abs(float(np.linalg.norm(found.fit.center_m - centre)) - reach) < (
                    config.max_distance_mismatch_m
                ):
                    shortlist.plausible[color].append(found)
                    added[target].append(found)
    return added


def _search_round_trunk(
    views: Sequence[ViewBallCandidates],
    shortlists: list[_Shortlist],
    per_view: list[list[tuple[float, tuple[BallCandidate, ...]]]],
    grounds: Sequence[GroundPlane | None],
    config: BallConfig,
) -> list[list[BallCandidate]]:
    """Look for each of a view's balls where the one ball it shares with another view, the ground and the
    trunk place it: the ball shared fixes where, the ground's up fixes two turns and the trunk, seen in both
    views (:func:`view_trunk_foot`), the turn about the up. The other view's ball is carried by that rigid
    motion, and a sphere found there (:meth:`ViewBallCandidates.sphere_near`) joins the colour's shortlist.

    For views that each see two balls well but not the same two, their third a fragment 4 m away that
    grass and leaves outscore all along the circle round the shared ball (:func:`_search_on_circles`): the
    trunk narrows the circle to one place. The ball's distance from the trunk must agree between the views
    (``max_trunk_reach_mismatch_m``), else they found different trunks, or a post, and nothing is placed.
    Every likely sphere of the shared colour is tried in both views, each with the trunk found round it:
    a look-alike may outscore the shared ball in either (2048017: straw in both). Returns, per view, the
    spheres added."""
    del per_view  # one shared ball suffices here

    def foot(index: int, ball: BallCandidate) -> np.ndarray | None:
        """The trunk's foot in view ``index``, sought round ``ball``."""
        ground, scene = grounds[index], views[index].scene
        if ground is None or scene is None:
            return None
        return scene.trunk_foot(ground, ball.fit.center_m, config.max_trunk_distance_m)

    added: list[list[BallCandidate]] = [[] for _ in views]
    for target, (view, shortlist, ground) in enumerate(zip(views, shortlists, grounds, strict=True)):
        for color, anchor, shared in itertools.product(config.colors, range(len(views)), config.colors):
            anchor_ground = grounds[anchor]
            if (
                anchor == target
                or color == shared
                or ground is None
                or anchor_ground is None
                or not shortlists[anchor].plausible[color]
            ):
                continue
            wanted = shortlists[anchor].plausible[color][0].fit.center_m
            # Every likely sphere of the shared colour, in both views: a look-alike may outscore the ball.
            pairs = itertools.product(
                list(shortlists[anchor].plausible[shared]), list(shortlist.plausible[shared])
            )
            for seen, ball in pairs:
                there, here = foot(anchor, seen), foot(target, ball)
                if there is None or here is None:
                    continue
                estimate = _carried_round_trunk(
                    wanted,
                    (seen.fit.center_m, there, anchor_ground),
                    (ball.fit.center_m, here, ground),
                    config,
                )
                if estimate is None or _listed_near(estimate, shortlist.plausible[color], config.radius_m):
                    continue
                found = _sphere_where_placed(view, estimate, color, config)
                if found is not None:
                    shortlist.plausible[color].append(found)
                    added[target].append(found)
    return added


def _search_on_circles_of_look_alikes(
    views: Sequence[ViewBallCandidates],
    shortlists: list[_Shortlist],
    per_view: list[list[tuple[float, tuple[BallCandidate, ...]]]],
    grounds: Sequence[GroundPlane | None],
    config: BallConfig,
) -> list[list[BallCandidate]]:
    """:func:`_search_on_circles` on the circles the other views' next likeliest pairs of spheres draw, for
    when a look-alike outscores a ball there and every other search failed (2088010: views/1's likeliest
    red sphere an apple 1.35 m from the red ball, and views/2 showing the red ball whole, its yellow and
    blue balls half hidden). Last: each circle drawn from a look-alike's pair passes clutter where a
    fragment may be found and close a triangle that agrees by construction, so these circles must not
    pre-empt the stronger searches. Returns, per view, the spheres added."""
    return _search_on_circles(views, shortlists, per_view, grounds, config, likeliest=False)


def _search_about_shared_ball(
    views: Sequence[ViewBallCandidates],
    shortlists: list[_Shortlist],
    per_view: list[list[tuple[float, tuple[BallCandidate, ...]]]],
    grounds: Sequence[GroundPlane | None],
    config: BallConfig,
) -> list[list[BallCandidate]]:
    """Look for two views' missing balls together, where the one ball both show and their grounds leave the
    pose open by a turn about that ball's vertical: each view's ball of another colour, carried by the
    turn, must land on a ball of its colour in the other view (:func:`_places_both_supported`); spheres
    are fitted at both places (:meth:`ViewBallCandidates.sphere_near`), each kept if it lies as far from
    the shared ball as its colour's ball in the other view, and found together they join their views'
    shortlists.

    For views that each see two balls whole but not the same two, the third a fragment in each (2088013:
    views/1 shows the yellow and blue balls, views/2 the red and blue, each the other a third hidden in
    grass 4 m away): the search on circles (:func:`_search_on_circles`) weighs each view alone, and clutter
    along either circle outscores a fragment; two fragments at one turn are a pair clutter seldom makes. A
    colour of which a view has likely spheres already (look-alikes) is taken only with its hue
    (``min_color_score``). The shared ball is each view's likeliest sphere of its colour, seen well in
    both (2088038: a yellow look-alike 2.5 m off, taken for it, placed clutter in both views at one turn);
    every likely sphere of the other two colours takes part, the likeliest ``_MAX_SHARED_PAIRS``
    combinations first. Returns, per view, the spheres added."""
    del per_view  # one shared ball and one more per view suffice
    added: list[list[BallCandidate]] = [[] for _ in views]
    fitted: dict[tuple[int, str, bytes], BallCandidate | None] = {}

    def sphere_at(
        index: int, estimate: np.ndarray, color: str, *, reach: tuple[np.ndarray, np.ndarray, np.ndarray]
    ) -> BallCandidate | None:
        """The sphere near ``estimate`` in view ``index`` if it lies as far from the view's shared ball as
        the other view's ball of ``color`` from its (``reach``: this view's shared ball, the other's ball
        and the other's shared ball), within ``max_distance_mismatch_m``; the choice across views then
        judges the whole triangle."""
        key = (index, color, np.round(estimate, 3).tobytes())
        if key not in fitted:
            found = views[index].sphere_near(estimate, color, config)
            look_alikes = bool(shortlists[index].plausible[color])
            if found is not None and look_alikes and found.color_scores[color] < config.min_color_score:
                found = None
            fitted[key] = found
        found = fitted[key]
        shared_here, ball_there, shared_there = reach
        if (
            found is None
            or abs(
                float(np.linalg.norm(found.fit.center_m - shared_here))
                - float(np.linalg.norm(ball_there - shared_there))
            )
            >= config.max_distance_mismatch_m
        ):
            return None
        return found

    for first, second in itertools.combinations(range(len(views)), 2):
        pair_grounds = (grounds[first], grounds[second])
        if pair_grounds[0] is None or pair_grounds[1] is None:
            continue
        for shared, mine, theirs in itertools.permutations(config.colors, 3):
            here, there = shortlists[first].plausible, shortlists[second].plausible
            # The ball both show is each view's likeliest sphere of its colour, the pivot of every turn: a
            # look-alike of its colour taken for it turns the other balls onto clutter.
            combinations = _likeliest_combinations(
                [
                    (here[mine], mine),
                    (there[theirs], theirs),
                    (here[shared][:1], shared),
                    (there[shared][:1], shared),
                ],
                config,
            )
            for own, other, shared_here, shared_there in combinations:
                if min(np.linalg.norm(own - shared_here), np.linalg.norm(other - shared_there)) < (
                    config.diameter_m
                ):
                    continue
                for place_first, place_second in _places_both_supported(
                    (views[first], views[second]),
                    (pair_grounds[0], pair_grounds[1]),
                    (shared_here, shared_there),
                    (own, other),
                    (theirs, mine),
                    config,
                ):
                    found_first = sphere_at(
                        first, place_first, theirs, reach=(shared_here, other, shared_there)
                    )
                    found_second = (
                        None
                        if found_first is None
                        else sphere_at(second, place_second, mine, reach=(shared_there, own, shared_here))
                    )
                    if found_first is None or found_second is None:
                        continue
                    _shortlist_new(shortlists, added, first, theirs, found_first, config)
                    _shortlist_new(shortlists, added, second, mine, found_second, config)
    return added


def _likeliest_combinations(
    options: list[tuple[list[BallCandidate], str]], config: BallConfig
) -> list[tuple[np.ndarray, ...]]:
    """The centres of each combination of one sphere from each of ``options`` (likely spheres, and the
    colour they are scored for), seen (not placed unseen: those carry no surface), the likeliest
    ``_MAX_SHARED_PAIRS`` by the product of their scores."""
    scored = [
        [(c.fit.center_m, c.score(color, radius_m=config.radius_m)) for c in spheres if not c.unseen]
        for spheres, color in options
    ]
    combinations = [
        (float(np.prod([score for _, score in combination])), tuple(centre for centre, _ in combination))
        for combination in itertools.product(*scored)
    ]
    combinations.sort(key=lambda entry: -entry[0])
    return [centres for _, centres in combinations[:_MAX_SHARED_PAIRS]]


def _places_both_supported(
    views: tuple[ViewBallCandidates, ViewBallCandidates],
    grounds: tuple[GroundPlane, GroundPlane],
    shared: tuple[np.ndarray, np.ndarray],
    own: tuple[np.ndarray, np.ndarray],
    colors: tuple[str, str],
    config: BallConfig,
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Where two views' balls land in each other under the turns about a shared ball's vertical that both
    places support best.

    The shared ball's centres (``shared``, in each view) and the grounds' normals fix all of the motion
    from the first view to the second but the turn about that vertical. Under each turn (every
    ``_CIRCLE_STEP_RADII`` radii at the farther of the two balls carried), the second view's own ball
    (``own[1]``) lands in the first view and the first's (``own[0]``) in the second; each place is weighed
    by the surface support of a ball of its colour (``colors``: the first view's sought colour, then the
    second's) in its view, also ``_CIRCLE_SLACK_M`` higher and lower (the floor is uneven). The turns
    whose weaker place has any support (more points on a ball's surface there than inside it), best
    first, at most ``_CIRCLE_TRIES``, each placing the first view's ball at least a radius from a better
    turn's; per turn, the places. Any support, not ``min_completeness_where_placed``: a guess centimetres
    off a fragment's centre sees less of it than the sphere fitted there holds (2088013: the red ball's
    third in grass supports 0.11 at the turn that places it 5 cm off, and the sphere fitted there is the
    ball); the fits decide."""
    frames = tuple(_level_frame(ground.normal) for ground in grounds)
    reach = max(
        float(np.linalg.norm((frames[0].T @ (own[0] - shared[0]))[:2])),
        float(np.linalg.norm((frames[1].T @ (own[1] - shared[1]))[:2])),
    )
    if reach <= config.radius_m:
        return []
    angles = np.arange(0.0, 2 * np.pi, _CIRCLE_STEP_RADII * config.radius_m / reach)
    cosines, sines = np.cos(angles), np.sin(angles)
    # Level coordinates of each view's own ball about the shared one, turned by each angle into the other's.
    local_first = frames[0].T @ (own[0] - shared[0])
    local_second = frames[1].T @ (own[1] - shared[1])
    into_second = np.column_stack(
        [
            cosines * local_first[0] - sines * local_first[1],
            sines * local_first[0] + cosines * local_first[1],
            np.full(angles.size, local_first[2]),
        ]
    )
    into_first = np.column_stack(
        [
            cosines * local_second[0] + sines * local_second[1],
            -sines * local_second[0] + cosines * local_second[1],
            np.full(angles.size, local_second[2]),
        ]
    )
    places = (shared[0] + into_first @ frames[0].T, shared[1] + into_second @ frames[1].T)
    supports, best_places = [], []
    for view, ground, place, color in zip(views, grounds, places, colors, strict=True):
        up = ground.normal / np.linalg.norm(ground.normal)
        shifted = np.concatenate([place + shift * up for shift in (0.0, -_CIRCLE_SLACK_M, _CIRCLE_SLACK_M)])
        support = view.surface_support(shifted, config, color=color, ground=ground).reshape(3, -1)
        best = support.argmax(axis=0)
        supports.append(support.max(axis=0))
        best_places.append(shifted.reshape(3, -1, 3)[best, np.arange(angles.size)])
    weaker = np.minimum(supports[0], supports[1])
    chosen: list[tuple[np.ndarray, np.ndarray]] = []
    for index in np.argsort(-weaker, kind="stable"):
        if weaker[index] <= 0.0 or len(chosen) == _CIRCLE_TRIES:
            break
        if all(np.linalg.norm(best_places[0][index] - first) >= config.radius_m for first, _ in chosen):
            chosen.append((best_places[0][index], best_places[1][index]))
    return chosen


def _level_frame(up: np.ndarray) -> np.ndarray:
    """An orthonormal frame (columns) whose third axis is ``up``: two level directions, then up."""
    up = up / np.linalg.norm(up)
    along = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    along /= np.linalg.norm(along)
    return np.column_stack([along, np.cross(up, along), up])


def _place_hidden(
    views: Sequence[ViewBallCandidates],
    shortlists: list[_Shortlist],
    per_view: list[list[tuple[float, tuple[BallCandidate, ...]]]],
    grounds: Sequence[GroundPlane | None],
    config: BallConfig,
) -> list[list[BallCandidate]]:
    """Place each of a view's balls that no search found where the other views' triangles, carried onto a
    pair of this view's spheres and its ground's up (:func:`_placements`), put it, as a ball the view does
    not show (:meth:`ViewBallCandidates.hidden_ball_at`: the view must not see through that place).

    For a ball hidden behind the trunk or weeds, or lying outside the image, in one view: two balls and the
    ground fix the view's pose (two points and a direction fix a rigid motion), so the ball need not be
    seen. A placed ball scores nothing, so it completes a triangle only where no sphere does; it is no
    anchor for ICP, which then checks the pose against the surfaces, and no chosen pair of triangles may
    rest on fewer than two balls both views show (:func:`_consistent_choice`). At most
    ``_CANDIDATES_PER_COLOR`` places per view and colour, the likeliest anchors' first (:func:`_anchors`).
    Returns, per view, the balls placed."""
    anchors = [
        (a, triangle, ground)
        for a, triangle, ground in _anchors(per_view, grounds)
        if not any(c.unseen for c in triangle)
    ]
    wanted: list[list[tuple[str, np.ndarray, np.ndarray]]] = [[] for _ in views]
    for target, (shortlist, ground) in enumerate(zip(shortlists, grounds, strict=True)):
        if ground is None:
            continue
        others = [(triangle, anchor_ground) for a, triangle, anchor_ground in anchors if a != target]
        for missing, color in enumerate(config.colors):
            for estimate, carried in _placements(shortlist, ground, others, missing, config):
                spread = float(np.trace(carried.fit.center_covariance_m2)) / 3 + _CARRY_SD_M**2
                wanted[target].append((color, estimate, spread * np.eye(3)))
    added: list[list[BallCandidate]] = [[] for _ in views]
    for target, (view, shortlist, ground) in enumerate(zip(views, shortlists, grounds, strict=True)):
        for color, estimate, covariance in wanted[target]:
            known = shortlist.plausible[color]
            if sum(c.unseen for c in known) >= _CANDIDATES_PER_COLOR or _listed_near(
                estimate, known, config.radius_m
            ):
                continue
            placed = view.hidden_ball_at(estimate, covariance, config)
            if placed is not None and _floating(placed, ground, config) is None:
                known.append(placed)
                added[target].append(placed)
    return added


def _search_by_pair(
    views: Sequence[ViewBallCandidates],
    shortlists: list[_Shortlist],
    per_view: list[list[tuple[float, tuple[BallCandidate, ...]]]],
    grounds: Sequence[GroundPlane | None],
    config: BallConfig,
) -> list[list[BallCandidate]]:
    """Look for a ball that no view holds a sphere of, where two views both show fragments of it: each
    place one view's points of its colour gather (:meth:`ViewBallCandidates.places_of`, within twice
    ``max_trunk_distance_m`` of the pair) where a sphere is found (:meth:`ViewBallCandidates.sphere_near`)
    is carried onto the other view by the rigid motion that lays a pair of balls both views show, and
    the ground's up, on each other's (:func:`_pair_frame`); a sphere must be found there too, within
    ``_PLACEMENT_TOLERANCE_M``. Both then join their views' shortlists.

    For a third ball a third of which each view sees at 4 m: no triangle places it, and no view has it to
    draw a circle round (2045012: the blue ball, 23-25 points in each view). Two fragments of a sphere
    found at one place of the floor by two views are a ball where one alone is not. Returns, per view, the
    spheres added."""
    del per_view  # the pair both views show places the ball, not a triangle
    added: list[list[BallCandidate]] = [[] for _ in views]
    fitted: dict[tuple[int, str, bytes], BallCandidate | None] = {}  # pairs near each other share places

    def sphere_at(index: int, guess: np.ndarray, color: str) -> BallCandidate | None:
        key = (index, color, guess.tobytes())
        if key not in fitted:
            fitted[key] = views[index].sphere_near(guess, color, config)
        return fitted[key]

    for color in config.colors:
        others = [other for other in config.colors if other != color][:2]
        for source, target in itertools.permutations(range(len(views)), 2):
            source_ground, target_ground = grounds[source], grounds[target]
            if source_ground is None or target_ground is None:
                continue
            for there, here in _shared_pairs(shortlists[source], shortlists[target], others, config):
                frame_there = _pair_frame(there[0], there[1], source_ground.normal)
                frame_here = _pair_frame(here[0], here[1], target_ground.normal)
                if frame_there is None or frame_here is None:
                    continue
                middle = (there[0] + there[1]) / 2
                for guess in views[source].places_of(
                    color, config, around_m=middle, reach_m=2 * config.max_trunk_distance_m
                ):
                    seen = sphere_at(source, guess, color)
                    if seen is None or seen.color_scores[color] < config.min_color_score:
                        continue
                    carried = (here[0] + here[1]) / 2 + frame_here @ (
                        frame_there.T @ (seen.fit.center_m - middle)
                    )
                    found = _sphere_where_placed(views[target], carried, color, config)
                    if found is None:
                        continue
                    _shortlist_new(shortlists, added, source, color, seen, config)
                    _shortlist_new(shortlists, added, target, color, found, config)
    return added


def _sphere_where_placed(
    view: ViewBallCandidates, estimate_m: np.ndarray, color: str, config: BallConfig
) -> BallCandidate | None:
    """The sphere :meth:`ViewBallCandidates.sphere_near` finds near where a ball is placed, if it lies
    within ``_PLACEMENT_TOLERANCE_M`` of that place; None otherwise."""
    found = view.sphere_near(estimate_m, color, config)
    if found is None or np.linalg.norm(found.fit.center_m - estimate_m) >= _PLACEMENT_TOLERANCE_M:
        return None
    return found


def _shortlist_new(
    shortlists: list[_Shortlist],
    added: list[list[BallCandidate]],
    index: int,
    color: str,
    sphere: BallCandidate,
    config: BallConfig,
) -> None:
    """Put ``sphere`` on view ``index``'s shortlist of ``color`` and among the view's ``added`` spheres,
    unless a sphere there lies within a radius of it (:func:`_listed_near`)."""
    known = shortlists[index].plausible[color]
    if not _listed_near(sphere.fit.center_m, known, config.radius_m):
        known.append(sphere)
        added[index].append(sphere)


def _listed_near(centre_m: np.ndarray, listed: Sequence[BallCandidate], radius_m: float) -> bool:
    """Whether a sphere of ``listed`` lies within a ball's radius of ``centre_m``: the same ball, already
    on the shortlist, where a search would add it twice."""
    return any(np.linalg.norm(c.fit.center_m - centre_m) < radius_m for c in listed)


def _shared_pairs(
    first: _Shortlist, second: _Shortlist, colors: list[str], config: BallConfig
) -> list[_SharedPair]:
    """The pairs of likely spheres of two ``colors`` in two views that stand the same distance apart in
    both (within ``max_distance_mismatch_m``): each a pair of centres in the first view and in the
    second, in the order found; at most ``_MAX_SHARED_PAIRS`` of them, those whose four spheres' scores have
    the greatest product. Balls placed unseen take no part: the pair must be seen in both views."""
    if len(colors) < 2:
        return []

    def seen(shortlist: _Shortlist, color: str) -> list[tuple[BallCandidate, float]]:
        return [
            (c, c.score(color, radius_m=config.radius_m)) for c in shortlist.plausible[color] if not c.unseen
        ]

    matched: list[tuple[float, int, _SharedPair]] = []
    for (a, score_a), (b, score_b) in itertools.product(seen(first, colors[0]), seen(first, colors[1])):
        apart = float(np.linalg.norm(a.fit.center_m - b.fit.center_m))
        for (c, score_c), (d, score_d) in itertools.product(seen(second, colors[0]), seen(second, colors[1])):
            if (
                abs(float(np.linalg.norm(c.fit.center_m - d.fit.center_m)) - apart)
                <= config.max_distance_mismatch_m
            ):
                pairs = ((a.fit.center_m, b.fit.center_m), (c.fit.center_m, d.fit.center_m))
                matched.append((score_a * score_b * score_c * score_d, len(matched), pairs))
    likeliest = sorted(matched, key=lambda entry: (-entry[0], entry[1]))[:_MAX_SHARED_PAIRS]
    return [pairs for _, _, pairs in sorted(likeliest, key=lambda entry: entry[1])]


def _carried_round_trunk(
    wanted: np.ndarray,
    there: tuple[np.ndarray, np.ndarray, GroundPlane],
    here: tuple[np.ndarray, np.ndarray, GroundPlane],
    config: BallConfig,
) -> np.ndarray | None:
    """Where ``wanted`` (a ball's centre in another view) lies in this view, carried by the rigid motion that
    lays the shared ball, the ground's up and the trunk of ``there`` (the shared ball's centre, the trunk's
    foot and the ground plane, in the other view) on those of ``here``; None when the shared ball's
    distance from the trunk differs between the views by more than ``max_trunk_reach_mismatch_m``."""
    (seen, foot_there, ground_there), (ball, foot_here, ground_here) = there, here
    reach_there = float(horizontal_distance(seen[None], foot_there, ground_there.normal)[0])
    reach_here = float(horizontal_distance(ball[None], foot_here, ground_here.normal)[0])
    if abs(reach_there - reach_here) > config.max_trunk_reach_mismatch_m:
        return None
    frame_there = _pair_frame(seen, _at_height_of(foot_there, seen, ground_there), ground_there.normal)
    frame_here = _pair_frame(ball, _at_height_of(foot_here, ball, ground_here), ground_here.normal)
    if frame_there is None or frame_here is None:
        return None
    return ball + frame_here @ (frame_there.T @ (wanted - seen))


def _at_height_of(foot: np.ndarray, point: np.ndarray, ground: GroundPlane) -> np.ndarray:
    """The point of the vertical line through ``foot`` (on ``ground``) at ``point``'s height above it."""
    normal = ground.normal / np.linalg.norm(ground.normal)
    return foot + ((point - foot) @ normal) * normal


def _likeliest_on_circles(
    view: ViewBallCandidates,
    points: list[tuple[np.ndarray, float, np.ndarray]],
    color: str,
    ground: GroundPlane,
    config: BallConfig,
) -> list[tuple[np.ndarray, float, np.ndarray]]:
    """The points of one circle (see :func:`_circles`) worth fitting a sphere at, each moved within
    ``_CIRCLE_SLACK_M`` (out, in, up, down: the circle errs by the other view's fits and the ground's
    unevenness) to where a ``color`` ball's surface support (:meth:`ViewBallCandidates.surface_support`) is
    best; those reaching ``config.min_completeness_where_placed``, best first, each at least a radius from a
    better one, at most ``_CIRCLE_TRIES``. Each circle has its own tries: a circle drawn from a look-alike
    another view took for a ball passes grass and leaves that may support a ball's surface better than the
    right circle's ball half hidden."""
    if not points:
        return []
    normal = ground.normal / np.linalg.norm(ground.normal)
    shifts = np.array([np.zeros(3), -_CIRCLE_SLACK_M * normal, _CIRCLE_SLACK_M * normal])
    on_circle = np.array([point for point, _, _ in points])
    outward = on_circle - np.array([centre for _, _, centre in points])
    # Row by row, as one point's dot product and norm round (a whole array's go through other routines).
    outward -= np.array([row @ normal for row in outward])[:, None] * normal
    outward /= np.maximum(np.array([np.linalg.norm(row) for row in outward]), 1e-9)[:, None]
    # Every point moved out, in or not at all, and up, down or not at all: nine rows of len(points) each.
    radial_steps = np.array([0.0, -1.0, 1.0])[:, None, None, None] * _CIRCLE_SLACK_M * outward
    estimates = ((on_circle + shifts[:, None, :])[None] + radial_steps).reshape(-1, 3)
    support = view.surface_support(estimates, config, color=color, ground=ground)
    best = support.reshape(-1, len(points)).argmax(axis=0)
    support = support.reshape(-1, len(points)).max(axis=0)
    chosen: list[tuple[np.ndarray, float, np.ndarray]] = []
    for index in np.argsort(-support, kind="stable"):
        if support[index] < config.min_completeness_where_placed or len(chosen) == _CIRCLE_TRIES:
            break
        estimate = estimates[best[index] * len(points) + index]
        if all(np.linalg.norm(estimate - point) >= config.radius_m for point, _, _ in chosen):
            chosen.append((estimate, points[index][1], points[index][2]))
    return chosen


def _circles(
    target: int,
    color: str,
    shortlists: list[_Shortlist],
    grounds: Sequence[GroundPlane | None],
    ground: GroundPlane,
    config: BallConfig,
    *,
    likeliest: bool,
) -> list[list[tuple[np.ndarray, float, np.ndarray]]]:
    """Circles to look for view ``target``'s ``color`` ball on: for each ball this view has (its likeliest
    sphere) and a pair of spheres another view shows of that colour and ``color``, the circle of the
    points at the pair's distance from it, at the height above this view's ground plane that the other
    view's ground puts it relative to that ball; sampled every ``_CIRCLE_STEP_RADII`` radii. Each point
    comes with the distance it must keep from the ball's centre and that centre.

    The pair is the other view's ``likeliest`` spheres of the two colours, or else its next likeliest
    pairs (by the product of their scores, up to ``_CANDIDATES_PER_COLOR`` in all): a look-alike (a fallen
    apple, straw) may outscore a ball there, and the circle drawn from it misses the ball. Not every pair:
    each circle costs up to ``_CIRCLE_TRIES`` sphere fits, and a row of look-alikes pairs them by the
    dozen."""
    axis_u, axis_v, normal = _level_frame(ground.normal).T
    circles: list[list[tuple[np.ndarray, float, np.ndarray]]] = []
    for other, (anchor, anchor_ground) in enumerate(zip(shortlists, grounds, strict=True)):
        if other == target:
            continue
        for known in config.colors:
            if known == color or not shortlists[target].plausible[known]:
                continue
            if not anchor.plausible[color] or not anchor.plausible[known]:
                continue
            centre = shortlists[target].plausible[known][0].fit.center_m
            first = (anchor.plausible[color][0], anchor.plausible[known][0])
            pairs = [first] if likeliest else _next_likeliest_pairs(anchor, color, known, first, config)
            for wanted, seen in pairs:
                reach = float(np.linalg.norm(wanted.fit.center_m - seen.fit.center_m))
                rise = (
                    0.0
                    if anchor_ground is None
                    else anchor_ground.height_of(wanted.fit.center_m)
                    - anchor_ground.height_of(seen.fit.center_m)
                )
                if reach <= abs(rise):
                    continue
                middle = centre + rise * normal
                spread = float(np.sqrt(reach**2 - rise**2))
                angles = np.arange(0.0, 2 * np.pi, _CIRCLE_STEP_RADII * config.radius_m / spread)
                circles.append(
                    [
                        (middle + spread * (np.cos(a) * axis_u + np.sin(a) * axis_v), reach, centre)
                        for a in angles
                    ]
                )
    return circles


def _next_likeliest_pairs(
    anchor: _Shortlist,
    color: str,
    known: str,
    first: tuple[BallCandidate, BallCandidate],
    config: BallConfig,
) -> list[tuple[BallCandidate, BallCandidate]]:
    """A view's pairs of likely spheres of ``color`` and ``known`` after its likeliest pair ``first``, two
    different spheres each, by the product of their scores, ``_CANDIDATES_PER_COLOR`` pairs with ``first``."""
    pairs = [
        (wanted, seen)
        for wanted, seen in itertools.product(anchor.plausible[color], anchor.plausible[known])
        if wanted is not seen and not (wanted is first[0] and seen is first[1])
    ]
    pairs.sort(
        key=lambda pair: (
            -pair[0].score(color, radius_m=config.radius_m) * pair[1].score(known, radius_m=config.radius_m)
        )
    )
    return pairs[: _CANDIDATES_PER_COLOR - 1]


def _placements(
    shortlist: _Shortlist,
    ground: GroundPlane,
    anchors: list[tuple[tuple[BallCandidate, ...], GroundPlane | None]],
    missing: int,
    config: BallConfig,
) -> list[tuple[np.ndarray, BallCandidate]]:
    """Where the other views place one view's ball of colour index ``missing``: one point per anchor and
    pair of this view's spheres for the other two colours that stand at the anchor's distance apart, each
    with the anchor's ball carried there.

    The balls do not move: a triangle found whole in another view (an anchor) is carried onto the pair by
    the rigid motion that lays its two balls on the pair's and its ground's up on this view's (two points
    and a direction fix a rigid motion). Both grounds are fitted on metres of floor round the balls, so
    their normals agree within a degree or so, which moves the ball placed 0.6 m away by a centimetre;
    and, unlike a guess of its height above this view's plane (which the floor's undulation under the
    balls puts centimetres off, and two circles meeting at a slant turn into several more along the
    floor), the motion keeps the triangle's turn: no mirror image.
    """
    others = [i for i in range(len(config.colors)) if i != missing][:2]
    up = ground.normal / np.linalg.norm(ground.normal)
    placed = []
    for triangle, anchor_ground in anchors:
        centres = np.array([c.fit.center_m for c in triangle])
        anchor_up = CAMERA_UP if anchor_ground is None else anchor_ground.normal
        there = _pair_frame(centres[others[0]], centres[others[1]], anchor_up)
        if there is None:
            continue
        in_pair_frame = there.T @ (centres[missing] - (centres[others[0]] + centres[others[1]]) / 2)
        apart = float(np.linalg.norm(centres[others[0]] - centres[others[1]]))
        pairs = itertools.product(*(shortlist.plausible[config.colors[i]] for i in others))
        for first, second in pairs:
            a, b = first.fit.center_m, second.fit.center_m
            if abs(float(np.linalg.norm(a - b)) - apart) > config.max_distance_mismatch_m:
                continue
            here = _pair_frame(a, b, up)
            if here is not None:
                placed.append(((a + b) / 2 + here @ in_pair_frame, triangle[missing]))
    return placed


def _pair_frame(a: np.ndarray, b: np.ndarray, up: np.ndarray) -> np.ndarray | None:
    """The orthonormal frame (columns) of a pair of balls: along from ``a`` to ``b``, then ``up`` made square
    to it, then their cross product; None when ``up`` runs along the pair."""
    along = (b - a) / max(float(np.linalg.norm(b - a)), 1e-9)
    square = up - (up @ along) * along
    length = float(np.linalg.norm(square))
    if length < 1e-6:
        return None
    square /= length
    return np.column_stack([along, square, np.cross(along, square)])


@dataclass(frozen=True)
class _Shortlist:
    """Per colour, the plausible spheres (likeliest first, at most ``_CANDIDATES_PER_COLOR``) and the
    others with why each was refused."""

    plausible: dict[str, list[BallCandidate]]
    refused: dict[str, list[Rejection]]


def _shortlist(view: ViewBallCandidates, config: BallConfig, *, ground: GroundPlane | None) -> _Shortlist:
    plausible: dict[str, list[BallCandidate]] = {}
    refused: dict[str, list[Rejection]] = {}
    for color in config.colors:
        plausible[color], refused[color] = [], []
        for candidate in view.ranked(color, config):
            objection = (
                candidate.objection(color, config)
                or _floating(candidate, ground, config)
                or _under_something(candidate, view, ground, config)
            )
            if objection is None and len(plausible[color]) < _CANDIDATES_PER_COLOR:
                plausible[color].append(candidate)
            else:
                refused[color].append(Rejection(candidate, objection or _weaker()))
    return _Shortlist(plausible=plausible, refused=refused)


def _floating(candidate: BallCandidate, ground: GroundPlane | None, config: BallConfig) -> Objection | None:
    """Why a sphere is not resting on the ground, or None when it is (or no ground is known)."""
    if ground is None:
        return None
    gap_m = ground.height_of(candidate.fit.center_m) - config.radius_m
    if gap_m <= config.max_ground_gap_m:
        return None
    return Objection(
        "floating",
        f"a sphere {candidate.range_m:.1f} m away stands {gap_m:.2f} m above the ground, where a calibration "
        "ball rests on it (an apple in the crown?)",
        "Lay the ball on the ground, in view",
    )


def _under_something(
    candidate: BallCandidate, view: ViewBallCandidates, ground: GroundPlane | None, config: BallConfig
) -> Objection | None:
    """Why a sphere is the foot of something upright rather than a ball lying on the ground, or None when
    nothing stands over it (``config.max_points_over``; or no ground or points are known)."""
    if ground is None or view.scene is None or candidate.unseen:
        return None
    over = view.scene.points_over(candidate.fit.center_m, ground.normal, config.radius_m)
    if over <= config.max_points_over * candidate.expected_points:
        return None
    return Objection(
        "upright",
        f"a sphere {candidate.range_m:.1f} m away has {over} points standing right over it, where a ball of "
        f"{candidate.expected_points:.0f} pixels lying on the ground has open air: the foot of something "
        "upright (a post, a stake)",
        "Lay the ball in open ground, away from posts",
    )


def _weaker() -> Objection:
    return Objection("weaker", "less likely than the sphere chosen")


def _missing_objection(
    view: ViewBallCandidates, shortlist: _Shortlist, color: str, config: BallConfig
) -> Objection:
    """Why a view has no plausible sphere for ``color``: the likeliest one floats, or the view's own
    reason (no point of the colour, too few, no sphere, the likeliest sphere's problem)."""
    floating = [r.objection for r in shortlist.refused[color] if r.objection.code == "floating"]
    if floating and not shortlist.plausible[color]:
        return floating[0]
    if shortlist.plausible[color]:  # every plausible one was taken for another colour
        return Objection("taken", "its only plausible spheres were taken for other balls")
    error = view.not_found(color, config)
    return Objection("missing", error.message, error.hint)


def _first_missing(
    view: ViewBallCandidates, shortlist: _Shortlist, config: BallConfig
) -> BallNotFound | RegistrationFailed:
    """The error for a view without a plausible combination: the first colour lacking a sphere, or the
    spheres' spacing when every colour has one."""
    for color in config.colors:
        if not shortlist.plausible[color]:
            objection = _missing_objection(view, shortlist, color, config)
            return BallNotFound(objection.message, view=view.view, color=color, hint=objection.hint)
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
    per_view: list[list[tuple[float, tuple[BallCandidate, ...]]]],
    ups: list[np.ndarray],
    placed: set[int],
    config: BallConfig,
) -> list[tuple[BallCandidate, ...]] | None:
    """The combination per view, one for every view, whose distances agree with the first view's, that
    turns the same way seen from above (``ups``: each view's up, its ground's normal), that shares at least
    two balls both views show with it (a ball placed unseen in one view and another in the other would
    leave one shared ball and the views' turn about it open), in which each ball is found by the view's or
    the first view's own detection (not only among ``placed``, the ids of the spheres sought where other
    views' balls put them) or two balls are both views' own, and whose total score is highest; None when
    there is none.

    Distances alone allow a mirror image: a look-alike where the ball would lie mirrored across the line
    through the other two (where the circles round the other two meet a second time) makes a
    triangle of the same sides, and registering it turns the view upside down. And placements alone make
    a triangle agree by construction: look-alikes in one view place a ball in the other, where a fragment
    of clutter is found, while that view's look-alikes place the first view's ball (2036042: the yellow
    ball taken from fragments of clutter 1 m off in both views, one found where views/2's triangle put it,
    the other where the trunk and the blue ball did; views/2 turned 48 degrees about the trunk, which the
    trunk's agreement cannot see, and H came out 37 % high). Two balls that both views found themselves fix
    the pose, and a third found by position in both then lies where it is (2074031: the red ball, a third
    clean in each view).

    Every triangle of the first view is compared with every one of the others at once (:class:`_Triangles`):
    after the searches the shortlists hold thousands of combinations, and comparing them one pair at a time
    took minutes (2064027: 160 s)."""
    if not per_view[0]:
        return None
    reference = _Triangles.of(per_view[0], ups[0], placed, config)
    others = [
        _Triangles.of(triangles, up, placed, config)
        for triangles, up in zip(per_view[1:], ups[1:], strict=True)
    ]
    best: tuple[float, list[tuple[BallCandidate, ...]]] | None = None
    for index, (reference_score, triangle) in enumerate(per_view[0]):
        total, chosen = reference_score, [triangle]
        for triangles, view in zip(per_view[1:], others, strict=True):
            agreeing = np.flatnonzero(view.agree_with(reference, index, config))
            if agreeing.size == 0:
                break
            score, match = triangles[int(agreeing[0])]  # the likeliest: the triangles come likeliest first
            total += score
            chosen.append(match)
        else:
            if best is None or total > best[0]:
                best = (total, chosen)
    return None if best is None else best[1]


@dataclass(frozen=True)
class _Triangles:
    """One view's combinations of balls as arrays, to compare with another view's all at once."""

    distances_m: np.ndarray
    """``(T, P)`` the distance between each pair of balls (``itertools.combinations`` order)."""
    variances_m2: np.ndarray
    """``(T, P)`` each distance's variance along it, from its two centres' covariances."""
    turns: np.ndarray
    """``(T,)`` whether the first three balls follow each other anticlockwise seen from the view's up."""
    seen: np.ndarray
    """``(T, B)`` which balls the view shows (not placed unseen)."""
    own: np.ndarray
    """``(T, B)`` which balls the view's own detection found (shown, and not sought where others put it)."""

    @classmethod
    def of(
        cls,
        triangles: list[tuple[float, tuple[BallCandidate, ...]]],
        up: np.ndarray,
        placed: set[int],
        config: BallConfig,
    ) -> _Triangles:
        balls = len(config.colors)
        pairs = list(itertools.combinations(range(balls), 2))
        centres = np.array([[c.fit.center_m for c in triangle] for _, triangle in triangles]).reshape(
            -1, balls, 3
        )
        covariances = np.array(
            [[c.fit.center_covariance_m2 for c in triangle] for _, triangle in triangles]
        ).reshape(-1, balls, 3, 3)
        distances = np.empty((len(triangles), len(pairs)))
        variances = np.empty((len(triangles), len(pairs)))
        for k, (i, j) in enumerate(pairs):
            offset = centres[:, j] - centres[:, i]
            distances[:, k] = np.linalg.norm(offset, axis=1)
            direction = offset / np.maximum(distances[:, k], 1e-9)[:, None]
            spread = covariances[:, i] + covariances[:, j]
            variances[:, k] = np.einsum("ti,tij,tj->t", direction, spread, direction)
        turns = np.array([_turn(triangle, up) for _, triangle in triangles], dtype=bool)
        seen = np.array([[not c.unseen for c in triangle] for _, triangle in triangles], dtype=bool)
        own = np.array(
            [[not c.unseen and id(c) not in placed for c in triangle] for _, triangle in triangles],
            dtype=bool,
        )
        return cls(
            distances_m=distances,
            variances_m2=variances,
            turns=turns,
            seen=seen.reshape(-1, balls),
            own=own.reshape(-1, balls),
        )

    def agree_with(self, reference: _Triangles, index: int, config: BallConfig) -> np.ndarray:
        """Mask of this view's combinations that may pair with the reference view's ``index``-th: distances
        within ``config.max_distance_mismatch_m`` beyond ``config.distance_mismatch_sds`` of their standard
        errors, the same turn, two balls both show, and each ball some detection's own in one of the two or
        two balls both views' own (which fix the pose with the ground's up: a third ball placed in both views
        then follows from it, and cannot make a wrong pose agree)."""
        excess = np.abs(
            self.distances_m - reference.distances_m[index]
        ) - config.distance_mismatch_sds * np.sqrt(self.variances_m2 + reference.variances_m2[index])
        mismatch = np.maximum(excess.max(axis=1), 0.0)
        return (
            (mismatch <= config.max_distance_mismatch_m)
            & (self.turns == reference.turns[index])
            & ((self.seen & reference.seen[index]).sum(axis=1) >= 2)
            & (
                (self.own | reference.own[index]).all(axis=1)
                | ((self.own & reference.own[index]).sum(axis=1) >= 2)
            )
        )


def _describe(
    view: ViewBallCandidates,
    shortlist: _Shortlist,
    chosen: dict[str, BallCandidate],
    config: BallConfig,
    rescued: list[BallCandidate],
    *,
    alternative: Objection,
) -> BallChoice:
    """The choice of ``chosen`` in one view: each colour's other plausible spheres are rejected as taken
    for another colour, or with ``alternative``; then come the refused ones."""
    rejected: dict[str, list[Rejection]] = {}
    for color in config.colors:
        others = []
        for candidate in shortlist.plausible[color]:
            if candidate is chosen.get(color) or candidate.unseen:
                continue  # a ball placed but not chosen was never seen: nothing to reject
            taken_as = next((c for c, other in chosen.items() if other is candidate), None)
            objection = Objection("taken", f"taken for the {taken_as} ball") if taken_as else alternative
            others.append(Rejection(candidate, objection))
        rejected[color] = others + shortlist.refused[color]
    by_position = tuple(
        color
        for color, candidate in chosen.items()
        if not candidate.unseen and any(candidate is r for r in rescued)
    )
    return BallChoice(
        view=view.view,
        chosen=chosen,
        rejected=rejected,
        found_by_position=by_position,
        placed_unseen=tuple(color for color, candidate in chosen.items() if candidate.unseen),
    )


def _disagreement(centres: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """``(B, B)`` absolute differences between the balls' mutual distances here and in the reference."""
    here = np.linalg.norm(centres[:, None] - centres[None, :], axis=2)
    there = np.linalg.norm(reference[:, None] - reference[None, :], axis=2)
    return np.abs(here - there)


def _turn(triangle: tuple[BallCandidate, ...], up: np.ndarray) -> bool:
    """Whether the first three balls of ``triangle`` follow each other anticlockwise seen from ``up``."""
    a, b, c = (candidate.fit.center_m for candidate in triangle[:3])
    return bool(np.cross(b - a, c - a) @ up > 0.0)


def _in_a_line(centres: np.ndarray, diameter_m: float) -> bool:
    spread = np.linalg.svd(centres - centres.mean(axis=0), compute_uv=False)
    return bool(spread[1] < 0.2 * diameter_m)
