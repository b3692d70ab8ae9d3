"""A measurement's report page: one HTML document with its numbers, registration diagnostics, figures (as
data URIs) and the fused cloud for the 3D viewer, so a grower can check where H, W and D were taken.

The page needs nothing from the internet: the viewer's script and three.js come from the service's own
``/static`` (``service/static``); everything else is inside the document.
"""

from __future__ import annotations

import base64
from pathlib import Path
from typing import Any

import numpy as np
from jinja2 import Environment, FileSystemLoader, select_autoescape

from canopy_core.cloud_io import Cloud
from service.farm.history import TreeHistory

__all__ = ["MAX_VIEWER_POINTS", "report_html"]

MAX_VIEWER_POINTS = 80_000
"""The 3D viewer gets at most this many points (a fixed random sample): enough to see the tree, light
enough for a phone."""
FIGURE_ORDER = ("elevation", "top", "density", "modes", "growth")
_TEMPLATES = Environment(
    loader=FileSystemLoader(Path(__file__).parent / "templates"),
    autoescape=select_autoescape(["html"]),
    trim_blocks=True,
    lstrip_blocks=True,
)


def report_html(
    document: dict[str, Any], figures: dict[str, bytes], cloud: Cloud, growth: TreeHistory
) -> str:
    """The report page of the measurement ``document`` (as ``GET /v1/measurements/{id}`` answers it), with
    its PNG ``figures`` by name (``growth`` among them when the tree was measured more than once), its fused
    ``cloud`` and the tree's measurements over time."""
    views = [name for name in document["modes"] if name != "merged"]
    ordered = [name for name in FIGURE_ORDER if name in figures]
    ordered += sorted(name for name in figures if name not in FIGURE_ORDER and name != "report")
    return _TEMPLATES.get_template("report.html").render(
        m=document,
        views=views,
        figures=[(name, _data_uri(figures[name])) for name in ordered],
        viewer=_viewer_data(cloud, document["marks"]),
        growth=growth,
    )


def _data_uri(png: bytes) -> str:
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def _viewer_data(cloud: Cloud, marks: dict[str, Any]) -> dict[str, Any]:
    """The cloud for the viewer: float32 positions, uint8 colours and ASPRS classes, little-endian,
    base64."""
    if len(cloud) > MAX_VIEWER_POINTS:
        keep = np.zeros(len(cloud), dtype=bool)
        keep[np.random.default_rng(0).choice(len(cloud), MAX_VIEWER_POINTS, replace=False)] = True
        cloud = cloud.only(keep)
    colors = cloud.colors_rgb if cloud.colors_rgb is not None else np.full(cloud.points_m.shape, 90)
    return {
        "points": len(cloud),
        "positions_b64": _base64(cloud.points_m.astype("<f4")),
        "colors_b64": _base64(colors.astype(np.uint8)),
        "classes_b64": None if cloud.classes is None else _base64(cloud.classes.astype(np.uint8)),
        "marks": marks,
    }


def _base64(values: np.ndarray) -> str:
    return base64.b64encode(np.ascontiguousarray(values).tobytes()).decode("ascii")
