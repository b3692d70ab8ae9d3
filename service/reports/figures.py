"""A measurement's figures, drawn headless with matplotlib from the measurement itself.

Each panel is a function drawing on a matplotlib ``Axes`` from the fused cloud's tree points (class 5:
exactly the points the merged metrics were read from) and the metrics' marks, so a figure shows where H, W
and D were taken, not a picture made apart from them. Every drawn element that carries a number has a
``gid`` (``tree-points``, ``width``, ``hull``, ``density``, ``threshold``, ``crown-base-kde``, ...), by
which tests and readers find it.

- ``elevation``: the tree from the side (along the row, x, against height z), the ground, H, the crown base
  and D;
- ``top``: the tree from above with the convex hull of its points and the W segment (eq. 6);
- ``density``: the density of the points' heights times H against z, the threshold, and the crown base and
  D it gives (eqs. 7-8);
- ``modes``: H, W and D per view and merged (the paper's V1, V2, V1+V2);
- ``balls-<view>``: each view's colour image with the balls chosen and the spheres rejected;
- ``report``: the first four in one picture.
"""

from __future__ import annotations

import io

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from PIL import Image, ImageDraw, ImageFont

from canopy_core.ball_preview import draw_ball_preview
from canopy_core.capture import Capture
from canopy_core.cloud_io import Cloud, PointClass
from canopy_core.config import MetricsConfig
from canopy_core.measure import MERGED, Measurement
from canopy_core.metrics import CanopyMetrics, height_density, supported_hull

__all__ = [
    "FIGURE_NAMES",
    "draw_elevation",
    "draw_height_density",
    "draw_modes",
    "draw_top_view",
    "measurement_figures",
    "report_png",
]

FIGURE_NAMES = ("report", "elevation", "top", "density", "modes")
"""The figures every measurement has; ``balls-<view>`` (``views/1`` as ``balls-views-1``) besides."""
_MAX_DRAWN_POINTS = 8_000
"""Points drawn per panel at most (a random, fixed sample): a cloud's 100 000 look the same, drawn slower."""
_DPI = 100
_TITLE_PX = 40
"""Height of the composed report's title line, pixels."""
_BALL_PICTURE_WIDTH_PX = 720
"""The ball pictures' width (the report shows them at about this size; a 1920 px colour image is scaled)."""
_PHOTO_PNG_LEVEL = 1
"""zlib level of the ball pictures (photographs): level 6 takes 2.5 times as long for 10 % fewer bytes."""
_H, _BASE, _W = "tab:red", "tab:blue", "tab:purple"


def measurement_figures(measurement: Measurement, capture: Capture) -> dict[str, bytes]:
    """Every figure of a measurement as PNG bytes, by name (see the module docstring)."""
    cloud, merged = measurement.cloud, measurement.merged
    pngs: dict[str, bytes] = {}
    figure, ax = _single((6.4, 5.2))
    draw_elevation(ax, cloud, merged)
    pngs["elevation"] = _png(figure)
    figure, ax = _single((6.4, 5.2))
    draw_top_view(ax, cloud, merged, measurement.config.metrics)
    pngs["top"] = _png(figure)
    figure, ax = _single((6.4, 5.2))
    draw_height_density(ax, cloud, merged, measurement.config.metrics)
    pngs["density"] = _png(figure)
    figure, ax = _single((6.4, 5.2))
    draw_modes(ax, measurement.modes)
    pngs["modes"] = _png(figure)
    manifest = measurement.manifest
    title = (
        f"{manifest.orchard} / {manifest.row} / {manifest.tree}, {manifest.captured_at}: "
        f"H {merged.height_m:.2f} m, W {merged.width_m:.2f} m, D {merged.thickness_m:.2f} m"
    )
    pngs["report"] = report_png([pngs[name] for name in ("elevation", "top", "density", "modes")], title)
    for view, choice in zip(capture.views, measurement.ball_choices, strict=True):
        image = draw_ball_preview(view, choice, measurement.config.balls, max_width_px=_BALL_PICTURE_WIDTH_PX)
        buffer = io.BytesIO()
        Image.fromarray(image).save(buffer, format="PNG", compress_level=_PHOTO_PNG_LEVEL)
        pngs["balls-" + view.name.replace("/", "-")] = buffer.getvalue()
    return pngs


def report_png(panels: list[bytes], title: str) -> bytes:
    """The panels (PNG, drawn once for their own figures) two to a row under ``title``, as one PNG: the
    whole measurement on one picture, for a notebook or an e-mail."""
    images = [Image.open(io.BytesIO(panel)).convert("RGB") for panel in panels]
    width, height = max(i.width for i in images), max(i.height for i in images)
    columns, rows = 2, (len(images) + 1) // 2
    sheet = Image.new("RGB", (columns * width, _TITLE_PX + rows * height), "white")
    for index, image in enumerate(images):
        sheet.paste(image, ((index % columns) * width, _TITLE_PX + (index // columns) * height))
    ImageDraw.Draw(sheet).text(
        (sheet.width // 2, _TITLE_PX // 2), title, fill="black", anchor="mm", font=ImageFont.load_default(20)
    )
    buffer = io.BytesIO()
    sheet.save(buffer, format="PNG")
    return buffer.getvalue()


def draw_elevation(ax: Axes, cloud: Cloud, metrics: CanopyMetrics) -> None:
    """The tree from the side: its points (x along the row against z, in their colours), the ground at
    z = 0, the top (H), the crown base and D between them."""
    tree = _tree(cloud)
    _scatter(ax, tree.points_m[:, [0, 2]], tree.colors_rgb, gid="tree-points")
    left, right = _span(tree.points_m[:, 0])
    ax.axhline(0.0, color="saddlebrown", lw=1.5, gid="ground", label="ground (z = 0)")
    ax.axhline(metrics.height_m, color=_H, lw=1.2, gid="height", label=f"H = {metrics.height_m:.2f} m")
    ax.axhline(
        metrics.crown_base_m,
        color=_BASE,
        lw=1.2,
        gid="crown-base",
        label=f"crown base {metrics.crown_base_m:.2f} m",
    )
    top_x = metrics.marks.top_m[0]
    ax.plot([top_x], [metrics.height_m], marker="v", color=_H, ms=9, gid="top")
    middle = right + 0.05 * (right - left)
    ax.annotate(
        "",
        xy=(middle, metrics.height_m),
        xytext=(middle, metrics.crown_base_m),
        arrowprops={"arrowstyle": "<->", "color": "black"},
        gid="thickness",
    )
    ax.text(
        middle,
        (metrics.height_m + metrics.crown_base_m) / 2,
        f" D = {metrics.thickness_m:.2f} m",
        va="center",
    )
    ax.set_xlim(left - 0.1 * (right - left), right + 0.35 * (right - left))
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("along the row, x (m)")
    ax.set_ylabel("height, z (m)")
    ax.set_title("Side elevation")
    ax.legend(loc="lower right", fontsize=8)


def draw_top_view(ax: Axes, cloud: Cloud, metrics: CanopyMetrics, config: MetricsConfig) -> None:
    """The tree from above: its points, the convex hull that W is read from (its stray vertices dropped,
    :func:`~canopy_core.metrics.supported_hull`) and the W segment between W's two ends (eq. 6): the hull's
    diameter, each end moved out by half a depth pixel."""
    tree = _tree(cloud)
    xy = tree.points_m[:, :2]
    _scatter(ax, xy, tree.colors_rgb, gid="tree-points")
    hull = supported_hull(
        tree.points_m, support_radius_m=config.support_radius_m, support_points=config.top_support_points
    )
    if hull.size >= 3:
        ring = xy[np.append(hull, hull[0])]
        ax.plot(ring[:, 0], ring[:, 1], color="0.3", lw=1, gid="hull", label="convex hull")
    ends = np.array(metrics.marks.width_ends_m)
    ax.plot(
        ends[:, 0],
        ends[:, 1],
        color=_W,
        lw=2.5,
        marker="o",
        gid="width",
        label=f"W = {metrics.width_m:.2f} m",
    )
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("along the row, x (m)")
    ax.set_ylabel("across the row, y (m)")
    ax.set_title("Top view")
    ax.legend(loc="lower right", fontsize=8)


def draw_height_density(ax: Axes, cloud: Cloud, metrics: CanopyMetrics, config: MetricsConfig) -> None:
    """The density f(z) of the tree points' heights (eq. 7), times H so that 1 means "spread evenly over
    the height", against z; the threshold, the crown base it gives (eq. 8: where f(z) H first reaches the
    threshold) and D, and the geometric crown base the headline D uses."""
    z = _tree(cloud).points_m[:, 2]
    grid, density = height_density(z, bandwidth_m=config.kde_bandwidth_m)
    ax.plot(density * metrics.height_m, grid, color="tab:green", lw=1.5, gid="density", label="f(z) · H")
    ax.axvline(config.kde_threshold, color="0.4", ls="--", lw=1, gid="threshold", label="threshold")
    ax.axhline(
        metrics.crown_base_kde_m,
        color=_BASE,
        ls="--",
        lw=1.2,
        gid="crown-base-kde",
        label=f"crown base (eq. 8) {metrics.crown_base_kde_m:.2f} m, D {metrics.thickness_kde_m:.2f} m",
    )
    ax.axhline(
        metrics.crown_base_m,
        color=_BASE,
        lw=1.2,
        gid="crown-base",
        label=f"crown base (geometric) {metrics.crown_base_m:.2f} m, D {metrics.thickness_m:.2f} m",
    )
    ax.axhline(metrics.height_m, color=_H, lw=1.2, gid="height", label=f"H = {metrics.height_m:.2f} m")
    ax.set_xlabel("height density times H")
    ax.set_ylabel("height, z (m)")
    ax.set_title("Density of heights (eqs. 7-8)")
    ax.legend(loc="lower right", fontsize=8)


def draw_modes(ax: Axes, modes: dict[str, CanopyMetrics]) -> None:
    """H, W and D side by side for each view alone and for the merged views."""
    names = [name for name in modes if name != MERGED] + [MERGED]
    metrics = (("H", "height_m"), ("W", "width_m"), ("D", "thickness_m"))
    width = 0.8 / len(names)
    for index, name in enumerate(names):
        values = [getattr(modes[name], field) for _, field in metrics]
        offsets = np.arange(len(metrics)) + (index - (len(names) - 1) / 2) * width
        bars = ax.bar(
            offsets, values, width, label=name, color="tab:green" if name == MERGED else f"C{index}"
        )
        for bar in bars:
            bar.set_gid(f"mode-{name}")
        ax.bar_label(bars, fmt="%.2f", fontsize=7)
    ax.set_xticks(np.arange(len(metrics)), [short for short, _ in metrics])
    ax.set_ylabel("m")
    ax.set_title("Per view and merged")
    ax.legend(fontsize=8)


def _tree(cloud: Cloud) -> Cloud:
    if cloud.classes is None:
        return cloud
    return cloud.only(cloud.classes == PointClass.TREE)


def _scatter(ax: Axes, xy: np.ndarray, colors_rgb: np.ndarray | None, *, gid: str) -> None:
    """Points drawn small in their own colours (a fixed random sample of at most ``_MAX_DRAWN_POINTS``);
    the artist holds exactly the points drawn."""
    if xy.shape[0] > _MAX_DRAWN_POINTS:
        keep = np.random.default_rng(0).choice(xy.shape[0], _MAX_DRAWN_POINTS, replace=False)
        xy = xy[keep]
        colors_rgb = None if colors_rgb is None else colors_rgb[keep]
    colors = "tab:green" if colors_rgb is None else colors_rgb / 255.0
    ax.scatter(xy[:, 0], xy[:, 1], s=1.5, c=colors, linewidths=0, gid=gid, rasterized=True)


def _span(values: np.ndarray) -> tuple[float, float]:
    return (float(values.min()), float(values.max())) if values.size else (-1.0, 1.0)


def _single(size_in: tuple[float, float]) -> tuple[Figure, Axes]:
    # Fixed margins, not matplotlib's constrained layout: it measured every label again for each figure and
    # took half the drawing time of a measurement's figures.
    figure = Figure(figsize=size_in, dpi=_DPI)
    figure.subplots_adjust(left=0.12, right=0.97, bottom=0.11, top=0.93)
    return figure, figure.subplots()


def _png(figure: Figure) -> bytes:
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png")
    return buffer.getvalue()
