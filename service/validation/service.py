"""Manual measurements paired with the service's, and the paper's Table 1 over the pairs.

Each manual measurement is paired with the measurement of the same tree (by orchard, row and tree name)
whose capture lies nearest in time to noon UTC of the manual day, within a window of days: a tree grows,
so a capture months away measures another tree. Over the pairs, per view mode (each single view and the
merged views, the paper's V1, V2 and V1+V2) and metric, the table gives n, R², RMSE and ARE:

- R² = 1 - Σ(c - m)² / Σ(m - mean(m))², of calculated c against manual m (the 1:1 line, not a fitted one:
  a measurement biased by 10 % has a lower R², as it should);
- RMSE = sqrt(mean((c - m)²)), metres; ARE = mean(|c - m| / m), per cent.
"""

from __future__ import annotations

import csv
import io
from collections import defaultdict
from datetime import UTC, datetime, time
from typing import Any

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session

from service.models import Capture, ManualMeasurement, Measurement, Orchard, Row, Tree
from service.spreadsheet import safe_cell
from service.validation.manual import METRIC_COLUMNS
from service.validation.schemas import Metrics, ModeMetricRow, Pair, Unmatched, Validation

__all__ = ["MERGED", "calculated_metrics", "validation", "validation_csv"]

MERGED = "merged"
_SECONDS_PER_DAY = 86_400.0


def validation(
    session: Session, *, window_days: float, orchard: str | None = None, row: str | None = None
) -> Validation:
    """Every manual measurement (of ``orchard`` and ``row`` when given) paired or reported unmatched, and
    Table 1 over the pairs."""
    query = select(ManualMeasurement).order_by(
        ManualMeasurement.orchard,
        ManualMeasurement.row,
        ManualMeasurement.tree,
        ManualMeasurement.measured_on,
    )
    if orchard is not None:
        query = query.where(ManualMeasurement.orchard == orchard)
    if row is not None:
        query = query.where(ManualMeasurement.row == row)
    manual = list(session.scalars(query))
    measured = _measurements_by_tree(session, {(m.orchard, m.row, m.tree) for m in manual})
    pairs: list[Pair] = []
    unmatched: list[Unmatched] = []
    for record in manual:
        names = (record.orchard, record.row, record.tree)
        where = {"orchard": record.orchard, "row": record.row, "tree": record.tree}
        if names not in measured:
            reason = "no tree of this name in this row and orchard has been measured"
            unmatched.append(Unmatched(**where, measured_on=record.measured_on, reason=reason))
            continue
        noon = datetime.combine(record.measured_on, time(12), tzinfo=UTC)
        measurement_id, captured_at, result = min(
            measured[names], key=lambda found: (abs((found[1] - noon).total_seconds()), -found[0])
        )
        apart = abs((captured_at - noon).total_seconds()) / _SECONDS_PER_DAY
        if apart > window_days:
            reason = (
                f"the nearest measurement of this tree (id {measurement_id}) was captured {apart:.1f} days "
                f"away, beyond the window of {window_days:g} days (window_days)"
            )
            unmatched.append(Unmatched(**where, measured_on=record.measured_on, reason=reason))
            continue
        pairs.append(
            Pair(
                **where,
                measured_on=record.measured_on,
                manual=Metrics(
                    height_m=record.height_m, width_m=record.width_m, thickness_m=record.thickness_m
                ),
                measurement_id=measurement_id,
                captured_at=captured_at,
                days_apart=(captured_at - noon).total_seconds() / _SECONDS_PER_DAY,
                calculated=calculated_metrics(result["modes"]),
            )
        )
    return Validation(window_days=window_days, pairs=pairs, unmatched=unmatched, table=table(pairs))


def calculated_metrics(modes: dict[str, dict[str, Any]]) -> dict[str, Metrics]:
    """Per mode of a measurement (its document's ``modes``), H, W and D as Table 1 compares them; a view's
    metric its own image's edge cut (``cut_by_frame``: the tree runs out of that view) is None, left out
    like a value not measured, since it is a bound, not a measurement."""
    return {
        mode: Metrics(
            **{
                metric: None if metric in values.get("cut_by_frame", ()) else values.get(metric)
                for metric in METRIC_COLUMNS
            }
        )
        for mode, values in modes.items()
    }


def table(pairs: list[Pair]) -> list[ModeMetricRow]:
    """Table 1 over ``pairs``: per view mode (views in name order, then merged) and metric, over the pairs
    that have both the manual and the calculated value."""
    modes = sorted({mode for pair in pairs for mode in pair.calculated if mode != MERGED})
    modes.append(MERGED)
    rows = []
    for mode in modes:
        for metric in METRIC_COLUMNS:
            values = [
                (getattr(pair.calculated[mode], metric), getattr(pair.manual, metric))
                for pair in pairs
                if mode in pair.calculated
            ]
            known = np.array([(c, m) for c, m in values if c is not None and m is not None], dtype=float)
            rows.append(_row(mode, metric, known.reshape(-1, 2)))
    return rows


def _row(mode: str, metric: str, pairs: np.ndarray) -> ModeMetricRow:
    n = int(pairs.shape[0])
    if n == 0:
        return ModeMetricRow(mode=mode, metric=metric, n=0, r2=None, rmse_m=None, are_pct=None)
    calculated, manual = pairs[:, 0], pairs[:, 1]
    residual = calculated - manual
    spread = float(np.sum((manual - manual.mean()) ** 2))
    return ModeMetricRow(
        mode=mode,
        metric=metric,
        n=n,
        r2=1.0 - float(np.sum(residual**2)) / spread if n > 1 and spread > 0 else None,
        rmse_m=float(np.sqrt(np.mean(residual**2))),
        are_pct=100.0 * float(np.mean(np.abs(residual) / manual)),
    )


def validation_csv(result: Validation) -> str:
    """Table 1 as CSV, one line per view mode and metric."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(("mode", "metric", "n", "r2", "rmse_m", "are_pct"))
    for row in result.table:
        cells = (row.mode, row.metric, row.n, row.r2, row.rmse_m, row.are_pct)
        writer.writerow([safe_cell("" if cell is None else cell) for cell in cells])
    return buffer.getvalue()


def _measurements_by_tree(
    session: Session, names: set[tuple[str, str, str]]
) -> dict[tuple[str, str, str], list[tuple[int, datetime, dict]]]:
    """Per (orchard, row, tree) among ``names``, its measurements: id, capture time and result."""
    found: dict[tuple[str, str, str], list[tuple[int, datetime, dict]]] = defaultdict(list)
    if not names:
        return found
    query = (
        select(Orchard.name, Row.name, Tree.name, Measurement.id, Capture.captured_at, Measurement.result)
        .join(Row, Row.orchard_id == Orchard.id)
        .join(Tree, Tree.row_id == Row.id)
        .join(Measurement, Measurement.tree_id == Tree.id)
        .join(Capture, Capture.id == Measurement.capture_id)
        .where(Orchard.name.in_({orchard for orchard, _, _ in names}))
    )
    for orchard, row, tree, measurement_id, captured_at, result in session.execute(query):
        if (orchard, row, tree) in names:
            found[(orchard, row, tree)].append((measurement_id, captured_at, result))
    return found
