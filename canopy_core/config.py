"""Every tunable parameter of a measurement, with physical units and defaults, in one tree of models.

A ``MeasureConfig`` is built from the defaults, then the capture's own settings (ball diameter, colours and
HSV ranges, region of interest), then any caller overrides; it is echoed in every result so that a
measurement can be reproduced exactly.
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, model_validator

__all__ = [
    "DEFAULT_HSV_RANGES",
    "BallConfig",
    "BallSet",
    "FilterConfig",
    "GroundConfig",
    "HsvRange",
    "IcpConfig",
    "MeasureConfig",
    "MetricsConfig",
    "PoleConfig",
    "RoiConfig",
    "WireConfig",
    "deep_merge",
]


def _hue_on_opencv_scale(bounds: list[list[int]]) -> list[list[int]]:
    for bound in bounds:
        if bound[0] > 180:
            raise ValueError(f"hue {bound[0]} is off OpenCV's 0-180 scale")
    return bounds


HsvTriple = Annotated[list[Annotated[int, Field(ge=0, le=255)]], Field(min_length=3, max_length=3)]
HsvRange = Annotated[list[HsvTriple], Field(min_length=2, max_length=2), AfterValidator(_hue_on_opencv_scale)]
"""``[[h, s, v], [h, s, v]]``, lower and upper bound on OpenCV's HSV scale (H 0-180, S and V 0-255).
A lower hue above the upper hue wraps round through 0, as red needs."""

DEFAULT_HSV_RANGES: dict[str, list[list[int]]] = {
    "red": [[168, 110, 50], [8, 255, 255]],
    "orange": [[9, 130, 80], [19, 255, 255]],
    "yellow": [[20, 110, 70], [34, 255, 255]],
    "green": [[40, 110, 50], [80, 255, 255]],
    "blue": [[100, 140, 40], [128, 255, 255]],
    "purple": [[130, 90, 40], [160, 255, 255]],
}


class _Section(BaseModel):
    """A section of settings: unknown keys are refused, and so are infinite or NaN numbers (the results are
    written as strict JSON)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class BallSet(_Section):
    """The calibration balls a capture used: their size and colours (capture.json's calibration_balls)."""

    diameter_m: float = Field(0.10, gt=0.0, le=2.0, allow_inf_nan=False, description="Ball diameter, m.")
    colors: list[str] = Field(
        default_factory=lambda: ["red", "yellow", "blue"],
        min_length=1,
        description="The balls' colours, each once; registration and the ground frame need three.",
    )
    hsv: dict[str, HsvRange] = Field(
        default_factory=dict,
        description="Per-colour HSV ranges, [[h, s, v] low, [h, s, v] high] in OpenCV units (hue 0-180, a "
        "low hue above the high one wrapping round red; saturation and value 0-255), overriding the built-in "
        "ones of red, orange, yellow, green, blue and purple, or giving another colour's.",
    )

    @model_validator(mode="after")
    def _colors_known_and_distinct(self) -> BallSet:
        if len(set(self.colors)) != len(self.colors):
            raise ValueError("colors lists a colour twice")
        for color in self.colors:
            if color not in self.hsv and color not in DEFAULT_HSV_RANGES:
                raise ValueError(
                    f"colour {color!r} has no default HSV range; give one in hsv "
                    f"(known: {', '.join(DEFAULT_HSV_RANGES)})"
                )
        return self


class BallConfig(BallSet):
    """The calibration balls and how they are found (``balls.py``)."""

    min_points: int = Field(12, ge=4, description="Fewest ball-coloured surface points a ball may have.")
    inlier_tolerance_m: float = Field(
        0.008,
        gt=0.0,
        description="A point is a sphere inlier when its distance to the surface is below this.",
    )
    max_radius_error: float = Field(
        0.25, gt=0.0, lt=1.0, description="Largest relative difference of the fitted and the true radius."
    )
    radius_error_sds_where_placed: float = Field(
        2.0,
        ge=0.0,
        description="A sphere found where the other views place a ball may have a radius off by "
        "max_radius_error plus this many of the fit's standard errors: a dozen noisy points on a far ball's "
        "cap hardly fix its radius, and its place is vouched for by the other balls and views.",
    )
    max_rms_m: float = Field(
        0.012, gt=0.0, description="Largest RMS distance of inliers to the fitted sphere."
    )
    ransac_iterations: int = Field(
        300,
        ge=10,
        description="Sphere hypotheses of the known radius (through three points each) tried per candidate "
        "before its least-squares fit.",
    )
    hue_spread: float = Field(
        8.0,
        gt=0.0,
        le=90.0,
        description="Hue distance outside a colour's HSV range (OpenCV units: 180 = a full turn) at which a "
        "point's colour likelihood falls to exp(-1/2): white-balance drift and shade move a ball's hue.",
    )
    min_color_score: float = Field(
        0.3,
        gt=0.0,
        le=1.0,
        description="Least mean colour likelihood of a sphere's points for it to be taken for that colour's "
        "ball.",
    )
    min_completeness: float = Field(
        0.3,
        gt=0.0,
        le=1.0,
        description="Least fraction of the pixels a ball at the fitted centre would cover that must lie on "
        "it.",
    )
    max_completeness: float = Field(
        1.5,
        gt=1.0,
        description="Most points a ball's sphere may hold, as a multiple of the pixels a ball there covers "
        "(a ball shows 0.5-1.2 with its rim's mixed pixels; a post's or trunk's band on a sphere of the "
        "ball's radius shows 1.6-2).",
    )
    min_completeness_where_placed: float = Field(
        0.15,
        gt=0.0,
        le=1.0,
        description="As min_completeness, for a sphere found where the other views place a ball (grass "
        "hiding most of it): that the balls' triangle puts it there is evidence a fragment lacks.",
    )
    max_seen_through_share: float = Field(
        0.25,
        gt=0.0,
        lt=1.0,
        description="A ball a view does not show at all may be placed where two balls it does show and the "
        "other views' triangle put it, if it is hidden there: the rays through the inner half of its outline "
        "end on it or in front of it (grass, the trunk). When more than this share of them pass behind "
        "where it would be, the view sees through that place and no ball lies there.",
    )
    min_coverage: float = Field(
        0.6,
        gt=0.0,
        le=1.0,
        description="Least fraction of the points seen through a sphere's outline that lie on it (a solid "
        "ball hides what is behind it; a sphere through unrelated surfaces does not).",
    )
    max_points_over: float = Field(
        1.0,
        ge=0.0,
        description="A calibration ball lying on the ground has open air over it. A sphere with more points "
        "than this share of a ball's pixels there standing right over it (within 1.3 radii of its vertical "
        "axis, 1.4 to 4 radii above its centre, on the camera's side of it) is the foot of something "
        "upright of a ball's width and colour: a post, a stake. A surface standing there shows about twice a "
        "ball's pixels; grass blades, a weed's leaves or the trunk behind a ball far fewer.",
    )
    max_ground_gap_m: float = Field(
        0.25,
        gt=0.0,
        description="A ball rests on the ground, its centre one radius above it; a sphere whose centre "
        "stands more than this higher above the view's ground plane (undulations, grass, the plane's error) "
        "is not a calibration ball (an apple in the crown).",
    )
    max_trunk_distance_m: float = Field(
        1.2,
        gt=0.0,
        description="The crew lays the balls 0.3-0.8 m from the trunk; a ball found farther than this from "
        "the trunk is a look-alike (an apple lying on the ground) that every view saw and took for it.",
    )
    max_trunk_reach_mismatch_m: float = Field(
        0.05,
        gt=0.0,
        description="Where two views share only one ball, the trunk found in each fixes how the other balls "
        "turn round it; the ball's horizontal distance from the trunk agrees between the two within this "
        "(each view fits the trunk's circle on the arc it sees, a centimetre or two off), else they found "
        "different trunks or posts and nothing is placed.",
    )
    max_distance_mismatch_m: float = Field(
        0.02,
        gt=0.0,
        description="The balls' mutual distances agree between views within this: detection errs by a few "
        "mm; a moved ball or a look-alike taken for one differs by more.",
    )
    distance_mismatch_sds: float = Field(
        2.0,
        ge=0.0,
        description="The distances may differ by max_distance_mismatch_m and this many standard errors of "
        "the difference, from the spheres' fits: a ball seen whole is known to a millimetre, a fragment "
        "of a dozen noisy points to centimetres.",
    )

    @property
    def radius_m(self) -> float:
        """Half the diameter."""
        return self.diameter_m / 2.0

    def hsv_range(self, color: str) -> list[list[int]]:
        """The HSV range for ``color``: the capture's override, else the default for that colour name.

        Validation guarantees one of the two exists for every configured colour.
        """
        return self.hsv.get(color) or DEFAULT_HSV_RANGES[color]


class RoiConfig(_Section):
    """Region of interest: a vertical cylinder around the trunk that holds the tree and nothing else."""

    radius_m: float = Field(
        1.5,
        gt=0.0,
        le=20.0,
        description="Cylinder radius round the trunk (round the balls' centroid where no trunk is found), m.",
    )
    max_height_m: float = Field(5.0, gt=0.0, le=50.0, description="Cylinder top above the ground, metres.")
    link_m: float = Field(
        0.15, gt=0.0, description="A gap wider than this separates the tree from other things in the ROI."
    )


class WireConfig(_Section):
    """Trellis wires crossing the region of interest, removed from the tree's points (``segment.py``)."""

    tolerance_m: float = Field(
        0.03,
        gt=0.0,
        le=0.2,
        description="Points within this distance of a wire's fitted line are the wire's: its few "
        "millimetres, the depth noise along the ray (about 1.3 cm at 4 m in sun) and the views' registration "
        "(a few mm).",
    )
    spread_m: float = Field(
        0.3,
        gt=0.0,
        le=1.0,
        description="Points in a wire's sight plane (within tolerance_m) up to this far across it, and any "
        "behind it as their camera sees it, are its mixed pixels: a wire fills part of a depth pixel, whose "
        "reading blends it with what lies behind, so its points stand off it along the camera rays, each "
        "view's to its own side. Without the camera (the wire search), points at its height this far across "
        "it are its own (its mixed pixels reach 0.25 m in most simulated captures).",
    )
    max_slope_deg: float = Field(
        5.0,
        ge=0.0,
        lt=45.0,
        description="The first wire found is level within this angle of the ground frame: the floor round "
        "the tree, to which that frame is fitted, undulates and tilts against the row's level, which the "
        "wires follow from post to post (3.2 degrees in a simulated capture whose floor falls 12 cm across "
        "2.5 m); its sag bends it by about a centimetre over the region of interest. The trellis's other "
        "wires hang from the same posts, so they slope within this angle of the first.",
    )
    min_coverage: float = Field(
        0.8,
        gt=0.0,
        le=1.0,
        description="Least share of a wire's chord through the region of interest that it covers: where it "
        "is seen, between its farthest sightings (hidden in a crown), and where something lies along it (the "
        "crowns it passes through); the rest is out of the cameras' view or lost to dropout.",
    )
    scene_radius_m: float = Field(
        3.0,
        ge=0.0,
        le=20.0,
        description="A wire runs on from post to post: it is also sought in what the cameras see beyond the "
        "region of interest, up to this far from the trunk, where it shows between the crown and the "
        "neighbours (a Kinect v2 3.5 m away sees 2.4 m either side along the row). A line of leaves ends "
        "with its crown. Below roi.radius_m, nothing beyond the region of interest is searched.",
    )
    scene_min_height_m: float = Field(
        0.3,
        ge=0.0,
        description="Beyond the region of interest, where no ground is fitted, only points this high in the "
        "ground frame are searched for wires: above the floor's tilt over scene_radius_m (16 cm at 3 degrees "
        "and 3 m) and its scan lines, which a far, grazing view shows as level lines; below the lowest wire "
        "of a trellis (0.4-0.8 m).",
    )


class PoleConfig(_Section):
    """Trellis posts and other poles standing beside the tree (``poles.py``), found by their shape: each thin
    horizontal slab of a pole in open air is a compact group with nothing near it, in one straight line
    down to the ground."""

    cell_m: float = Field(
        0.02,
        gt=0.0,
        le=0.1,
        description="Grid cell on which a slab's points are grouped: about two depth pixels at 4 m (a Kinect "
        "v2 pixel covers 11 mm there).",
    )
    slab_m: float = Field(
        0.05,
        gt=0.0,
        le=0.5,
        description="Height of the horizontal slabs a pole is seen in, slab after slab.",
    )
    isolation_m: float = Field(
        0.08,
        gt=0.0,
        le=0.5,
        description="A slab of a pole standing in open air has nothing nearer it than about this: a slab's "
        "groups closer together (this rounded up to an even number of cells) are one group. Leaves in a "
        "crown stand a few centimetres apart, so a post inside the crown shows no group of its own there.",
    )
    max_radius_m: float = Field(
        0.12,
        gt=0.0,
        le=0.5,
        description="The thickest pole sought: a slab of it lies within this of its group's centre. Trellis "
        "posts are 5-20 cm thick (wood 8-15 cm, concrete 10-12 cm, steel 5-8 cm); support stakes 2 cm.",
    )
    min_radius_m: float = Field(
        0.025,
        gt=0.0,
        le=0.5,
        description="The thinnest pole taken: as far as its surface's points lie from its axis. Trellis "
        "posts are at least 5 cm thick; a sucker or a shoot beside the trunk, or a 2 cm support stake, is "
        "thinner and is not taken for a post.",
    )
    tolerance_m: float = Field(
        0.02,
        gt=0.0,
        le=0.2,
        description="How far a pole's slab centres stand from its straight line (RMS), and the margin round "
        "the surface its groups show within which points are the pole's: the depth noise at 4 m in sun "
        "(about 1.3 cm), the views' registration (a few mm) and one view's side of the pole against both.",
    )
    min_length_m: float = Field(
        0.4,
        gt=0.0,
        description="A pole shows in open air, compact and straight, over at least this height: longer than "
        "a weed's or a sucker's straight stretch, and shorter than the bare stretch between the ground's "
        "grass and a tree's lowest leaves that a post stands in.",
    )
    max_lean_deg: float = Field(
        10.0,
        ge=0.0,
        lt=45.0,
        description="A pole leans at most this far from the ground frame's vertical: line posts are set "
        "plumb, and the frame may tilt a few degrees against gravity. A stretch of it too short to stand as "
        "its foot (under min_length_m) may seem to lean more, within two standard errors of its lean.",
    )
    max_gap_m: float = Field(
        0.3,
        ge=0.0,
        le=2.0,
        description="A pole is followed down and up its line through spans where nothing is seen on it up to "
        "this long: hidden behind leaves, tall grass or the trunk from both views.",
    )
    spread_m: float = Field(
        0.3,
        ge=0.0,
        le=2.0,
        description="Where a pole stands alone, a view's points up to this far in front of it within its "
        "outline (as that view's camera sees it) are its own: the last pixels across a round pole meet it at "
        "grazing incidence, where a Kinect v2's depth noise along the ray is 5 cm at 80 degrees and 4 m, "
        "and several times that nearer 90 degrees and in sun. Behind it, anything within its outline is its "
        "mixed pixels: it hides what stands there.",
    )
    min_trunk_gap_m: float = Field(
        0.1,
        ge=0.0,
        le=1.0,
        description="A pole's axis stands at least this far outside the trunk's bark (at the lowest point "
        "where it stands alone): nearer, "
        "its line cannot be told from the trunk's own outline and the suckers at its foot, and it is not "
        "sought (a support stake tied to the trunk is not found as a pole).",
    )


class FilterConfig(_Section):
    """Per-view cleaning of the back-projected points (``filters.py``)."""

    min_depth_m: float = Field(0.3, ge=0.0, description="Depth readings nearer than this are dropped.")
    max_depth_m: float = Field(8.0, gt=0.0, description="Depth readings farther than this are dropped.")
    flying_window_px: int = Field(2, ge=1, le=5, description="Half-size of the flying-pixel window.")
    flying_jump_ratio: float = Field(
        0.03,
        gt=0.0,
        description="A pixel is flying when its window holds depths both nearer and farther than it by more "
        "than this fraction of its own depth (plus flying_jump_min_m).",
    )
    flying_jump_min_m: float = Field(
        0.02, ge=0.0, description="The depth step a flying pixel's window shows at least, besides the ratio."
    )
    sparse_radius_px: float = Field(
        4.0, gt=0.0, description="Neighbourhood of the sparse-point check, in pixels at the point's range."
    )
    sparse_min_neighbors: int = Field(2, ge=1, description="Fewest neighbours a kept point has in it.")

    @model_validator(mode="after")
    def _range_not_empty(self) -> FilterConfig:
        if self.min_depth_m >= self.max_depth_m:
            raise ValueError(f"min_depth_m {self.min_depth_m} must be below max_depth_m {self.max_depth_m}")
        return self


class GroundConfig(_Section):
    """Ground plane fitting and the world frame (``ground.py``)."""

    search_band_m: float = Field(
        0.20, gt=0.0, description="Ground candidates lie within this height of the balls' contact plane."
    )
    inlier_tolerance_m: float = Field(0.03, gt=0.0, description="Ground plane RANSAC inlier distance.")
    trunk_radius_m: float = Field(
        0.6, gt=0.0, description="Ground height is taken from ground points within this distance of the axis."
    )
    max_tilt_from_balls_deg: float = Field(
        15.0,
        gt=0.0,
        lt=90.0,
        description="The balls rest on the ground, so the ground found round them is level with their "
        "centres' plane within the ground's unevenness between the balls (up to 11 degrees on simulated "
        "orchards with bumps and grass). Tilted more, a sphere taken for a ball lies off the ground (a "
        "fallen apple fitted at ground level): the balls are chosen again without it, or the registration "
        "fails naming it.",
    )

    ball_rest_tolerance_m: float = Field(
        0.03,
        gt=0.0,
        description="A ball's centre stands one radius above the floor right round it within this (grass, "
        "the floor's texture): where the balls' plane tilts more than max_tilt_from_balls_deg from the "
        "ground round them, they still rest on it when every ball does (one lies in a hollow 8 cm lower).",
    )


class IcpConfig(_Section):
    """ICP refinement after the ball registration (``refine.py``)."""

    enabled: bool = Field(True, description="Refine the ball registration by ICP (false: the balls alone).")
    max_height_m: float = Field(
        0.6,
        gt=0.0,
        description="ICP uses the points below this height: ground, trunk foot and balls, which views from "
        "opposite sides of a row both see (their foliage surfaces differ).",
    )
    voxel_m: float = Field(0.02, gt=0.0, description="Voxel size the clouds are thinned to for ICP.")
    max_correspondence_m: float = Field(
        0.03, gt=0.0, description="A point is matched to the other view's nearest point only within this."
    )
    max_iterations: int = Field(30, ge=1, description="ICP iterations, each re-matching every point.")
    max_ball_shift_m: float = Field(
        0.01,
        gt=0.0,
        description="How far the balls' fits leave their centres open. A refinement sliding any ball centre "
        "farther than this across the ground (horizontally) is rejected: the ground fixes the tilt and the "
        "height, and leaves the slide to the balls. Their heights err by more (noise over the triangle, "
        "grass or weeds under a ball) and yield to the ground up to max_disagreement_m. A choice of balls "
        "the surfaces must confirm (one resting on fragments, or chosen again) fails when ICP moves any "
        "ball farther in any direction.",
    )
    max_rotation_deg: float = Field(
        0.5,
        gt=0.0,
        description="How far the balls' fits leave a view's turn open. A refinement turning the view more "
        "than this about the vertical is rejected (the ground and the upright trunk do not hold that turn; "
        "its tilt yields to the ground up to max_disagreement_deg). A choice of balls the surfaces must "
        "confirm fails when ICP turns the view more about any axis. When such a choice, made again, rests on "
        "a ball placed unseen in the view or the reference view, the view may turn as far as moves the balls "
        "it shares with the reference by max_ball_shift_m about their midpoint, at most "
        "max_rotation_found_by_position_deg.",
    )
    max_ball_shift_found_by_position_m: float = Field(
        0.05,
        gt=0.0,
        description="As max_ball_shift_m, for a view whose balls, or the reference view's, include one found "
        "where the other views place it: a fragment of a ball, whose centre is known to a few centimetres.",
    )
    max_rotation_found_by_position_deg: float = Field(
        3.0,
        gt=0.0,
        description="As max_rotation_deg, for such a view: a few centimetres at balls 0.6-1.5 m apart; also "
        "the most a view held by two balls and a ball placed unseen may turn (see max_rotation_deg).",
    )
    max_disagreement_m: float = Field(
        0.05,
        gt=0.0,
        description="When the views' surfaces line up only with some ball centre moved farther than this, "
        "the registration fails: the balls' fits err by millimetres, a fragment's by a few centimetres; "
        "beyond, a look-alike (a sphere fitted on the trunk, an apple) was taken for a ball.",
    )
    max_trunk_mismatch_m: float = Field(
        0.4,
        gt=0.0,
        description="Registered by the balls, the trunk each view finds on its own (the circle of the arc "
        "of bark it sees) must stand within this of the reference view's, or else each view must also hold "
        "a trunk's circle within this of the other's (one view's best circle may be a trellis post, or "
        "suckers beside a trunk that weeds half hide), else the registration fails. On sound registrations "
        "the feet stand a few centimetres apart, up to 19 cm where suckers pull one view's circle (twice the "
        "largest trunk radius the search takes); a registration on look-alikes puts them metres apart while "
        "ICP, lining up flat ground, barely moves.",
    )
    trunk_coincidence_m: float = Field(
        0.06,
        gt=0.0,
        description="The views' trunks coincide where the trunk each view finds on its own stands within "
        "this of the first view's that finds one: the arcs of one trunk seen from two sides, registered "
        "soundly, give circles a few centimetres apart (36 sound registrations of mixed 2064 within 4 cm), "
        "though a post, suckers or weeds may make one view's best circle stand apart on a sound registration "
        "too. A first choice of balls that passes every check with its trunks apart is weighed against the "
        "choices made with each ball ruled out in turn; a choice made again that the surfaces do not confirm "
        "within a sound registration's bounds stands only where its trunks coincide and it passes a first "
        "choice's checks. Well below max_trunk_mismatch_m.",
    )
    max_disagreement_deg: float = Field(
        6.0,
        gt=0.0,
        description="When the views' surfaces line up only with a view turned more than this, the "
        "registration fails: twice the turn a fragment's registration leaves open "
        "(max_rotation_found_by_position_deg). Balls nearly in a line hold a view's turn about that line "
        "loosely, so a look-alike there moves the balls little but turns the view by degrees.",
    )


class MetricsConfig(_Section):
    """Canopy metrics (``metrics.py``)."""

    support_radius_m: float = Field(
        0.05, gt=0.0, description="Neighbourhood in which the top and the crown base need supporting points."
    )
    top_support_points: int = Field(
        2,
        ge=1,
        description="The top, and each of the two points whose distance is W, count only with this many "
        "other points within support_radius_m.",
    )
    edge_px: float = Field(
        0.5,
        ge=0.0,
        description="Each extreme of the crown (W's two ends, the top, the lowest leaf) is moved outward by "
        "this many depth pixel pitches (the pitch where it lies): sampled on a pixel grid at a random phase, "
        "the last pixel that reads an object lies on average half a pitch inside its outline (0.5, from the "
        "geometry of sampling; 0 measures the points' own extremes).",
    )
    base_support_points: int = Field(
        4, ge=1, description="The crown base counts only with this many other points within support_radius_m."
    )
    pole_width_m: float = Field(
        0.03,
        gt=0.0,
        description="A slab of the tree support_radius_m high (the top's own neighbourhood) whose points "
        "(nine in ten) lie within this horizontal distance of their median, and whose median lies within it "
        "of the slab above's, is as thin as a pole: a support stake 1-3 cm thick with the depth noise and "
        "the views' registration, or a leader's bare tip.",
    )
    max_thin_top_m: float = Field(
        0.25,
        ge=0.0,
        description="The merged tree's top may be as thin as a pole over at most this length (a "
        "leader's bare tip: up to 25 cm, with no margin, on 100 simulated trees, the first 40 of mixed "
        "2091 and the 60 of 2096); a longer run is refused as what a support stake standing above the "
        "crown shows, which would add its length to H and D. A one-view capture is not judged. Raise it "
        "for trees whose leaders are bare that far.",
    )
    kde_bandwidth_m: float = Field(0.04, gt=0.0, description="Gaussian kernel bandwidth h of eq. 7, metres.")
    kde_threshold: float = Field(
        0.6,
        gt=0.0,
        description="Crown base z_f of eq. 8: the lowest z where f(z) * H first exceeds this (dimensionless: "
        "1 is the density of points spread evenly over the tree's height).",
    )
    voxel_volume_m: float = Field(0.05, gt=0.0, description="Voxel edge for the occupied-voxel crown volume.")
    crown_base_min_radius_m: float = Field(
        0.25, gt=0.0, description="Crown base: points this far from the trunk's axis count as crown."
    )
    crown_link_m: float = Field(
        0.1,
        gt=0.0,
        description="Foliage and spreading points closer than this form one body; the crown is the largest "
        "body and those at its height. Ground vegetation, suckers and fallen fruit stand farther below it, "
        "across the bare trunk.",
    )
    trunk_column_radius_m: float = Field(
        0.1,
        gt=0.0,
        description="Foliage this close to the trunk's axis (suckers, bark coloured by the leaves behind it) "
        "joins the crown only within crown_link_m of it, and never links anything to it (weeds at the foot).",
    )
    trunk_slab_m: float = Field(
        0.1,
        gt=0.0,
        description="The trunk's axis is followed up from its foot in slabs this high: the bark's circle is "
        "found in each (a trunk bends a few centimetres between nodes, 10-30 cm apart).",
    )
    trunk_max_lean_deg: float = Field(
        35.0,
        ge=0.0,
        lt=90.0,
        description="The trunk's axis leans at most this far from vertical between the slabs where it is "
        "found, degrees: trellis systems that slant their trees (Tatura, V-trellis) plant them at up to 30; "
        "0 keeps the axis plumb above the foot.",
    )
    trunk_max_gap_m: float = Field(
        0.3,
        ge=0.0,
        description="The trunk's axis ends once more than this height of slabs in a row have not shown "
        "its bark's circle: a sucker or a tuft of weeds hides the trunk over a few decimetres, the crown "
        "for good (a circle found above it is a branch or the leader's tip, not the trunk).",
    )
    trunk_bark_tolerance_m: float = Field(
        0.015,
        gt=0.0,
        description="A point lies on a slab's bark circle within this distance of it, and a slab's circle "
        "is at most this much narrower than the last one's and wider than the narrowest so far: the depth "
        "noise at a few metres, the bark's roughness, and the views' registration, whose small turn shifts "
        "them apart with the height (the foot's own circle, at the height the views are refined on, takes "
        "1 cm).",
    )
    trunk_min_points: int = Field(
        20,
        ge=3,
        description="A slab's bark circle needs at least this many points on it (a trunk seen by one view "
        "over 10 cm shows hundreds).",
    )
    frame_margin_px: float = Field(
        3.0,
        gt=0.0,
        le=20.0,
        description="A tree point within this many pixels of an edge of its view's depth image is where the "
        "tree may run out of that image; another view looked beyond it if the point, moved this many pixels "
        "beyond that edge, falls this many pixels inside the other's image. Where none did, the "
        "merged measurement is refused (a view's own metrics are marked cut_by_frame). 3 px: the half pixel "
        "by which the last point sampled lies inside an outline, and the pixel or two the flying-pixel "
        "window (flying_window_px) may drop at a depth edge.",
    )
    frame_hidden_margin_m: float = Field(
        0.1,
        gt=0.0,
        le=1.0,
        description="A view that does not frame the tree whole looked beyond another's edge only where it "
        "saw there: its depth reads no nearer than that place less this (a leaf layer and the depth noise), "
        "or nothing; nearer, the crown in front hides it.",
    )
    frame_min_points: int = Field(
        3,
        ge=1,
        description="Fewer tree points than this at an image's edge are specks (flying pixels), not a tree "
        "cut by the frame: as many as make the top (itself and top_support_points others), so that a top "
        "the metrics would take is never too few to be a cut.",
    )
    frame_up_within_deg: float = Field(
        60.0,
        gt=0.0,
        lt=90.0,
        description="An image's edge faces up (down) when the image's outward axis across it points within "
        "this angle, degrees, of the vertical (of straight down): a cut there may make H and D (the crown "
        "base) read wrong; otherwise it faces sideways (W). An upright camera's top edge, or a portrait "
        "one's side, whatever its field of view or pitch up to this angle.",
    )
    crown_piece_min_voxels: int = Field(
        5,
        ge=1,
        description="A body apart from the crown's main body counts as crown only with at least this many "
        "occupied 4 cm voxels (a cluster of leaves); fewer is a speck: flying pixels, a glint of wire.",
    )
    seen_through_margin_m: float = Field(
        0.1,
        gt=0.0,
        description="A point that another view's depth readings, all round where it projects, put at least "
        "this far behind it was seen through by that view: a mixed pixel or a wire thinner than a pixel, "
        "not a surface; it is no crown. Many times the depth noise at 4 m (about 1.3 cm in sun) and the "
        "views' registration (a few mm).",
    )
    seen_through_window_px: int = Field(
        1,
        ge=0,
        le=5,
        description="Pixels on each side of where a point projects in another view that must all see past "
        "it (1: a 3x3 window): a point at a leaf's edge may project a pixel off the leaf.",
    )
    seen_through_reach_percentile: float = Field(
        95.0,
        gt=0.0,
        le=100.0,
        description="A view reads any surface nearer than this percentile of its own depth readings "
        "(foliage, bark and soil return the sensor's light well): a pixel without a reading looking at a "
        "place that near saw nothing there.",
    )
    crown_piece_min_bottom_m: float = Field(
        0.3,
        ge=0.0,
        description="A body apart from the crown's main body counts as crown only if its lowest point is at "
        "least this high above the ground: one reaching lower rises from the ground (a trellis post, a "
        "stake, a tall weed), where no crown hangs. Tree points start 0.12 m above the local ground.",
    )
    wire_piece_min_length_m: float = Field(
        0.1,
        gt=0.0,
        description="A body apart from the crown's main body that is a level straight line at least this "
        "long is a piece of trellis wire seen beside the crown, not crown: apple leaves are 5-10 cm long.",
    )
    wire_piece_max_thickness_m: float = Field(
        0.015,
        gt=0.0,
        description="Such a line's points stand at most this far (RMS) above or below it: half the wire "
        "tolerance. Across it in plan they may spread further (mixed pixels lie along the camera's rays).",
    )
    foliage_min_exgr: float = Field(
        0.15, ge=0.0, description="Points whose ExGR vegetation index exceeds this are foliage (crown base)."
    )


class MeasureConfig(_Section):
    """All parameters of one measurement. Units are metres unless a name says otherwise."""

    balls: BallConfig = Field(default_factory=BallConfig)
    roi: RoiConfig = Field(default_factory=RoiConfig)
    wires: WireConfig = Field(default_factory=WireConfig)
    poles: PoleConfig = Field(default_factory=PoleConfig)
    filters: FilterConfig = Field(default_factory=FilterConfig)
    ground: GroundConfig = Field(default_factory=GroundConfig)
    icp: IcpConfig = Field(default_factory=IcpConfig)
    metrics: MetricsConfig = Field(default_factory=MetricsConfig)

    def merged(self, overrides: dict[str, Any]) -> MeasureConfig:
        """A copy with ``overrides`` (a nested dict of the same shape, any depth) applied and validated."""
        return MeasureConfig.model_validate(deep_merge(self.model_dump(), overrides))


def deep_merge(base: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    """``base`` with ``overrides`` applied at any depth: where both hold a dict the two are merged, else the
    override's value replaces the base's (the way several settings overrides, or a job's, are combined)."""
    out = dict(base)
    for key, value in overrides.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = deep_merge(out[key], value)
        else:
            out[key] = value
    return out
