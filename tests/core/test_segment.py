"""Separating the tree from a neighbour's crown reaching into the region of interest."""

from __future__ import annotations

import numpy as np

from canopy_core.segment import tree_component


def _blob(rng: np.random.Generator, centre: list[float], radius: float, n: int) -> np.ndarray:
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    return np.asarray(centre) + direction * radius * rng.uniform(0.8, 1.0, size=(n, 1))


def _trunk(rng: np.random.Generator, top_m: float = 0.9) -> np.ndarray:
    return np.column_stack(
        [rng.normal(0, 0.02, 500), rng.normal(0, 0.02, 500), rng.uniform(0.12, top_m, 500)]
    )


def _tree(rng: np.random.Generator) -> np.ndarray:
    return np.vstack([_trunk(rng), _blob(rng, [0.0, 0.0, 1.7], 0.8, 8000)])


def _inside(points: np.ndarray, radius: float) -> np.ndarray:
    return points[np.linalg.norm(points[:, :2], axis=1) < radius]


def test_neighbour_crown_reaching_through_the_wall_is_dropped() -> None:
    rng = np.random.default_rng(0)
    tree = _tree(rng)
    neighbour = _inside(_blob(rng, [2.1, 0.0, 1.6], 0.9, 8000), 1.5)  # 0.4 m gap to the tree's crown
    keep = tree_component(np.vstack([tree, neighbour]), np.zeros(2), roi_radius_m=1.5)
    assert keep[: len(tree)].all() and not keep[len(tree) :].any()


def test_crown_floating_above_its_trunk_is_kept() -> None:
    """Scaffold branches hidden by leaves: a 25 cm gap between the trunk's top and the crown."""
    rng = np.random.default_rng(1)
    tree = np.vstack([_trunk(rng, top_m=0.65), _blob(rng, [0.0, 0.0, 1.7], 0.8, 8000)])
    keep = tree_component(tree, np.zeros(2), roi_radius_m=1.5)
    assert keep.all()


def test_crown_piece_inside_the_cylinder_is_kept_even_when_apart() -> None:
    rng = np.random.default_rng(2)
    tree = _tree(rng)
    branch_tip = _blob(rng, [0.0, 1.05, 1.7], 0.08, 300)  # 17 cm from the crown, 0.3 m from the wall
    keep = tree_component(np.vstack([tree, branch_tip]), np.zeros(2), roi_radius_m=1.5)
    assert keep.all()


def test_isolated_specks_are_dropped() -> None:
    rng = np.random.default_rng(3)
    tree = _tree(rng)
    speck = np.array([[0.9, -0.9, 0.15], [0.91, -0.9, 0.15]])
    keep = tree_component(np.vstack([tree, speck]), np.zeros(2), roi_radius_m=1.5)
    assert keep[: len(tree)].all() and not keep[len(tree) :].any()
