"""Scenario families: what a capture adds to the plain orchard so that a tool tuned on them meets real ones.

``green`` is the plain scene (green grass, a herbicide strip of colours kept out of the balls' ranges, no
fruit, wires or weeds, no cast shadows, a neutral camera) and renders exactly as it always has. Every other
family adds, on top of the same scene, its element and a per-view colour camera drift (automatic white
balance and exposure: channel gains within about +-25 %, exposure 0.6-1.5):

- ``dry``: a floor palette beyond green grass (straw, red and brown soil, dark mulch; :mod:`.palette`),
  often fallen leaves;
- ``fruit``: apples in the crown and on the ground (:mod:`.fruit`);
- ``wires``: a trellis of steel wires through the crown (:mod:`.trellis`);
- ``weeds``: weeds and suckers at the trunk's foot (:mod:`.weeds`);
- ``harsh``: hard sun with cast shadows, exposure and contrast extremes;
- ``mixed``: each element with some probability, sun and shadows at random: the family the product is
  judged on.

Randomness: the plain scene draws from the streams it always has; each element draws from its own stream
(children of one new child of the seed), so adding an element never changes another one.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from canopy_core.simulate.fruit import VARIETIES, fallen_apples, hanging_apples
from canopy_core.simulate.mesh import Mesh
from canopy_core.simulate.palette import GroundPalette, fallen_leaves, random_palette
from canopy_core.simulate.raycast import Sphere
from canopy_core.simulate.scene import Orchard
from canopy_core.simulate.sensor import CameraResponse, Sunlight, random_sunlight
from canopy_core.simulate.trellis import Trellis, build_trellis
from canopy_core.simulate.weeds import Weeds, grow_weeds

__all__ = [
    "Dressing",
    "Scenario",
    "ScenarioPlan",
    "ScenarioStreams",
    "camera_responses",
    "dress_orchard",
    "fallen_fruit_beside",
    "parse_scenario",
    "plan_scenario",
    "scenario_sunlight",
]


class Scenario(StrEnum):
    """A family of scenes (see the module's description)."""

    GREEN = "green"
    DRY = "dry"
    FRUIT = "fruit"
    WIRES = "wires"
    WEEDS = "weeds"
    HARSH = "harsh"
    MIXED = "mixed"


_DRY_FALLEN_LEAVES_CHANCE = 0.6
_MIXED_CHANCES = {
    "ground_palette": 0.6,
    "fallen_leaves": 0.35,
    "fruit": 0.5,
    "wires": 0.5,
    "weeds": 0.5,
    "harsh_light": 0.3,
    "shadows": 0.5,
}
"""How often a mixed capture holds each element (shadows: when its light is not already harsh)."""
_HARSH_STRENGTH = (0.8, 1.0)
_HARSH_SKYLIGHT_SCALE = (0.3, 0.55)
_HARSH_DIRECT_SCALE = (1.6, 2.4)
"""A clear sky: a third to a half of the usual sky light, about twice the sun; shadows get 3-8 times darker
than sunlit ground."""
_HARSH_CONTRAST = (1.2, 1.7)
_MIXED_CONTRAST = (0.9, 1.15)
_RED_BLUE_GAIN_SIGMA = 0.1
_GREEN_GAIN_SIGMA = 0.04
_MAX_LOG_GAIN = np.log(1.25)
"""White-balance gains are log-normal, red and blue more than green, clipped to +-25 %."""
_EXPOSURE = (0.6, 1.5)
"""Exposure scales are log-uniform within this range."""


@dataclass(frozen=True)
class ScenarioPlan:
    """Which elements a capture holds."""

    scenario: Scenario
    ground_palette: bool
    fallen_leaves: bool
    fruit: bool
    wires: bool
    weeds: bool
    harsh_light: bool
    shadows: bool
    camera_drift: bool


@dataclass(frozen=True, eq=False)
class ScenarioStreams:
    """One random stream per element, all children of the seed's scenario stream."""

    plan: np.random.Generator
    palette: np.random.Generator
    leaves: np.random.Generator
    fruit: np.random.Generator
    fallen_fruit: np.random.Generator
    wires: np.random.Generator
    weeds: np.random.Generator
    light: np.random.Generator
    camera: np.random.Generator

    @classmethod
    def spawn(cls, seed_sequence: np.random.SeedSequence) -> ScenarioStreams:
        """The streams, in a fixed order, from ``seed_sequence``."""
        names = [name for name in cls.__dataclass_fields__]
        children = seed_sequence.spawn(len(names))
        return cls(
            **{name: np.random.default_rng(child) for name, child in zip(names, children, strict=True)}
        )


@dataclass(frozen=True, eq=False)
class Dressing:
    """A plan carried out: the dressed orchard (its mesh holds every added triangle), the apples hanging in
    the main tree's crown, the apples' main variety, and what was added (None: not in this capture)."""

    plan: ScenarioPlan
    orchard: Orchard
    palette: GroundPalette | None
    fallen_leaves: int
    hanging_apples: tuple[Sphere, ...]
    apple_variety: str | None
    trellis: Trellis | None
    weeds: Weeds | None


def parse_scenario(name: str) -> Scenario:
    """The scenario called ``name``.

    Raises
    ------
    ValueError
        If there is none by that name; the message lists the names.
    """
    try:
        return Scenario(name)
    except ValueError:
        names = ", ".join(scenario.value for scenario in Scenario)
        raise ValueError(f"unknown scenario {name!r}; choose one of {names}") from None


def plan_scenario(scenario: Scenario, rng: np.random.Generator) -> ScenarioPlan:
    """What a capture of ``scenario`` holds; the mixed family draws it with ``rng``."""
    if scenario is Scenario.MIXED:
        drawn = {element: bool(rng.random() < chance) for element, chance in _MIXED_CHANCES.items()}
        drawn["shadows"] = drawn["shadows"] or drawn["harsh_light"]
        return ScenarioPlan(scenario=scenario, camera_drift=True, **drawn)
    return ScenarioPlan(
        scenario=scenario,
        ground_palette=scenario is Scenario.DRY,
        fallen_leaves=scenario is Scenario.DRY and bool(rng.random() < _DRY_FALLEN_LEAVES_CHANCE),
        fruit=scenario is Scenario.FRUIT,
        wires=scenario is Scenario.WIRES,
        weeds=scenario is Scenario.WEEDS,
        harsh_light=scenario is Scenario.HARSH,
        shadows=scenario is Scenario.HARSH,
        camera_drift=scenario is not Scenario.GREEN,
    )


def dress_orchard(
    orchard: Orchard, plan: ScenarioPlan, streams: ScenarioStreams, *, near_posts: bool = False
) -> Dressing:
    """Add ``plan``'s elements to ``orchard`` (built without posts when the plan has wires: the trellis
    brings its own, within the crown's reach with ``near_posts``)."""
    palette, ground_colors = (
        random_palette(streams.palette, orchard.ground) if plan.ground_palette else (None, None)
    )
    leaves = fallen_leaves(streams.leaves, orchard.ground) if plan.fallen_leaves else None
    trellis = build_trellis(streams.wires, orchard, near_posts=near_posts) if plan.wires else None
    weeds = grow_weeds(streams.weeds, orchard.ground, orchard.main_tree) if plan.weeds else None
    extras: list[Mesh] = [part.mesh for part in (trellis, weeds) if part is not None]
    if leaves is not None:
        extras.append(leaves)
    variety = str(streams.fruit.choice(VARIETIES)) if plan.fruit else None
    apples = hanging_apples(streams.fruit, orchard.main_tree, variety) if variety is not None else ()
    return Dressing(
        plan=plan,
        orchard=orchard.dressed(
            ground_colors=ground_colors,
            extras=extras,
            post_positions=() if trellis is None else trellis.post_positions,
        ),
        palette=palette,
        fallen_leaves=0 if leaves is None else leaves.triangle_count,
        hanging_apples=apples,
        apple_variety=variety,
        trellis=trellis,
        weeds=weeds,
    )


def fallen_fruit_beside(
    dressing: Dressing, streams: ScenarioStreams, balls: tuple[Sphere, ...]
) -> tuple[Sphere, ...]:
    """Apples on the ground for the balls ``balls`` (none if the plan has no fruit)."""
    if dressing.apple_variety is None:
        return ()
    return fallen_apples(streams.fallen_fruit, dressing.orchard.ground, balls, dressing.apple_variety)


def scenario_sunlight(
    plan: ScenarioPlan, sun_rng: np.random.Generator, light_rng: np.random.Generator, strength: float | None
) -> Sunlight:
    """The sun as the plain scene draws it (``sun_rng``), made hard for harsh light: strength 0.8-1.0
    (unless ``strength`` is given), a third to half the sky light and about twice the sun."""
    if not plan.harsh_light:
        return random_sunlight(sun_rng, strength=strength)
    hard = float(light_rng.uniform(*_HARSH_STRENGTH)) if strength is None else strength
    sunlight = random_sunlight(sun_rng, strength=hard)
    return Sunlight(
        strength=sunlight.strength,
        direction=sunlight.direction,
        skylight_scale=float(light_rng.uniform(*_HARSH_SKYLIGHT_SCALE)),
        direct_scale=float(light_rng.uniform(*_HARSH_DIRECT_SCALE)),
    )


def camera_responses(
    plan: ScenarioPlan, rng: np.random.Generator, n_views: int
) -> tuple[CameraResponse | None, ...]:
    """Each view's colour camera response: None (neutral) without camera drift, else white-balance gains,
    an exposure scale and, in the harsh and mixed families, a contrast."""
    if not plan.camera_drift:
        return (None,) * n_views
    responses = []
    for _ in range(n_views):
        log_gains = rng.normal(0.0, [_RED_BLUE_GAIN_SIGMA, _GREEN_GAIN_SIGMA, _RED_BLUE_GAIN_SIGMA])
        gains = np.exp(np.clip(log_gains, -_MAX_LOG_GAIN, _MAX_LOG_GAIN))
        exposure = float(np.exp(rng.uniform(*np.log(_EXPOSURE))))
        contrast = 1.0
        if plan.harsh_light:
            contrast = float(rng.uniform(*_HARSH_CONTRAST))
        elif plan.scenario is Scenario.MIXED:
            contrast = float(rng.uniform(*_MIXED_CONTRAST))
        responses.append(
            CameraResponse(
                gains=(float(gains[0]), float(gains[1]), float(gains[2])),
                exposure=exposure,
                contrast=contrast,
            )
        )
    return tuple(responses)
