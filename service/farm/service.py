"""Queries of the farm management system: orchards, rows, trees, their measurements, CSV export."""

from __future__ import annotations

import csv
import hashlib
import io
from collections.abc import Iterator
from dataclasses import fields
from datetime import datetime
from typing import Any, TypeVar

from sqlalchemy import Select, func, select
from sqlalchemy.orm import Session

from canopy_core import __version__
from canopy_core.metrics import CanopyMetrics
from service.conventions import strong_etag
from service.errors import NotFound
from service.farm.schemas import MeasurementSummary, OrchardOut, RowOut, TreeOut
from service.models import Capture, Measurement, Orchard, Row, Tree, utc_text
from service.pagination import Page, keyset, page_of
from service.spreadsheet import safe_cell

__all__ = [
    "CSV_COLUMNS",
    "get_measurement",
    "get_orchard",
    "get_row",
    "get_tree",
    "latest_measurements",
    "list_orchards",
    "list_rows",
    "list_tree_measurements",
    "list_trees",
    "measurement_document",
    "measurements_csv",
    "measurements_csv_etag",
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


Record = TypeVar("Record", Orchard, Row, Tree)


def _one(session: Session, model: type[Record], key: int) -> Record:
    """The orchard, row or tree with id ``key``, or a 404 problem naming it."""
    record = session.get(model, key)
    if record is None:
        what = model.__name__.lower()
        members: dict[str, Any] = {f"{what}_id": key}
        raise NotFound(f"no {what} with id {key}", **members)
    return record


def get_orchard(session: Session, orchard_id: int) -> OrchardOut:
    """The orchard with this id, or a 404 problem."""
    return OrchardOut.model_validate(_one(session, Orchard, orchard_id), from_attributes=True)


def get_row(session: Session, row_id: int) -> RowOut:
    """The row with this id, or a 404 problem."""
    return RowOut.model_validate(_one(session, Row, row_id), from_attributes=True)


def get_tree(session: Session, tree_id: int) -> TreeOut:
    """The tree with this id and its latest measurement, or a 404 problem."""
    return _trees_out(session, [_one(session, Tree, tree_id)])[0]


def list_orchards(session: Session, *, name: str | None, cursor: str | None, limit: int) -> Page[OrchardOut]:
    """Orchards in the order they were first seen; only the one called ``name`` if given."""
    query = select(Orchard)
    if name is not None:
        query = query.where(Orchard.name == name)
    rows = list(session.scalars(keyset(query, Orchard.id, cursor, limit)))
    items = [OrchardOut.model_validate(row, from_attributes=True) for row in rows]
    return page_of(items, [row.id for row in rows], limit)


def list_rows(
    session: Session, orchard_id: int, *, name: str | None, cursor: str | None, limit: int
) -> Page[RowOut]:
    """The rows of an orchard; only the one called ``name`` if given."""
    _one(session, Orchard, orchard_id)
    query = select(Row).where(Row.orchard_id == orchard_id)
    if name is not None:
        query = query.where(Row.name == name)
    rows = list(session.scalars(keyset(query, Row.id, cursor, limit)))
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


def list_trees(
    session: Session, row_id: int, *, name: str | None, cursor: str | None, limit: int
) -> Page[TreeOut]:
    """The trees of a row, each with its latest measurement; only the one called ``name`` if given."""
    _one(session, Row, row_id)
    query = select(Tree).where(Tree.row_id == row_id)
    if name is not None:
        query = query.where(Tree.name == name)
    trees = list(session.scalars(keyset(query, Tree.id, cursor, limit)))
    return page_of(_trees_out(session, trees), [tree.id for tree in trees], limit)


def latest_measurements(session: Session, tree_ids: list[int]) -> dict[int, tuple[Measurement, datetime]]:
    """Per tree, its most recent measurement by capture time (the newest job's, when one capture was
    measured twice) and that capture time; trees never measured are absent."""
    latest: dict[int, tuple[Measurement, datetime]] = {}
    if not tree_ids:
        return latest
    newest = (
        select(Measurement.tree_id, func.max(Capture.captured_at).label("captured_at"))
        .join(Capture, Capture.id == Measurement.capture_id)
        .where(Measurement.tree_id.in_(tree_ids))
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
        latest[measurement.tree_id] = (measurement, captured_at)  # the newest job wins
    return latest


def _trees_out(session: Session, trees: list[Tree]) -> list[TreeOut]:
    """The trees as the API shows them, each with its most recent measurement by capture time."""
    latest = latest_measurements(session, [tree.id for tree in trees])
    return [
        TreeOut(
            id=tree.id,
            row_id=tree.row_id,
            name=tree.name,
            created_at=tree.created_at,
            latest_measurement=_summary(*latest[tree.id]) if tree.id in latest else None,
        )
        for tree in trees
    ]


def list_tree_measurements(
    session: Session, tree_id: int, *, cursor: str | None, limit: int
) -> Page[MeasurementSummary]:
    """A tree's measurements, newest first (by measurement id): its growth history."""
    _one(session, Tree, tree_id)
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
    """The whole measurement: the core's result document, with ids and the cloud's address added, and the
    capture's time written as every time the API answers (UTC, ``Z``), whatever zone capture.json gave."""
    captured_at = session.scalars(
        select(Capture.captured_at).where(Capture.id == measurement.capture_id)
    ).one()
    return {
        "id": measurement.id,
        "job_id": measurement.job_id,
        "capture_id": measurement.capture_id,
        "tree_id": measurement.tree_id,
        "captured_at": utc_text(captured_at),
        "created_at": utc_text(measurement.created_at),
        "cloud": {
            "href": f"/v1/measurements/{measurement.id}/cloud.ply",
            "points": measurement.cloud_points,
            "sha256": measurement.cloud_sha256,
        },
        "figures": {
            name: f"/v1/measurements/{measurement.id}/figures/{name}.png"
            for name in measurement.figures or {}
        },
        **measurement.result,
        "capture": {**measurement.result["capture"], "captured_at": utc_text(captured_at)},
    }


def _csv_query(
    orchard: str | None, row: str | None, since: datetime | None
) -> Select[Measurement, datetime, str, str, str]:
    """The measurements the CSV export holds with these filters, with who and when, unordered."""
    query = (
        select(Measurement, Capture.captured_at, Orchard.name, Row.name, Tree.name)
        .join(Capture, Capture.id == Measurement.capture_id)
        .join(Tree, Tree.id == Measurement.tree_id)
        .join(Row, Row.id == Tree.row_id)
        .join(Orchard, Orchard.id == Row.orchard_id)
    )
    if orchard is not None:
        query = query.where(Orchard.name == orchard)
    if row is not None:
        query = query.where(Row.name == row)
    if since is not None:
        query = query.where(Capture.captured_at >= since)
    return query


def measurements_csv_etag(
    session: Session, *, orchard: str | None, row: str | None, since: datetime | None
) -> str:
    """The ETag of the CSV export with these filters, known before a line of it is written.

    A measurement never changes once stored and ids are never reused, so the set of lines is told by its
    count, highest id and sum of ids: a deleted one lowers the count, a new one raises the sum (also where
    PostgreSQL commits ids out of order). The service's version is in too: a new version may write the
    lines differently.
    """
    counted = _csv_query(orchard, row, since).with_only_columns(
        func.count(), func.max(Measurement.id), func.sum(Measurement.id)
    )
    count, highest, total = session.execute(counted).one()
    known = f"{__version__}|{','.join(CSV_COLUMNS)}|{count}|{highest}|{total}"
    return strong_etag(hashlib.sha256(known.encode()).hexdigest())


def measurements_csv(
    session: Session, *, orchard: str | None, row: str | None, since: datetime | None
) -> Iterator[str]:
    """CSV text, header first, of every measurement matching the filters, by orchard, row, tree, time;
    names that a spreadsheet would run as formulas are written as text (:func:`safe_cell`)."""
    query = _csv_query(orchard, row, since).order_by(
        Orchard.name, Row.name, Tree.name, Capture.captured_at, Measurement.id
    )
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
            "captured_at": utc_text(captured_at),
            "capture_id": measurement.capture_id,
            "job_id": measurement.job_id,
        }
        writer.writerow(
            [safe_cell(identity.get(column, measurement.result.get(column))) for column in CSV_COLUMNS]
        )
        yield buffer.getvalue()
        buffer.seek(0)
        buffer.truncate()
    yield buffer.getvalue()
