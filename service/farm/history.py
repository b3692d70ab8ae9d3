"""A tree's growth: its measurements in the order they were captured, as JSON, CSV and a plot of H, W and D
against the capture date."""

from __future__ import annotations

import csv
import io
from datetime import datetime

from pydantic import BaseModel
from sqlalchemy import select
from sqlalchemy.orm import Session

from service.errors import NotFound
from service.models import Capture, Measurement, Orchard, Row, Tree, utc_text
from service.spreadsheet import safe_cell

__all__ = ["HistoryPoint", "TreeHistory", "history_csv", "history_png", "tree_history"]

_METRICS = (("height_m", "H", "tab:red"), ("width_m", "W", "tab:purple"), ("thickness_m", "D", "tab:blue"))


class HistoryPoint(BaseModel):
    """One measurement of the tree: when its capture was taken and its merged H, W and D (m)."""

    measurement_id: int
    captured_at: datetime
    height_m: float
    width_m: float
    thickness_m: float


class TreeHistory(BaseModel):
    """A tree's measurements, oldest capture first."""

    tree_id: int
    orchard: str
    row: str
    tree: str
    measurements: list[HistoryPoint]


def tree_history(session: Session, tree_id: int) -> TreeHistory:
    """The tree's measurements by capture time (then id); a 404 problem when there is no such tree."""
    names = session.execute(
        select(Orchard.name, Row.name, Tree.name)
        .join(Row, Row.orchard_id == Orchard.id)
        .join(Tree, Tree.row_id == Row.id)
        .where(Tree.id == tree_id)
    ).one_or_none()
    if names is None:
        raise NotFound(f"no tree with id {tree_id}", tree_id=tree_id)
    rows = session.execute(
        select(
            Measurement.id,
            Capture.captured_at,
            Measurement.height_m,
            Measurement.width_m,
            Measurement.thickness_m,
        )
        .join(Capture, Capture.id == Measurement.capture_id)
        .where(Measurement.tree_id == tree_id)
        .order_by(Capture.captured_at, Measurement.id)
    ).all()
    return TreeHistory(
        tree_id=tree_id,
        orchard=names[0],
        row=names[1],
        tree=names[2],
        measurements=[
            HistoryPoint(measurement_id=mid, captured_at=at, height_m=h, width_m=w, thickness_m=d)
            for mid, at, h, w, d in rows
        ],
    )


def history_csv(history: TreeHistory) -> str:
    """The history as CSV: one line per measurement, oldest first; names safe for spreadsheets."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(
        ("orchard", "row", "tree", "captured_at", "measurement_id", "height_m", "width_m", "thickness_m")
    )
    for point in history.measurements:
        writer.writerow(
            [
                safe_cell(cell)
                for cell in (
                    history.orchard,
                    history.row,
                    history.tree,
                    utc_text(point.captured_at),
                    point.measurement_id,
                    point.height_m,
                    point.width_m,
                    point.thickness_m,
                )
            ]
        )
    return buffer.getvalue()


def history_png(history: TreeHistory) -> bytes:
    """H, W and D against the capture date, one line each (gid ``history-height_m`` and so on)."""
    # Imported here, not at the top: matplotlib adds 0.9 s to every API start, and only figure routes draw.
    from matplotlib.dates import AutoDateLocator, ConciseDateFormatter, date2num
    from matplotlib.figure import Figure

    figure = Figure(figsize=(7, 3.6), dpi=100, layout="constrained")
    ax = figure.subplots()
    dates = date2num([point.captured_at for point in history.measurements])
    for field, short, colour in _METRICS:
        values = [getattr(point, field) for point in history.measurements]
        ax.plot(dates, values, marker="o", color=colour, label=short, gid=f"history-{field}")
    ax.xaxis_date()
    locator = AutoDateLocator()
    ax.xaxis.set_major_locator(locator)
    ax.xaxis.set_major_formatter(ConciseDateFormatter(locator))
    ax.set_ylabel("m")
    ax.set_title(f"{history.orchard} / {history.row} / {history.tree}: growth")
    ax.grid(True, color="0.9")
    ax.legend(loc="upper left", fontsize=8)
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png")
    return buffer.getvalue()
