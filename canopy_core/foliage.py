"""Telling foliage from wood and soil by colour: the excess-green-minus-excess-red vegetation index.

ExGR = ExG - ExR with ExG = 2g - r - b and ExR = 1.4r - g on chromaticity coordinates (r = R / (R + G + B),
...) is positive for green leaves and negative for bark, soil, posts and sky, whatever the brightness, so
it holds in sun and shade (Meyer & Neto 2008, Computers and Electronics in Agriculture 63(2):282-293,
whose threshold is zero; the pipeline uses 0.15 because greenish, lichen-covered bark reaches 0.1).
Plain ExG alone takes dark olive bark for foliage. Points without colour (not seen by the colour camera,
black here) and points too dark to have a chromaticity (deep shade) have index 0 and are foliage only with
a negative threshold, which the configuration refuses.
"""

from __future__ import annotations

import numpy as np

__all__ = ["excess_green_minus_red", "foliage_mask"]

_MIN_CHANNEL_SUM = 24
"""Colours whose 8-bit channels sum to less than this have no usable chromaticity: rounding alone moves
each chromaticity coordinate by up to 0.5 / sum, so the index (3g - 2.4r - b) by up to 3.2 / sum, which
reaches the foliage threshold (0.15) at a sum of 21. Bark in deep shade is such a colour."""


def excess_green_minus_red(colors_rgb: np.ndarray) -> np.ndarray:
    """The ExGR index of ``(N, 3)`` uint8 RGB colours; 0 for black (no colour) and colours too dark to have
    a chromaticity."""
    rgb = colors_rgb.astype(np.float32)
    total = rgb.sum(axis=1)
    r, g, b = (rgb / np.maximum(total, 1.0)[:, None]).T
    index = (2.0 * g - r - b) - (1.4 * r - g)
    return np.where(total >= _MIN_CHANNEL_SUM, index, 0.0)


def foliage_mask(colors_rgb: np.ndarray, *, min_index: float = 0.0) -> np.ndarray:
    """True for points whose colour is that of leaves (ExGR above ``min_index``)."""
    return excess_green_minus_red(colors_rgb) > min_index
