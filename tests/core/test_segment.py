"""Separating the tree from a neighbour's crown reaching into the region of interest."""

from __future__ import annotations

import numpy as np

from canopy_core.segment import tree_component


def _blob(rng: np.random.Generator, centre: list[float], radius: float, n: int) -> np.ndarray:
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    return np.asarray(centre) + direction * radius * rng.uniform(0.8, 1.0, size=(n, 1))


def _tree(rng: np.random.Generator) -> np.ndarray:
    trunk = np.column_stack([rng.normal(0, 0.02, 500), rng.normal(0, 0.02, 500), rng.uniform(0.12, 0.9, 500)])
    return np.vstack([trunk, _blob(rng, [0.0, 0.0, 1.7], 0.8, 8000)])


def test_neighbour_crown_beyond_a_gap_is_separated() -> None:
    rng = np.random.default_rng(0)
    tree = _tree(rng)
    neighbour = _blob(rng, [2.1, 0.0, 1.6], 0.9, 4000)  # 0.4 m gap to the tree's crown
    keep = tree_component(np.vstack([tree, neighbour]), np.zeros(2))
    assert keep[: len(tree)].all() and not keep[len(tree) :].any()


def test_crown_with_small_gaps_stays_whole() -> None:
    rng = np.random.default_rng(1)
    tree = _tree(rng)
    branch_tip = _blob(rng, [0.0, 0.95, 1.7], 0.08, 200)  # 7 cm from the crown's surface
    keep = tree_component(np.vstack([tree, branch_tip]), np.zeros(2))
    assert keep.all()


def test_without_a_trunk_in_view_everything_is_kept() -> None:
    rng = np.random.default_rng(2)
    crown = _blob(rng, [0.0, 0.0, 1.7], 0.8, 3000)
    assert tree_component(crown, np.array([5.0, 5.0])).all()
