"""Fixtures for the core's tests: a small, valid capture folder that each test may break one way."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

CAMERA = {
    "depth_intrinsics": {"width": 64, "height": 48, "fx": 50.0, "fy": 50.0, "cx": 32.0, "cy": 24.0},
    "depth_scale": 1000.0,
}
MANIFEST = {
    "format": "canopy-capture/1",
    "orchard": "North block",
    "row": "R12",
    "tree": "T07",
    "captured_at": "2026-11-20T08:31:00Z",
    "sensor": "kinect-v2",
    "calibration_balls": {"diameter_m": 0.10, "colors": ["red", "yellow", "blue"]},
    "views": ["views/1", "views/2"],
}


def write_view(folder: Path, *, camera: dict = CAMERA, depth_mm: int = 2000) -> None:
    """A registered view: constant depth and a grey colour image of the camera's size."""
    folder.mkdir(parents=True, exist_ok=True)
    width, height = camera["depth_intrinsics"]["width"], camera["depth_intrinsics"]["height"]
    (folder / "camera.json").write_text(json.dumps(camera))
    Image.fromarray(np.full((height, width), depth_mm, dtype=np.uint16)).save(folder / "depth.png")
    Image.fromarray(np.full((height, width, 3), 128, dtype=np.uint8)).save(folder / "color.png")


@pytest.fixture
def capture_dir(tmp_path: Path) -> Path:
    """A valid two-view capture folder of tiny registered images."""
    root = tmp_path / "capture"
    root.mkdir()
    (root / "capture.json").write_text(json.dumps(MANIFEST))
    for view in MANIFEST["views"]:
        write_view(root / view)
    return root
