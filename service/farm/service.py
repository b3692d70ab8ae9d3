"""Queries of the farm management system: orchards, rows, trees, their measurements, CSV export."""

from __future__ import annotations

import csv
import io
from collections.abc import Iterator
from dataclasses import fields
from datetime import datetime
from typing import Any

from sqlalchemy import Select, func, select
from sqlalchemy.orm import Session

from canopy_core.metrics import CanopyMetrics
from service.farm.schemas import MeasurementSummary, OrchardOut, RowOut, TreeOut
from service.models import Capture, Measurement, Orchard, Row, Tree
from service.pagination import Page, keyset, page_of
from service.problems import NotFound

__all__ = [
    "CSV_COLUMNS",
    "get_measurement",
    "list_orchards",
    "list_rows",
    "list_tree_measurements",
    "list_trees",
    "measurement_document",
    "measurements_csv",
]

CSV_COLUMNS = (
    "measurement_id",
    "orchard",
    "row",
    "tree",
    "captured_at",
    *(field.name for field in fields(CanopyMetrics)),
    "capture_id",
    "job_id",
)
"""One line per measurement: who, when, then every merged-view metric (metres, m², m³)."""


def _exists(session: Session, model: type[Orchard] | type[Row] | type[Tree], key: int, what: str) -> None:
    if session.get(model, key) is None:
        raise NotFound(f"no {what} with id {key}")


def list_orchards(session: Session, *, cursor: str | None, limit: int) -> Page[OrchardOut]:
    """Orchards in the order they were first seen."""
    rows = list(session.scalars(keyset(select(Orchard), Orchard.id, cursor, limit)))
    items = [OrchardOut.model_validate(row, from_attributes=True) for row in rows]
    return page_of(items, [row.id for row in rows], limit)


def list_rows(session: Session, orchard_id: int, *, cursor: str | None, limit: int) -> Page[RowOut]:
    """The rows of an orchard."""
    _exists(session, Orchard, orchard_id, "orchard")
    rows = list(
        session.scalars(keyset(select(Row).where(Row.orchard_id == orchard_id), Row.id, cursor, limit))
    )
    items = [RowOut.model_validate(row, from_attributes=True) for row in rows]
    return page_of(items, [row.id for row in rows], limit)


def _summaries() -> Select[Measurement, datetime]:
    return select(Measurement, Capture.captured_at).join(Capture, Capture.id == Measurement.capture_id)


def _summary(measurement: Measurement, captured_at: datetime) -> MeasurementSummary:
    return MeasurementSummary(
        id=measurement.id,
        job_id=measurement.job_id,
        capture_id=measurement.capture_id,
        tree_id=measurement.tree_id,
        captured_at=captured_at,
        height_m=measurement.height_m,
        width_m=measurement.width_m,
        thickness_m=measurement.thickness_m,
        created_at=measurement.created_at,
        href=f"/v1/measurements/{measurement.id}",
    )


def list_trees(session: Session, row_id: int, *, cursor: str | None, limit: int) -> Page[TreeOut]:
    """The trees of a row, each with its latest measurement."""
    _exists(session, Row, row_id, "row")
    trees = list(session.scalars(keyset(select(Tree).where(Tree.row_id == row_id), Tree.id, cursor, limit)))
    latest: dict[int, MeasurementSummary] = {}
    if trees:
        newest = (
            select(Measurement.tree_id, func.max(Capture.captured_at).label("captured_at"))
            .join(Capture, Capture.id == Measurement.capture_id)
            .where(Measurement.tree_id.in_([tree.id for tree in trees]))
            .group_by(Measurement.tree_id)
            .subquery()
        )
        query_latest = (
            _summaries()
            .join(
                newest,
                (newest.c.tree_id == Measurement.tree_id) & (newest.c.captured_at == Capture.captured_at),
            )
            .order_by(Measurement.id)
        )
        for measurement, captured_at in session.execute(query_latest):
            latest[measurement.tree_id] = _summary(measurement, captured_at)  # the newest job wins
    items = [
        TreeOut(
            id=tree.id,
            row_id=tree.row_id,
            name=tree.name,
            created_at=tree.created_at,
            latest_measurement=latest.get(tree.id),
        )
        for tree in trees
    ]
    return page_of(items, [tree.id for tree in trees], limit)


def list_tree_measurements(
    session: Session, tree_id: int, *, cursor: str | None, limit: int
) -> Page[MeasurementSummary]:
    """A tree's measurements, newest first (by measurement id): its growth history."""
    _exists(session, Tree, tree_id, "tree")
    query = _summaries().where(Measurement.tree_id == tree_id)
    rows = session.execute(keyset(query, Measurement.id, cursor, limit, newest_first=True)).all()
    items = [_summary(measurement, captured_at) for measurement, captured_at in rows]
    return page_of(items, [measurement.id for measurement, _ in rows], limit)


def get_measurement(session: Session, measurement_id: int) -> Measurement:
    """The measurement with this id, or a 404 problem."""
    measurement = session.get(Measurement, measurement_id)
    if measurement is None:
        raise NotFound(f"no measurement with id {measurement_id}", measurement_id=measurement_id)
    return measurement


def measurement_document(session: Session, measurement: Measurement) -> dict[str, Any]:
    """The whole measurement: the core's result document, with ids and the cloud's address added."""
    captured_at = session.scalar(select(Capture.captured_at).where(Capture.id == measurement.capture_id))
    return {
        "id": measurement.id,
        "job_id": measurement.job_id,
        "capture_id": measurement.capture_id,
        "tree_id": measurement.tree_id,
        "captured_at": captured_at.isoformat() if captured_at else None,
        "created_at": measurement.created_at.isoformat(),
        "cloud": {
            "href": f"/v1/measurements/{measurement.id}/cloud.ply",
            "points": measurement.cloud_points,
            "sha256": measurement.cloud_sha256,
        },
        **measurement.result,
    }


def measurements_csv(
    session: Session, *, orchard: str | None, row: str | None, since: datetime | None
) -> Iterator[str]:
    """CSV text, header first, of every measurement matching the filters, by orchard, row, tree, time."""
    query = (
        select(Measurement, Capture.captured_at, Orchard.name, Row.name, Tree.name)
        .join(Capture, Capture.id == Measurement.capture_id)
        .join(Tree, Tree.id == Measurement.tree_id)
        .join(Row, Row.id == Tree.row_id)
        .join(Orchard, Orchard.id == Row.orchard_id)
        .order_by(Orchard.name, Row.name, Tree.name, Capture.captured_at, Measurement.id)
    )
    if orchard is not None:
        query = query.where(Orchard.name == orchard)
    if row is not None:
        query = query.where(Row.name == row)
    if since is not None:
        query = query.where(Capture.captured_at >= since)
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    rows = session.execute(query.execution_options(yield_per=500))
    for measurement, captured_at, orchard_name, row_name, tree_name in rows:
        identity = {
            "measurement_id": measurement.id,
            "orchard": orchard_name,
            "row": row_name,
            "tree": tree_name,
            "captured_at": captured_at.isoformat(),
            "capture_id": measurement.capture_id,
            "job_id": measurement.job_id,
        }
        writer.writerow([identity.get(column, measurement.result.get(column)) for column in CSV_COLUMNS])
        yield buffer.getvalue()
        buffer.seek(0)
        buffer.truncate()
    yield buffer.getvalue()
