"""Row and orchard summaries: per metric, count, mean, median, min, max and standard deviation over the
latest measurement of each tree, and the trees beyond two standard deviations; as JSON and as CSV.

A row's trees are meant to be alike (one variety, one age, one training system): a tree far from its row
is one to look at, a dying tree or a measurement gone wrong.
"""

from __future__ import annotations

import csv
import io
from typing import TYPE_CHECKING

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session

from service.errors import NotFound
from service.farm.schemas import MetricStats, OrchardSummary, Outlier, Summary
from service.farm.service import latest_measurements
from service.models import Orchard, Row, Tree
from service.spreadsheet import safe_cell

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = [
    "OUTLIER_DEVIATIONS",
    "SUMMARY_METRICS",
    "orchard_summary",
    "row_figure",
    "row_figure_png",
    "row_summary",
    "summary_csv",
]

SUMMARY_METRICS = ("height_m", "width_m", "thickness_m", "volume_hull_m3", "projected_area_m2")
"""H, W, D, crown volume (convex hull) and projected crown area, as each measurement's result names them."""
OUTLIER_DEVIATIONS = 2.0
"""A tree further than this many standard deviations from its row's or orchard's mean is an outlier."""
_CSV_COLUMNS = ("scope", "orchard", "row", "metric", "count", "mean", "median", "min", "max", "std")


def row_summary(session: Session, row_id: int) -> Summary:
    """The summary of one row; a 404 problem when there is no such row."""
    row = session.get(Row, row_id)
    if row is None:
        raise NotFound(f"no row with id {row_id}", row_id=row_id)
    orchard = session.get(Orchard, row.orchard_id)
    assert orchard is not None
    trees = list(session.scalars(select(Tree).where(Tree.row_id == row_id).order_by(Tree.id)))
    return _summary(session, "row", row.id, row.name, orchard.name, trees, {row.id: row.name})


def orchard_summary(session: Session, orchard_id: int) -> OrchardSummary:
    """The summary of one orchard and of each of its rows; a 404 problem when there is no such orchard."""
    orchard = session.get(Orchard, orchard_id)
    if orchard is None:
        raise NotFound(f"no orchard with id {orchard_id}", orchard_id=orchard_id)
    rows = list(session.scalars(select(Row).where(Row.orchard_id == orchard_id).order_by(Row.name, Row.id)))
    names = {row.id: row.name for row in rows}
    trees = list(session.scalars(select(Tree).where(Tree.row_id.in_(list(names))).order_by(Tree.id)))
    whole = _summary(session, "orchard", orchard.id, orchard.name, orchard.name, trees, names)
    return OrchardSummary(**whole.model_dump(), rows=[row_summary(session, row.id) for row in rows])


def _summary(
    session: Session,
    scope: str,
    key: int,
    name: str,
    orchard: str,
    trees: list[Tree],
    row_names: dict[int, str],
) -> Summary:
    latest = latest_measurements(session, [tree.id for tree in trees])
    measured = [tree for tree in trees if tree.id in latest]
    metrics: dict[str, MetricStats] = {}
    outliers: list[Outlier] = []
    for metric in SUMMARY_METRICS:
        values = np.array([float(latest[tree.id][0].result[metric]) for tree in measured])
        if values.size == 0:
            continue
        std = float(values.std(ddof=1)) if values.size > 1 else None
        mean = float(values.mean())
        metrics[metric] = MetricStats(
            count=int(values.size),
            mean=mean,
            median=float(np.median(values)),
            min=float(values.min()),
            max=float(values.max()),
            std=std,
        )
        if std:
            for tree, value in zip(measured, values, strict=True):
                deviations = (value - mean) / std
                if abs(deviations) > OUTLIER_DEVIATIONS:
                    outliers.append(
                        Outlier(
                            tree_id=tree.id,
                            tree=tree.name,
                            row=row_names[tree.row_id],
                            metric=metric,
                            value=float(value),
                            deviations=float(deviations),
                        )
                    )
    return Summary(
        scope=scope,
        id=key,
        name=name,
        orchard=orchard,
        trees=len(trees),
        measured_trees=len(measured),
        metrics=metrics,
        outliers=outliers,
    )


def summary_csv(summary: Summary) -> str:
    """The summary as CSV: one line per scope (the orchard, then each row) and metric."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(_CSV_COLUMNS)
    parts = [summary, *summary.rows] if isinstance(summary, OrchardSummary) else [summary]
    for part in parts:
        row = part.name if part.scope == "row" else ""
        for metric, stats in part.metrics.items():
            writer.writerow(
                [
                    safe_cell(cell)
                    for cell in (
                        part.scope,
                        part.orchard,
                        row,
                        metric,
                        stats.count,
                        stats.mean,
                        stats.median,
                        stats.min,
                        stats.max,
                        "" if stats.std is None else stats.std,
                    )
                ]
            )
    return buffer.getvalue()


def row_figure_png(session: Session, row_id: int) -> bytes:
    """:func:`row_figure` as PNG."""
    buffer = io.BytesIO()
    row_figure(session, row_id).savefig(buffer, format="png")
    return buffer.getvalue()


def row_figure(session: Session, row_id: int) -> Figure:
    """The row at a glance: each tree's latest H and W as bars along the row (trees by name), the row's mean
    of each as a dashed line, and the trees beyond 2 standard deviations marked; a 404 problem when there
    is no such row."""
    # Imported here, not at the top: matplotlib adds 0.9 s to every API start, and only figure routes draw.
    from matplotlib.figure import Figure

    summary = row_summary(session, row_id)
    trees = list(session.scalars(select(Tree).where(Tree.row_id == row_id).order_by(Tree.name, Tree.id)))
    latest = latest_measurements(session, [tree.id for tree in trees])
    measured = [tree for tree in trees if tree.id in latest]
    far = {(outlier.tree_id, outlier.metric) for outlier in summary.outliers}
    figure = Figure(figsize=(max(6.0, 0.45 * len(measured) + 2), 4.0), dpi=100, layout="constrained")
    ax = figure.subplots()
    positions = np.arange(len(measured))
    for offset, (metric, short, colour) in enumerate(
        (("height_m", "H", "tab:red"), ("width_m", "W", "tab:purple"))
    ):
        values = [float(latest[tree.id][0].result[metric]) for tree in measured]
        bars = ax.bar(positions + (offset - 0.5) * 0.4, values, 0.4, color=colour, alpha=0.75, label=short)
        for bar, tree in zip(bars, measured, strict=True):
            bar.set_gid(f"{metric}-{tree.name}")
            if (tree.id, metric) in far:
                bar.set_edgecolor("black")
                bar.set_linewidth(2)
        if metric in summary.metrics:
            ax.axhline(summary.metrics[metric].mean, color=colour, ls="--", lw=1, gid=f"mean-{metric}")
    ax.set_xticks(positions, [tree.name for tree in measured], rotation=45 if len(measured) > 12 else 0)
    ax.set_ylabel("m")
    ax.set_title(
        f"{summary.orchard} / {summary.name}: latest H and W of {summary.measured_trees} of {summary.trees} "
        "trees (dashed: row mean; outlined: beyond 2 SD)"
    )
    ax.legend(loc="lower right", fontsize=8)
    return figure
