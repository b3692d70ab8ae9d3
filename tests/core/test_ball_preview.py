"""What `canopy balls` shows: per view and colour the ball chosen and the spheres rejected; the picture."""

from __future__ import annotations

import numpy as np

from canopy_core.ball_preview import ball_report, ball_rgb, draw_ball_preview
from canopy_core.ball_selection import BallChoice, Rejection
from canopy_core.balls import BallCandidate, Objection, ViewBallCandidates
from canopy_core.capture import CameraModel, Intrinsics, View
from canopy_core.config import BallConfig
from canopy_core.errors import BallNotFound
from canopy_core.ground import GroundPlane
from canopy_core.spheres import SphereFit

COLORS = ("red", "yellow", "blue")
DEPTH = Intrinsics(width=512, height=424, fx=365.7, fy=365.7, cx=256.2, cy=210.5)
COLOR = Intrinsics(width=1920, height=1080, fx=1053.0, fy=1053.0, cx=958.4, cy=536.7)
GREY = (90, 90, 90)


def _sphere(
    centre: tuple[float, float, float],
    scores: dict[str, float],
    *,
    radius_m: float = 0.05,
    points: int = 120,
    problem: Objection | None = None,
) -> BallCandidate:
    fit = SphereFit(
        center_m=np.array(centre),
        radius_m=radius_m,
        points=points,
        rms_m=0.003,
        coverage=0.9,
    )
    return BallCandidate(
        fit=fit,
        expected_points=150.0,
        color_scores={color: scores.get(color, 0.0) for color in COLORS},
        problem=problem,
    )


def _view(name: str, *candidates: BallCandidate) -> ViewBallCandidates:
    return ViewBallCandidates(
        view=name,
        candidates=candidates,
        colored_points={color: 500 for color in COLORS},
        hsv_ranges={color: BallConfig().hsv_range(color) for color in COLORS},
    )


def _ring_share(
    image: np.ndarray,
    centre: tuple[float, float],
    radius_px: float,
    rgb: tuple[int, ...],
    *,
    tolerance: int = 12,
    spread_px: tuple[float, ...] = (0.0,),
) -> float:
    """The share of directions round ``centre`` in which the circle of ``radius_px`` (give or take one of
    ``spread_px``) is drawn in ``rgb``, within ``tolerance``."""
    angles = np.linspace(0.0, 2.0 * np.pi, 36, endpoint=False)
    hits = np.zeros(angles.size, dtype=bool)
    for spread in spread_px:
        u = np.rint(centre[0] + (radius_px + spread) * np.cos(angles)).astype(int)
        v = np.rint(centre[1] + (radius_px + spread) * np.sin(angles)).astype(int)
        hits |= np.abs(image[v, u].astype(int) - np.array(rgb)).max(axis=1) <= tolerance
    return float(np.mean(hits))


def test_registered_view_is_drawn_at_the_depth_pixels_full_size() -> None:
    ball = _sphere((0.3, 0.2, 3.0), {"yellow": 0.9})
    apple = _sphere(
        (-0.5, -0.1, 2.5), {"yellow": 0.6}, radius_m=0.08, problem=Objection("radius", "fitted radius 80 mm")
    )
    view = View(
        name="views/1",
        depth_raw=np.zeros((424, 512), dtype=np.uint16),
        color_rgb=np.full((424, 512, 3), GREY, dtype=np.uint8),
        camera=CameraModel(depth=DEPTH, depth_scale=1000.0),
    )
    choice = BallChoice(
        view="views/1",
        chosen={"yellow": ball},
        rejected={"yellow": [Rejection(apple, Objection("radius", ""))]},
    )
    image = draw_ball_preview(view, choice, BallConfig(colors=["yellow"]))
    assert image.shape == (424, 512, 3) and image.dtype == np.uint8
    centre = (DEPTH.fx * 0.3 / 3.0 + DEPTH.cx, DEPTH.fy * 0.2 / 3.0 + DEPTH.cy)
    radius = DEPTH.fx * 0.05 / 3.0
    yellow = ball_rgb("yellow", BallConfig())
    assert yellow[0] > 200 and yellow[1] > 200 and yellow[2] < 60
    assert _ring_share(image, centre, radius + 3, yellow) > 0.9
    assert _ring_share(image, centre, radius - 2, yellow) == 0.0  # the ball itself is left in sight
    apple_centre = (DEPTH.fx * -0.5 / 2.5 + DEPTH.cx, DEPTH.fy * -0.1 / 2.5 + DEPTH.cy)
    thin = _ring_share(
        image, apple_centre, DEPTH.fx * 0.08 / 2.5 + 2, (225, 225, 225), tolerance=60, spread_px=(-1, 0, 1)
    )
    assert thin > 0.9


def test_native_view_is_scaled_down_drawn_through_the_colour_camera_and_names_missing_balls() -> None:
    depth_to_color = np.eye(4)
    depth_to_color[0, 3] = -0.052
    view = View(
        name="views/2",
        depth_raw=np.zeros((424, 512), dtype=np.uint16),
        color_rgb=np.full((1080, 1920, 3), GREY, dtype=np.uint8),
        camera=CameraModel(depth=DEPTH, depth_scale=1000.0, color=COLOR, depth_to_color=depth_to_color),
    )
    ball = _sphere((0.4, 0.9, 2.5), {"blue": 0.9})
    image = draw_ball_preview(
        view, BallChoice(view="views/2", chosen={"blue": ball}, rejected={}), BallConfig()
    )
    assert image.shape == (540, 960, 3)
    centre = ((COLOR.fx * 0.348 / 2.5 + COLOR.cx) / 2, (COLOR.fy * 0.9 / 2.5 + COLOR.cy) / 2)
    assert _ring_share(image, centre, COLOR.fx * 0.05 / 2.5 / 2 + 3, ball_rgb("blue", BallConfig())) > 0.9
    corner = image[:60, :200].reshape(-1, 3).astype(int)  # "no red ball", "no yellow ball" written there
    for color in ("red", "yellow"):
        assert (np.abs(corner - ball_rgb(color, BallConfig())).max(axis=1) <= 12).sum() > 20, color
    assert not (np.abs(corner - ball_rgb("blue", BallConfig())).max(axis=1) <= 12).any()


def test_one_colour_lists_the_other_spheres_of_that_colour_with_their_reasons() -> None:
    best = _sphere((0.0, 1.0, 3.0), {"yellow": 0.95})
    weaker = _sphere((0.5, 1.0, 3.2), {"yellow": 0.5}, points=60)
    too_big = _sphere(
        (-0.5, 1.0, 3.0), {"yellow": 0.9}, radius_m=0.1, problem=Objection("radius", "fitted radius 100 mm")
    )
    blue_ball = _sphere((0.2, 1.0, 2.5), {"blue": 1.0})
    report = ball_report(
        [_view("views/1", weaker, blue_ball, too_big, best)], BallConfig(colors=["yellow"]), grounds=[None]
    )
    assert report.error is None
    (choice,) = report.choices
    assert choice.chosen == {"yellow": best}
    assert [(r.candidate, r.objection.code) for r in choice.rejected["yellow"]] == [
        (weaker, "weaker"),
        (too_big, "radius"),
    ]  # the blue ball has none of the yellow one's colour: no candidate for it
    document = report.to_dict()
    assert document["views"]["views/1"]["yellow"]["center_m"] == [0.0, 1.0, 3.0]
    assert [sphere["code"] for sphere in document["views"]["views/1"]["yellow"]["rejected"]] == [
        "weaker",
        "radius",
    ]
    assert report.lines(limit=1)[1:] == [
        "    rejected centre (+0.500, +1.000, +3.200) m  radius 50.0 mm  60 points  "
        "[weaker] less likely than the sphere chosen",
        "    ... 1 more rejected (--all lists them)",
    ]


def test_failed_selection_still_shows_each_views_likeliest_spheres_and_the_error() -> None:
    centres = {"red": (-0.4, 1.0, 3.3), "yellow": (0.45, 1.0, 3.2), "blue": (0.0, 1.0, 2.55)}
    balls = {color: _sphere(centre, {color: 0.95}) for color, centre in centres.items()}
    apple = _sphere((0.1, 0.2, 3.0), {"blue": 0.9})  # blue enough, but 80 cm above the ground
    views = [_view("views/1", *balls.values()), _view("views/2", balls["red"], balls["yellow"], apple)]
    ground = GroundPlane(point_m=np.array([0.0, 1.05, 3.0]), normal=np.array([0.0, -1.0, 0.0]))
    report = ball_report(views, BallConfig(), grounds=[ground, ground])
    assert isinstance(report.error, BallNotFound)
    assert (report.error.view, report.error.color) == ("views/2", "blue")
    first, second = report.choices
    assert first.chosen == balls
    assert second.chosen == {"red": balls["red"], "yellow": balls["yellow"]}
    assert [r.objection.code for r in second.rejected["blue"]] == ["floating"]
    assert "0.80 m above the ground" in second.missing["blue"].message
    document = report.to_dict()
    assert document["error"]["color"] == "blue" and "center_m" not in document["views"]["views/2"]["blue"]
    lines = report.lines()
    assert lines[0].startswith("ball selection failed")
    assert any(
        line.startswith("views/2 blue    no ball: a sphere 3.0 m away stands 0.80 m") for line in lines
    )
