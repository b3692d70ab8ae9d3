"""Bringing a capture's views into one world frame: the balls chosen jointly, the ball registration, the
ground frame, each view's region of interest and the gated ICP, chosen again when the views' surfaces
contradict the balls."""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, replace
from functools import partial

import numpy as np

from canopy_core.backproject import ViewCloud
from canopy_core.ball_selection import (
    BallChoice,
    ball_off_ground,
    balls_off_ground,
    balls_off_trunk,
    far_ball,
    no_trunk_round_balls,
    select_balls,
)
from canopy_core.balls import ViewBallCandidates
from canopy_core.config import IcpConfig, MeasureConfig
from canopy_core.errors import MeasurementError, RegistrationFailed
from canopy_core.filters import sparse_point_mask
from canopy_core.ground import (
    CAMERA_UP,
    GroundFrame,
    GroundPlane,
    fit_ground_frame,
    sees_trunk_near,
    view_trunk_foot,
)
from canopy_core.processes import on_each
from canopy_core.refine import (
    IcpRefinement,
    IcpSurface,
    check_icp_agreement,
    icp_surface,
    refine_views,
    refinement_bounds,
)
from canopy_core.register import apply, register_by_balls

__all__ = ["Alignment", "align_views", "balls_and_frame", "check_trunk_agreement"]

_GROUND_SAMPLE = 60_000
"""Points of all views together on which the world frame's ground is fitted."""


@dataclass(frozen=True)
class Alignment:
    """The views in one world frame: per view (in capture order) the balls chosen, the pose, the points
    of the region of interest in the world frame with their colours, how many stray points were dropped
    from it, and what ICP did (None for the reference, or when ICP is off)."""

    choices: list[BallChoice]
    view_to_reference: list[np.ndarray]
    ground: GroundFrame
    world_from_view: list[np.ndarray]
    roi_points_m: list[np.ndarray]
    roi_colors_rgb: list[np.ndarray]
    stray_points_removed: list[int]
    icp: list[IcpRefinement | None]


def align_views(
    view_names: Sequence[str],
    clouds: list[ViewCloud],
    focal_px: Sequence[float],
    candidates: list[ViewBallCandidates],
    grounds: list[GroundPlane | None],
    config: MeasureConfig,
    *,
    refining: Callable[[], None] | None = None,
    processes: int | None = 1,
) -> Alignment:
    """Register the views by their balls, fit the world frame, cut each view's region of interest and
    refine the poses by ICP.

    When the views' surfaces line up only with a view's balls moved or turned beyond what their fits allow
    (:func:`check_icp_agreement`), some sphere taken for a ball is a look-alike: an apple or a fragment of
    clutter that happens to close a triangle of the right sides. Each ball of that view, and then of the
    reference view, is ruled out in turn (:meth:`ViewBallCandidates.ruling_out`) and the balls chosen
    again; of the choices that stand (:func:`_stands_made_again`: the surfaces agree with them as closely
    as with a sound registration, ICP keeping its refinement of every view, or, where the trunk each view
    finds on its own stands at one place, at least as a first choice is judged), the one the surfaces
    contradict least is taken. A first choice resting on a ball placed unseen, or with a view that shares
    fewer than two balls fitted as spheres with the reference, must itself meet the closer bound
    (:func:`_check_weakly_held`), and every first choice must stand the views round one trunk
    (:func:`check_trunk_agreement`).

    A first choice that passes all that but under which the trunk each view finds on its own stands apart
    (:func:`_trunks_coincide`: a trellis post or a clump of suckers taken for the trunk in one view, or two
    look-alikes registering the views round the one true ball) is weighed against the choices made with
    each ball of every view ruled out in turn, and the one of them all the surfaces contradict least is
    taken. Mixed 2126017: only the blue ball right in both views, the red and yellow look-alikes 0.6-1.7 m
    off whose triangles agreed; the views registered 52 degrees from their true poses with ICP moving the
    balls 16 mm, the two trunks 0.70 m apart (each view holding a tuft within 0.4 m of the other's foot),
    W 27 % narrow. With a red look-alike ruled out, the true red and blue balls are found (the yellow a
    look-alike both views agree on), ICP moves them 2 mm and the trunks stand 5 mm apart. Of the 238 first
    choices that pass on 244 captures recorded (the tuning sets mixed 2118 and 2122, near posts 2119 and
    2121, and four examined trees), 63 had their trunks apart; weighed so, none was taken over by a wrong
    choice. Without ICP no choice is contradicted more than another, and none is weighed.

    Parameters
    ----------
    view_names, clouds, focal_px
        Per view, in capture order (the first is the reference): its name, its filtered points and its
        depth camera's focal length in pixels (the stray-point filter's pixel footprint).
    candidates, grounds
        Per view, the spheres found and its ground plane (:func:`canopy_core.measure.view_evidence`).
    refining
        Called once as ICP starts on the first choice (the ``refine`` progress stage).
    processes
        How many views' regions of interest are cut at once, as :func:`canopy_core.processes.on_each`
        takes it (1: one at a time; None: one per CPU). The result is the same either way.

    Raises
    ------
    BallNotFound, RegistrationFailed
        As :func:`balls_and_frame`; RegistrationFailed as :func:`check_icp_agreement` when no other
        choice satisfies the surfaces.
    """
    first = _aligned(
        view_names, clouds, focal_px, candidates, grounds, config, refining=refining, processes=processes
    )
    names = list(view_names)

    def made_again(suspects: Sequence[int]) -> list[Alignment]:
        """The choices made again, ruling out the balls of the ``suspects`` views, that stand."""
        return [
            again
            for again in _choices_made_again(
                first,
                suspects,
                view_names,
                clouds,
                focal_px,
                candidates,
                grounds,
                config,
                processes=processes,
            )
            if _stands_made_again(again, clouds, grounds, config)
        ]

    def least_contradicted(choices: list[Alignment]) -> Alignment:
        return min(choices, key=lambda alignment: _disagreement(alignment, config.icp))

    feet = _trunk_feet(first, clouds, grounds, config)
    try:
        _check_first_choice(first, clouds, grounds, config, feet=feet)
    except RegistrationFailed as disagreement:
        failure = disagreement
    else:
        # Without ICP no choice is contradicted more than another: nothing to weigh.
        if not config.icp.enabled or _trunks_coincide(feet, config) is not False:
            return first
        return least_contradicted([first, *made_again(range(len(names)))])
    suspect = names.index(failure.view) if failure.view in names else 0
    standing = made_again(list(dict.fromkeys((suspect, 0))))
    if standing:
        return least_contradicted(standing)
    # The balls sought about the one both views share first: where one view's fragments of clutter
    # closed a triangle with the other's, two fragments at one turn about the shared ball may be the
    # balls (2088013: each view shows two balls whole, not the same two; the circles took clutter).
    try:
        again = _aligned(
            view_names,
            clouds,
            focal_px,
            candidates,
            grounds,
            config,
            shared_ball_first=True,
            processes=processes,
        )
    except MeasurementError:
        raise failure from None
    if _stands_made_again(again, clouds, grounds, config):
        return again
    if _confirms_choice_made_again(again, config.icp):
        check_trunk_agreement(again, clouds, grounds, config)  # it stands unless the trunks disagree: say so
    raise failure


def _check_first_choice(
    first: Alignment,
    clouds: Sequence[ViewCloud],
    grounds: Sequence[GroundPlane | None],
    config: MeasureConfig,
    *,
    feet: list[tuple[int, np.ndarray]],
) -> None:
    """Refuse a first choice of balls the surfaces contradict (:func:`check_icp_agreement`), that rests
    on a ball placed unseen or a fragment without the surfaces' confirmation (:func:`_check_weakly_held`),
    or under which the views do not stand round one trunk (:func:`check_trunk_agreement`, on its views'
    trunk ``feet`` as :func:`_trunk_feet` finds them).

    Raises
    ------
    RegistrationFailed
        The first of these checks that fails, naming its view.
    """
    check_icp_agreement(_reports(first), config.icp)
    _check_weakly_held(first, config.icp)
    check_trunk_agreement(first, clouds, grounds, config, feet=feet)


def _choices_made_again(
    first: Alignment,
    suspects: Sequence[int],
    view_names: Sequence[str],
    clouds: list[ViewCloud],
    focal_px: Sequence[float],
    candidates: list[ViewBallCandidates],
    grounds: list[GroundPlane | None],
    config: MeasureConfig,
    *,
    processes: int | None = 1,
) -> Iterator[Alignment]:
    """The balls chosen again with each ball of the first choice in each of the ``suspects`` views (indices,
    in order) ruled out in turn (:meth:`ViewBallCandidates.ruling_out`), each carried through to ICP; a
    ruling-out under which no choice holds yields nothing; ``processes`` as :func:`align_views`."""
    for index in suspects:
        for color in config.balls.colors:
            retry = list(candidates)
            retry[index] = candidates[index].ruling_out(
                first.choices[index].chosen[color].fit.center_m, config.balls.radius_m
            )
            try:
                again = _aligned(view_names, clouds, focal_px, retry, grounds, config, processes=processes)
            except MeasurementError:
                continue
            yield again


def _stands_made_again(
    again: Alignment,
    clouds: Sequence[ViewCloud],
    grounds: Sequence[GroundPlane | None],
    config: MeasureConfig,
) -> bool:
    """Whether a choice of balls made again, one hypothesis among several, stands: the surfaces confirm it
    (:func:`_confirms_choice_made_again`) and the views stand round one trunk
    (:func:`check_trunk_agreement`); or the surfaces only do not contradict it as a first choice is judged
    (:func:`_check_first_choice`), but the trunk each view finds on its own stands at one place
    (:func:`_trunks_coincide`; where fewer than two views find their trunk, that is not known, and only
    the surfaces' confirmation counts). Trunks that coincide are evidence of their own that the balls are
    right (one trunk seen from two sides, found at one place), which a look-alike's registration meets by
    chance only: near posts 2125048, its first choice two look-alikes with the trunks 0.84 m apart; with
    either ruled out, views/1's red ball is placed unseen 3 cm from the ball and the others found, the
    trunks 4 mm apart, but ICP moves the balls 25 mm and turns the view 2.7 degrees, beyond what a pose
    resting on a ball placed unseen may (:func:`_confirms_choice_made_again`); mixed 2054014 likewise (12 mm,
    1.5 degrees). So this way a choice resting on a ball placed unseen or on fragments may stand, held only
    to a first choice's bounds, where its trunks coincide (2051009's look-alike, which only the bounds for
    a ball placed unseen refuse, stands in a view that finds no trunk of its own: not this way). Trunks
    apart do not refuse a choice the surfaces confirm: on sound registrations weeds and suckers pull one
    view's circle up to 19 cm aside (2036042: 15 cm)."""
    feet = _trunk_feet(again, clouds, grounds, config)
    if _confirms_choice_made_again(again, config.icp):
        try:
            check_trunk_agreement(again, clouds, grounds, config, feet=feet)
        except RegistrationFailed:
            return False
        return True
    if not _trunks_coincide(feet, config):
        return False
    try:
        _check_first_choice(again, clouds, grounds, config, feet=feet)
    except RegistrationFailed:
        return False
    return True


def _trunks_coincide(feet: list[tuple[int, np.ndarray]], config: MeasureConfig) -> bool | None:
    """Whether the trunk each view finds on its own (``feet`` as :func:`_trunk_feet` finds them) stands
    within ``icp.trunk_coincidence_m`` of that of the first view (in capture order) that finds one; None
    where fewer than two views find one."""
    if len(feet) < 2:
        return None
    (_, there), *others = feet
    tolerance = config.icp.trunk_coincidence_m
    return all(float(np.linalg.norm(here[:2] - there[:2])) <= tolerance for _, here in others)


def _trunk_feet(
    alignment: Alignment,
    clouds: Sequence[ViewCloud],
    grounds: Sequence[GroundPlane | None],
    config: MeasureConfig,
) -> list[tuple[int, np.ndarray]]:
    """Per view that finds its trunk on its own (:func:`view_trunk_foot`, within
    ``balls.max_trunk_distance_m`` of where the world frame puts it), its index and where the trunk's foot
    stands in the world frame."""
    trunk_xy = np.array(alignment.ground.trunk_xy_m)
    feet: list[tuple[int, np.ndarray]] = []
    for index, (cloud, ground, pose) in enumerate(
        zip(clouds, grounds, alignment.world_from_view, strict=True)
    ):
        if ground is None:
            continue
        near = apply(np.linalg.inv(pose), np.array([[*trunk_xy, 0.0]]))[0]
        foot = view_trunk_foot(cloud.points_m, ground, near, config.balls.max_trunk_distance_m)
        if foot is not None:
            feet.append((index, apply(pose, foot[None, :])[0]))
    return feet


def check_trunk_agreement(
    alignment: Alignment,
    clouds: Sequence[ViewCloud],
    grounds: Sequence[GroundPlane | None],
    config: MeasureConfig,
    *,
    feet: list[tuple[int, np.ndarray]] | None = None,
) -> None:
    """Refuse a registration under which the views do not stand round one trunk.

    Each view finds the trunk on its own (:func:`view_trunk_foot`: the arc of bark it sees fixes the circle)
    within ``balls.max_trunk_distance_m`` of where the world frame puts it; carried into the world frame,
    every view's foot must lie within ``icp.max_trunk_mismatch_m`` of the reference view's, or each of the two
    views must hold a trunk's circle that close to the other's foot (:func:`sees_trunk_near`): one view's best
    circle may be a trellis post or a clump of suckers (2067013: 0.73 m apart on a sound registration, each
    view holding a trunk where the other's stands). ICP cannot tell this: it lines up the ground and the
    trunk's foot, and flat ground slides and turns freely under a pose that has the trunk metres off. Three
    look-alikes the views took for the balls (2066007 weeds: each view a different set of fragments round
    weeds and straw, the triangles agreeing by chance) registered the views 35 degrees and 4 m apart while ICP
    moved the balls by 13 mm, and W came out 72 % wide; the two views' trunks stood 1.8 m apart in the world
    frame (views/2's best circle a trellis post that fell on views/1's trunk, and views/2 holding no trunk
    where views/1's stood), where on 36 sound registrations of mixed 2064 they stood within 4 cm but one (19
    cm: suckers round the foot). A view whose trunk is not found is not judged. ``feet``, where already
    found (:func:`_trunk_feet`), are not looked for again.

    Raises
    ------
    RegistrationFailed
        Naming the first view whose trunk stands too far from the reference's.
    """
    tolerance = config.icp.max_trunk_mismatch_m
    if feet is None:
        feet = _trunk_feet(alignment, clouds, grounds, config)

    def sees_trunk_at(index: int, foot_world_m: np.ndarray) -> bool:
        """Whether view ``index`` holds a trunk's circle within the tolerance of another view's foot."""
        ground = grounds[index]
        if ground is None:
            return False
        in_view = apply(np.linalg.inv(alignment.world_from_view[index]), foot_world_m[None, :])[0]
        return sees_trunk_near(clouds[index].points_m, ground, in_view, tolerance)

    if len(feet) < 2:
        return
    (reference, there), *others = feet
    for index, here in others:
        apart = float(np.linalg.norm(here[:2] - there[:2]))
        if apart <= tolerance or (sees_trunk_at(index, there) and sees_trunk_at(reference, here)):
            continue
        raise RegistrationFailed(
            f"registered by its balls, this view sees the trunk {apart:.2f} m from where "
            f"{alignment.choices[reference].view} sees it (at most {tolerance:.2f} m), and not each where "
            "the other does: something else of a ball's colour was probably taken for a ball in some view",
            view=alignment.choices[index].view,
            field="icp.max_trunk_mismatch_m",
            hint="check with `canopy balls --preview` which sphere was taken for each ball; clear what "
            "looks like a ball from around them, or re-lay them in open view, and capture again",
        )


def _confirms_choice_made_again(alignment: Alignment, config: IcpConfig) -> bool:
    """Whether the surfaces confirm a choice of balls made again, one hypothesis among several.

    A choice of balls every view shows must keep within :func:`_within_refinement_bounds`. One resting on a
    ball placed unseen holds each view by the balls it and the reference view both fit as spheres, and by
    the ground; the loose bounds of a pose resting on a fragment would let a look-alike through (2051009: a
    yellow look-alike, the red ball placed unseen 1.2 m off, ICP moving the balls 24 mm and turning the view
    2.3 degrees). So no view's pose may rest on a fragment, each must share at least two fitted balls with
    the reference and be refined by ICP, which may move those balls no farther than their fits leave open
    (``max_ball_shift_m``). A view that or whose reference has a ball placed unseen may turn no farther than
    moves a ball at half their spacing by as much, and never beyond a fragment's pose
    (``max_rotation_found_by_position_deg``): 0.9 degrees for 2051009's pair 1.26 m apart, 2.0 degrees for
    2090041's 0.58 m apart, whose blue ball stood hidden at 4.6 m behind the trunk in views/2 and where ICP,
    on balls placed right, moved them 6 mm and turned the view 0.8 degrees. Any other view (a third, sharing
    three fitted balls with the reference) keeps a sound registration's ``max_rotation_deg``."""
    if not any(choice.placed_unseen for choice in alignment.choices):
        return _within_refinement_bounds(alignment, config)
    if any(choice.found_by_position for choice in alignment.choices):
        return False
    reference = alignment.choices[0]
    for choice, report in zip(alignment.choices[1:], alignment.icp[1:], strict=True):
        held = [choice.chosen[color].fit.center_m for color in _shared_fitted(choice, reference)]
        if len(held) < 2 or report is None:
            return False  # neither two balls nor the surfaces hold the pose
        turn_deg = config.max_rotation_deg
        if choice.placed_unseen or reference.placed_unseen:
            spacing_m = max(float(np.linalg.norm(a - b)) for a, b in itertools.combinations(held, 2))
            turn_deg = min(
                float(np.degrees(config.max_ball_shift_m / (spacing_m / 2.0))),
                config.max_rotation_found_by_position_deg,
            )
        if report.ball_shift_m > config.max_ball_shift_m or report.rotation_change_deg > turn_deg:
            return False
    return True


def _within_refinement_bounds(alignment: Alignment, config: IcpConfig) -> bool:
    """Whether the surfaces confirm these balls: ICP moves no view's balls, and turns no view, in any
    direction beyond what the balls' fits leave open (:func:`refinement_bounds`), the tilt too, which a
    refinement of a sound choice may correct further (the ground's). A choice made again is one hypothesis
    among several, so it must meet that (one resting on a ball placed unseen, the bounds of
    :func:`_confirms_choice_made_again`), not merely stay short of a certain failure
    (:func:`check_icp_agreement`'s looser bounds): look-alikes both views see agree with each other and
    close triangles that ICP turns by 4-5 degrees."""
    loose_reference = _loose(alignment.choices[0])
    for choice, report in zip(alignment.choices, alignment.icp, strict=True):
        if report is None:
            continue
        shift_m, turn_deg = refinement_bounds(config, found_by_position=loose_reference or _loose(choice))
        if report.ball_shift_m > shift_m or report.rotation_change_deg > turn_deg:
            return False
    return True


def _check_weakly_held(alignment: Alignment, config: IcpConfig) -> None:
    """Refuse a pose that rests on a ball placed unseen, or on fewer than two balls that the view and the
    reference view both fit as spheres (the others found only as fragments where the other views place
    them), unless the surfaces confirm it: ICP keeps within the bounds of a sound registration
    (:func:`_within_refinement_bounds`). A look-alike in such a view, or in the triangle that placed the
    others, closes the same triangles; only the ground and the trunk can tell. 2051009: a yellow look-alike
    in the pair, the red ball placed 1.2 m off, W 75 % wide, with ICP wanting 3.1 degrees more than such
    a pose leaves open. 2054014: views/2's red and yellow balls taken as fragments 1.2-1.8 m off (fitted
    radii 74 and 80 mm) where views/1's triangle with a yellow look-alike put them, ICP wanting 3.5
    degrees, W 12 % wide (ICP's own pose was as wrong the other way). 2053020: each view fits one
    look-alike and holds a fragment where the other's triangle puts it, only blue right in both, ICP
    wanting 5.1 degrees, W 5 % wide.

    Raises
    ------
    RegistrationFailed
        Naming the first such view, and the balls it placed or shares as spheres.
    """
    reference = alignment.choices[0]
    shared = [_shared_fitted(choice, reference) for choice in alignment.choices]
    weak = [i for i, choice in enumerate(alignment.choices) if choice.placed_unseen or len(shared[i]) < 2]
    if not weak or _within_refinement_bounds(alignment, config):
        return
    choice = alignment.choices[weak[0]]
    what = (
        f"the {' and '.join(choice.placed_unseen)} ball, not seen in this view, was placed where the other "
        "views put it"
        if choice.placed_unseen
        else f"this view and {reference.view} both fit only the {' and '.join(shared[weak[0]]) or 'no'} ball "
        "as a sphere (the others were found as fragments where the other views place them)"
    )
    raise RegistrationFailed(
        f"{what}, and the view's ground and trunk do not confirm that pose",
        view=choice.view,
        field="icp.max_rotation_found_by_position_deg",
        hint="check with `canopy balls --preview` which sphere was taken for each ball; lay the balls where "
        "every view sees them, in open view, and capture again",
    )


def _shared_fitted(choice: BallChoice, reference: BallChoice) -> list[str]:
    """The colours of the balls a view and the reference view both fit as spheres (:func:`_fitted`): those
    that hold the view's pose to the reference's."""
    in_reference = _fitted(reference)
    return [color for color in _fitted(choice) if color in in_reference]


def _fitted(choice: BallChoice) -> list[str]:
    """The colours of the balls a view fits as spheres: neither found as fragments where the other views
    place them nor placed unseen."""
    return [
        color
        for color in choice.chosen
        if color not in choice.found_by_position and color not in choice.placed_unseen
    ]


def _loose(choice: BallChoice) -> bool:
    """Whether a view's pose rests on a ball known to centimetres only: a fragment found where the other
    views place it, or a ball placed there unseen."""
    return bool(choice.found_by_position or choice.placed_unseen)


def _reports(alignment: Alignment) -> list[IcpRefinement]:
    return [report for report in alignment.icp if report is not None]


def _disagreement(alignment: Alignment, config: IcpConfig) -> float:
    """How far the surfaces would move the balls or turn a view, as a share of what is allowed (the
    largest over the views): of two choices that both pass, the one the surfaces contradict less."""
    return max(
        (
            max(
                report.ball_shift_m / config.max_disagreement_m,
                report.rotation_change_deg / config.max_disagreement_deg,
            )
            for report in _reports(alignment)
        ),
        default=0.0,
    )


def _aligned(
    view_names: Sequence[str],
    clouds: list[ViewCloud],
    focal_px: Sequence[float],
    candidates: list[ViewBallCandidates],
    grounds: list[GroundPlane | None],
    config: MeasureConfig,
    *,
    refining: Callable[[], None] | None = None,
    shared_ball_first: bool = False,
    processes: int | None = 1,
) -> Alignment:
    """One choice of balls carried through registration, the world frame, the regions of interest and ICP
    (its reports not yet judged); ``shared_ball_first`` as :func:`select_balls`, ``processes`` as
    :func:`align_views`."""
    choices, view_to_reference, ground = balls_and_frame(
        clouds, candidates, grounds, config, shared_ball_first=shared_ball_first
    )
    colors = config.balls.colors
    centres = [np.array([choice.chosen[color].fit.center_m for color in colors]) for choice in choices]
    # A ball placed unseen holds no view to the others in ICP (it stands where they put it): NaN.
    anchors = [
        np.where(np.array([[color in choice.placed_unseen] for color in colors]), np.nan, view_centres)
        for choice, view_centres in zip(choices, centres, strict=True)
    ]
    world_from_view = [ground.world_from_reference @ pose for pose in view_to_reference]
    # ICP works on the low band of the cylinder round the balls (the origin), where they and the floor
    # between them hold the views together; the tree is measured in the cylinder round its trunk.
    measured_in = ground.round_trunk()
    to_trunk = measured_in.world_from_reference @ np.linalg.inv(ground.world_from_reference)
    axes_xy = [np.zeros(2), -to_trunk[:2, 3]] if measured_in.origin_at_trunk else [np.zeros(2)]
    refined = config.icp.enabled and len(clouds) > 1
    roi = on_each(
        partial(_view_region, config=config, axes_xy=axes_xy, refined=refined),
        list(zip(clouds, world_from_view, focal_px, strict=True)),
        processes=processes,
    )
    roi_points = [region.points_m for region in roi]
    if refining is not None:
        refining()
    icp: list[IcpRefinement | None] = [None] * len(clouds)
    if refined:
        corrections, reports = refine_views(
            list(view_names),
            [region.surface for region in roi if region.surface is not None],
            view_anchors_m=[apply(pose, a) for pose, a in zip(world_from_view, anchors, strict=True)],
            found_by_position=[_loose(choice) for choice in choices],
            config=config.icp,
        )
        roi_points = [apply(c, p) for c, p in zip(corrections, roi_points, strict=True)]
        world_from_view = [c @ pose for c, pose in zip(corrections, world_from_view, strict=True)]
        by_view = {report.view: report for report in reports}
        icp = [by_view.get(name) for name in view_names]
    roi_points = [apply(to_trunk, points) for points in roi_points]
    in_tree_roi = [np.linalg.norm(points[:, :2], axis=1) < config.roi.radius_m for points in roi_points]
    return Alignment(
        choices=choices,
        view_to_reference=view_to_reference,
        ground=measured_in,
        world_from_view=[to_trunk @ pose for pose in world_from_view],
        roi_points_m=[points[inside] for points, inside in zip(roi_points, in_tree_roi, strict=True)],
        roi_colors_rgb=[region.colors_rgb[inside] for region, inside in zip(roi, in_tree_roi, strict=True)],
        stray_points_removed=[region.stray_points_removed for region in roi],
        icp=icp,
    )


def balls_and_frame(
    clouds: list[ViewCloud],
    candidates: list[ViewBallCandidates],
    grounds: list[GroundPlane | None],
    config: MeasureConfig,
    *,
    shared_ball_first: bool = False,
) -> tuple[list[BallChoice], list[np.ndarray], GroundFrame]:
    """The balls chosen in each view, each view's pose in the reference view's frame, and the world frame
    (``shared_ball_first`` as :func:`select_balls`).

    The crew lays the balls on the ground, 0.3-0.8 m from the trunk. When a ball comes out farther from it
    than ``balls.max_trunk_distance_m``, or off the ground round the balls (their plane tilted from the
    ground's by more than a slope allows), the sphere taken for it is a look-alike every view saw (an apple
    lying on the ground agrees with itself across views; a fallen apple's centre lies lower than a ball's):
    the balls are chosen again without it (ruled out: no search finds it again as a fragment), and without
    any other sphere that lies as far from the trunk (the same apple fitted twice, its neighbours in a
    heap), so the ball is sought where the others place it. When no trunk stands round the balls at all
    (:func:`no_trunk_round_balls`), each ball is ruled out in turn. The ball is named in the reference view's
    frame, but the look-alike may be another view's: when each view took a look-alike for a different
    ball, each placed where the other's puts it, the triangles agree and the reference's odd ball out is
    the other view's true one. So if choosing again without the ball named fails, each other colour's
    choice is left out in turn. If none of those holds either, each colour's choice is left out in turn
    again with the spheres anywhere kept, the ball named last: the trunk was found round the balls taken,
    and a look-alike far out pulls their centre towards a trellis post, which is then taken for the trunk,
    with the true balls (the one named among them) 1-2 m from it. Such a choice, no longer held to the
    first trunk, must stand round a trunk of its own seen on its bark (``GroundFrame.trunk_on_bark``), not
    merely round the middle of what stands there.

    Raises
    ------
    BallNotFound, RegistrationFailed
        As :func:`select_balls`; RegistrationFailed naming the ball when no other choice lies round a
        trunk and on the ground.
    """
    choices = select_balls(candidates, config.balls, grounds=grounds, shared_ball_first=shared_ball_first)
    view_to_reference, ground, balls_world = _registered(choices, clouds, config)
    misplaced = _misplaced_ball(balls_world, ground, config)
    if misplaced is None:
        return choices, view_to_reference, ground
    named, failure = misplaced
    anywhere = {
        color: [
            # Ruled out, not merely dropped: no search may find the look-alike again as a fragment.
            view.ruling_out(choice.chosen[color].fit.center_m, config.balls.radius_m)
            for view, choice in zip(candidates, choices, strict=True)
        ]
        for color in config.balls.colors
    }
    # Each try: the views' spheres to choose from, and whether the choice must stand round a trunk seen
    # on its bark (where the spheres were not kept round the trunk the first choice found).
    tries: list[tuple[list[ViewBallCandidates], bool]]
    if named is None:  # no trunk found: none to keep the spheres round
        tries = [(views, False) for views in anywhere.values()]
    else:
        # Round the trunk first, the ball named first; then, where that dropped spheres, anywhere, the
        # ball named last: a look-alike far out pulls the balls' centre towards a trellis post, which is
        # then taken for the trunk, and the ball named may be a true one, 1-2 m from the post.
        others = [color for color in config.balls.colors if color != named]
        round_trunk = {
            color: _kept_round_trunk(anywhere[color], view_to_reference, ground, config)
            for color in (named, *others)
        }
        tries = [(views, False) for views in round_trunk.values()] + [
            (anywhere[color], True)
            for color in (*others, named)
            if _count(anywhere[color]) > _count(round_trunk[color])
        ]
    for without, on_bark in tries:
        try:
            again = select_balls(without, config.balls, grounds=grounds, shared_ball_first=shared_ball_first)
        except MeasurementError:
            continue
        poses, frame, centres_world = _registered(again, clouds, config)
        if (frame.trunk_on_bark or not on_bark) and _misplaced_ball(centres_world, frame, config) is None:
            return again, poses, frame
    raise failure


def _kept_round_trunk(
    views: list[ViewBallCandidates],
    view_to_reference: list[np.ndarray],
    ground: GroundFrame,
    config: MeasureConfig,
) -> list[ViewBallCandidates]:
    """Each view's spheres but those farther than ``balls.max_trunk_distance_m`` from the trunk of
    ``ground``, horizontally (``view_to_reference``: each view's pose in the reference view's frame)."""
    trunk_xy = np.array(ground.trunk_xy_m)
    kept = []
    for view, pose in zip(views, view_to_reference, strict=True):
        centres = np.array([candidate.fit.center_m for candidate in view.candidates]).reshape(-1, 3)
        world = apply(ground.world_from_reference @ pose, centres)
        near = np.linalg.norm(world[:, :2] - trunk_xy, axis=1) <= config.balls.max_trunk_distance_m
        kept.append(
            replace(view, candidates=tuple(c for c, n in zip(view.candidates, near, strict=True) if n))
        )
    return kept


def _count(views: list[ViewBallCandidates]) -> int:
    """How many spheres the views hold together."""
    return sum(len(view.candidates) for view in views)


def _misplaced_ball(
    balls_world: np.ndarray, ground: GroundFrame, config: MeasureConfig
) -> tuple[str | None, RegistrationFailed] | None:
    """The colour of a ball that cannot be one, far from the trunk or off the ground, with the failure to
    raise if no other choice does better; None for the colour when no trunk stands round the balls at all
    (each may be the look-alike); None when the balls lie where balls lie."""
    trunkless = no_trunk_round_balls(ground)
    if trunkless is not None:
        return None, trunkless
    trunk_xy = np.array(ground.trunk_xy_m)
    colors = config.balls.colors
    far = far_ball(balls_world, trunk_xy, colors, config.balls.max_trunk_distance_m)
    if far is not None:
        return far, balls_off_trunk(balls_world, trunk_xy, colors, far)
    sunk = ball_off_ground(ground, colors, config.balls.radius_m)
    if sunk is not None:
        return sunk, balls_off_ground(ground, colors, config.balls.radius_m, sunk)
    return None


def _registered(
    choices: list[BallChoice], clouds: list[ViewCloud], config: MeasureConfig
) -> tuple[list[np.ndarray], GroundFrame, np.ndarray]:
    """Each view's pose in the reference frame from the balls chosen, the world frame, and the reference
    view's balls in the world frame."""
    centres = [
        np.array([choice.chosen[color].fit.center_m for color in config.balls.colors]) for choice in choices
    ]
    view_to_reference = [register_by_balls(view_centres, centres[0]) for view_centres in centres]
    ground = _ground_frame(clouds, view_to_reference, centres[0], config)
    return view_to_reference, ground, apply(ground.world_from_reference, centres[0])


def _ground_frame(
    clouds: list[ViewCloud],
    view_to_reference: list[np.ndarray],
    ball_centres: np.ndarray,
    config: MeasureConfig,
) -> GroundFrame:
    """The world frame, fitted on a thinned sample of all views' points in the reference frame."""
    rng = np.random.default_rng(0)
    share = max(1, _GROUND_SAMPLE // len(clouds))
    sample = []
    for cloud, pose in zip(clouds, view_to_reference, strict=True):
        pick = rng.choice(len(cloud), size=min(share, len(cloud)), replace=False)
        sample.append(apply(pose, cloud.points_m[pick]))
    return fit_ground_frame(
        np.concatenate(sample),
        ball_centres,
        ball_radius_m=config.balls.radius_m,
        up_hint=CAMERA_UP,
        forward_hint=np.array([0.0, 0.0, 1.0]),
        search_radius_m=config.roi.radius_m,
        config=config.ground,
    )


@dataclass(frozen=True)
class _ViewRegion:
    """A view's points in the regions of interest (see :func:`_view_region`)."""

    points_m: np.ndarray
    """``(N, 3)`` in the world frame, without stray points."""
    colors_rgb: np.ndarray
    """``(N, 3)`` their colours."""
    stray_points_removed: int
    """How many stray points were dropped from the cylinder round the last axis (the tree's)."""
    surface: IcpSurface | None
    """Its band ICP works on, thinned (:func:`canopy_core.refine.icp_surface`); None when not refined."""


def _view_region(
    view: tuple[ViewCloud, np.ndarray, float],
    *,
    config: MeasureConfig,
    axes_xy: Sequence[np.ndarray],
    refined: bool,
) -> _ViewRegion:
    """A view's points (its cloud, its depth camera's pose in the world frame and focal length) inside the
    regions of interest (the vertical cylinders of ``roi.radius_m`` round each of ``axes_xy``, below
    ``roi.max_height_m``), in the world frame, without stray points; and, when ``refined``, the points ICP
    works on (below ``icp.max_height_m`` in the cylinder round the first axis, the balls'), thinned."""
    cloud, world_from_view, focal_px = view
    world = apply(world_from_view, cloud.points_m)
    inside = np.zeros(world.shape[0], dtype=bool)
    for axis_xy in axes_xy:
        inside |= np.linalg.norm(world[:, :2] - axis_xy, axis=1) < config.roi.radius_m
    inside &= world[:, 2] < config.roi.max_height_m
    inside &= world[:, 2] > -config.ground.search_band_m
    dense = sparse_point_mask(
        world[inside],
        range_m=cloud.points_m[inside, 2],
        focal_px=focal_px,
        radius_px=config.filters.sparse_radius_px,
        min_neighbors=config.filters.sparse_min_neighbors,
    )
    kept = np.flatnonzero(inside)[dense]
    dropped = world[np.flatnonzero(inside)[~dense]]
    in_tree_roi = np.linalg.norm(dropped[:, :2] - axes_xy[-1], axis=1) < config.roi.radius_m
    points = world[kept]
    surface = None
    if refined:
        low = (points[:, 2] < config.icp.max_height_m) & (
            np.linalg.norm(points[:, :2], axis=1) < config.roi.radius_m
        )
        surface = icp_surface(points[low], config.icp.voxel_m)
    return _ViewRegion(points, cloud.colors_rgb[kept], int(np.count_nonzero(in_tree_roi)), surface)
