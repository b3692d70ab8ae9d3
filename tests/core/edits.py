"""Edits of simulated capture folders that tests share: what happens to a ball in the field."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
from PIL import Image


def take_away_blue_ball(capture: Path, view: str) -> None:
    """Remove the blue ball from a view, as if a foot had kicked it away: the pixels around it lose their
    depth, and every blue pixel is painted grey."""
    truth = json.loads((capture / "ground_truth.json").read_text())
    camera = json.loads((capture / view / "camera.json").read_text())
    world = np.append(truth["balls"]["blue"]["center_m"], 1.0)
    x, y, z = (np.linalg.inv(np.array(truth["views"][view]["camera_to_world"])) @ world)[:3]
    depth_file = capture / view / "depth.png"
    depth = np.asarray(Image.open(depth_file)).copy()
    intrinsics = camera["depth_intrinsics"]
    rows, cols = np.mgrid[: depth.shape[0], : depth.shape[1]]
    u, v = intrinsics["fx"] * x / z + intrinsics["cx"], intrinsics["fy"] * y / z + intrinsics["cy"]
    depth[(cols - u) ** 2 + (rows - v) ** 2 <= (2.0 * intrinsics["fx"] * 0.05 / z) ** 2] = 0
    Image.fromarray(depth).save(depth_file)
    paint_blue_grey(capture, view)


def paint_blue_grey(capture: Path, view: str) -> None:
    """Paint every blue pixel of a view's colour image grey: the blue ball keeps its shape, not its colour."""
    color_file = next((capture / view).glob("color.*"))
    rgb = np.asarray(Image.open(color_file).convert("RGB")).copy()
    hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)
    rgb[(hsv[..., 0] > 95) & (hsv[..., 0] < 135) & (hsv[..., 1] > 80)] = (120, 110, 100)
    Image.fromarray(rgb).save(color_file)
