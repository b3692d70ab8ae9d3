"""Foliage by colour: leaves in sun and shade are foliage; bark (even olive), soil and sky are not."""

from __future__ import annotations

import numpy as np

from canopy_core.foliage import excess_green_minus_red, foliage_mask

LEAVES = np.array([[60, 110, 40], [20, 45, 15], [120, 170, 80], [90, 140, 60]], dtype=np.uint8)
NOT_LEAVES = np.array(
    [[48, 47, 29], [42, 45, 28], [110, 80, 60], [140, 120, 100], [180, 200, 230], [200, 35, 35], [0, 0, 0]],
    dtype=np.uint8,
)


def test_leaves_in_sun_and_shade_are_foliage() -> None:
    assert foliage_mask(LEAVES, min_index=0.15).all()


def test_olive_bark_soil_sky_ball_and_missing_colour_are_not_foliage() -> None:
    assert not foliage_mask(NOT_LEAVES, min_index=0.15).any()


def test_index_does_not_depend_on_brightness() -> None:
    leaf = np.array([[60, 110, 40], [30, 55, 20]], dtype=np.uint8)  # the same leaf, lit and in shade
    index = excess_green_minus_red(leaf)
    assert np.isclose(index[0], index[1], atol=0.01)
