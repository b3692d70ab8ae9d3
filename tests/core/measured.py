"""What the whole-pipeline tests share: a simulated capture's truth and how near a measurement came to it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from canopy_core.measure import Measurement
from canopy_core.metrics import CanopyMetrics


def truth_of(capture: Path) -> dict:
    """The simulator's ground truth of a capture folder (its ``ground_truth.json``)."""
    return json.loads((capture / "ground_truth.json").read_text())


def assert_within_5_percent(merged: CanopyMetrics, truth: dict) -> None:
    """H, W and D each within 5 % of the simulator's truth: measured right, not merely measured."""
    for key in ("height_m", "width_m", "thickness_m"):
        assert getattr(merged, key) == pytest.approx(truth[key], rel=0.05), key


def ball_error_m(result: Measurement, truth: dict, view: str, color: str) -> float:
    """How far the ball chosen for ``color`` in ``view`` lies from the simulator's ball, in that view."""
    chosen = next(v for v in result.views if v.view == view).balls[color].center_m
    view_from_world = np.linalg.inv(np.array(truth["views"][view]["camera_to_world"]))
    actual = view_from_world @ np.append(truth["balls"][color]["center_m"], 1.0)
    return float(np.linalg.norm(chosen - actual[:3]))


def assert_balls_true(
    result: Measurement,
    truth: dict,
    colors: tuple[str, ...] = ("red", "yellow", "blue"),
    *,
    within_m: float = 0.02,
) -> None:
    """The balls of ``colors`` chosen in every view each within ``within_m`` of the simulator's: the true
    balls, not look-alikes that happen to register the views (those stand decimetres off; a ball found as
    a fragment where the other views place it, a few centimetres)."""
    for view in result.views:
        for color in colors:
            assert ball_error_m(result, truth, view.view, color) < within_m, (view.view, color)
