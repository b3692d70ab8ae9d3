"""The validation's scatter plot: calculated against manual H, W and D, one marker per view mode, with the
1:1 line (the paper's Figures 8 and 9)."""

from __future__ import annotations

import io

from service.validation.manual import METRIC_COLUMNS
from service.validation.schemas import Validation
from service.validation.service import MERGED

__all__ = ["scatter_png"]

_TITLES = {"height_m": "Height H", "width_m": "Max. width W", "thickness_m": "Crown thickness D"}
_MARKERS = ("^", "s", "D", "v", "P")


def scatter_png(result: Validation) -> bytes:
    """A PNG of three panels (H, W, D), each the calculated values against the manual ones in metres, one
    marker per view mode (merged filled), with the 1:1 line and each mode's n and ARE in the legend."""
    # Imported here, not at the top: matplotlib adds 0.9 s to every API start, and only figure routes draw.
    from matplotlib.figure import Figure

    figure = Figure(figsize=(12, 4.2), dpi=100, layout="constrained")
    axes = figure.subplots(1, len(METRIC_COLUMNS))
    modes = [row.mode for row in result.table if row.metric == METRIC_COLUMNS[0]]
    for ax, metric in zip(axes, METRIC_COLUMNS, strict=True):
        everything: list[float] = []
        for index, mode in enumerate(modes):
            points = [
                (getattr(pair.manual, metric), getattr(pair.calculated[mode], metric))
                for pair in result.pairs
                if mode in pair.calculated
            ]
            points = [(m, c) for m, c in points if m is not None and c is not None]
            if not points:
                continue
            manual, calculated = zip(*points, strict=True)
            everything += [*manual, *calculated]
            row = next(r for r in result.table if r.mode == mode and r.metric == metric)
            merged = mode == MERGED
            ax.scatter(
                manual,
                calculated,
                marker="o" if merged else _MARKERS[index % len(_MARKERS)],
                s=36 if merged else 24,
                facecolors="tab:green" if merged else "none",
                edgecolors="tab:green" if merged else f"C{index}",
                label=f"{mode} (n={row.n}, ARE {row.are_pct:.1f} %)",
            )
        if everything:
            low, high = min(everything), max(everything)
            margin = 0.05 * (high - low or 1.0)
            ax.plot(
                [low - margin, high + margin], [low - margin, high + margin], color="0.4", lw=1, label="1:1"
            )
            ax.set_xlim(low - margin, high + margin)
            ax.set_ylim(low - margin, high + margin)
            ax.legend(fontsize=8, loc="upper left")
        ax.set_aspect("equal", adjustable="box")
        ax.set_title(_TITLES[metric])
        ax.set_xlabel("manual (m)")
        ax.set_ylabel("calculated (m)")
        ax.grid(True, color="0.9")
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png")
    return buffer.getvalue()
