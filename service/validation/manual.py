"""Manual measurements sent as CSV: read all-or-nothing, then stored one record per tree and day.

The file is the one a crew keeps in a spreadsheet: ``orchard,row,tree,date,height_m,width_m,thickness_m``
(any column order, a byte-order mark allowed, as Excel writes one); a metric not measured is left empty.
Every problem names the line and the column; nothing is stored from a file with one.
"""

from __future__ import annotations

import csv
import io
import re
from dataclasses import dataclass
from datetime import date

from sqlalchemy import select
from sqlalchemy.orm import Session

from service.errors import InvalidContent
from service.models import ManualMeasurement, utc_now
from service.validation.schemas import ManualReceipt

__all__ = ["MANUAL_COLUMNS", "ManualLine", "read_manual_csv", "store_manual"]

NAME_COLUMNS = ("orchard", "row", "tree")
METRIC_COLUMNS = ("height_m", "width_m", "thickness_m")
MANUAL_COLUMNS = (*NAME_COLUMNS, "date", *METRIC_COLUMNS)
_MAX_NAME = 200
_MAX_METRIC_M = 50.0
"""No fruit tree is this tall or wide: a larger number is in another unit (centimetres) or a typo."""
_CONTROL = re.compile(r"[\x00-\x1f\x7f]")


@dataclass(frozen=True)
class ManualLine:
    """One line of the file: a tree's hand measurements on one day (None where not measured)."""

    orchard: str
    row: str
    tree: str
    measured_on: date
    height_m: float | None
    width_m: float | None
    thickness_m: float | None


def read_manual_csv(body: bytes) -> list[ManualLine]:
    """The lines of a manual-measurement CSV.

    Raises
    ------
    InvalidContent
        The file is not UTF-8, lacks a column or has one it does not know, or a line holds an empty name, a
        date that is not ``YYYY-MM-DD``, a metric that is not a positive number of metres, no metric at all,
        or repeats an earlier line's tree and day. Names the line (the header is line 1) and column.
    """
    try:
        text = body.decode("utf-8-sig")
    except UnicodeDecodeError as error:
        raise _invalid(f"the file is not UTF-8 text (byte {error.start})", code="not_utf8") from error
    reader = csv.DictReader(io.StringIO(text, newline=""))
    header = [name.strip() for name in reader.fieldnames or []]
    missing = [column for column in MANUAL_COLUMNS if column not in header]
    unknown = [column for column in header if column not in MANUAL_COLUMNS]
    if missing or unknown:
        parts = [f"lacks the column(s) {', '.join(missing)}"] if missing else []
        parts += [f"has unknown column(s) {', '.join(repr(c) for c in unknown)}"] if unknown else []
        raise _invalid(
            f"the header {' and '.join(parts)}; expected {','.join(MANUAL_COLUMNS)}",
            line=1,
            code="bad_header",
        )
    reader.fieldnames = header
    lines: list[ManualLine] = []
    seen: dict[tuple[str, str, str, date], int] = {}
    for number, record in enumerate(reader, start=2):
        if None in record:
            raise _invalid(f"line {number} has more cells than the header", line=number)
        line = _line(record, number)
        key = (line.orchard, line.row, line.tree, line.measured_on)
        if key in seen:
            raise _invalid(
                f"line {number} repeats line {seen[key]}: the same tree on the same day", line=number
            )
        seen[key] = number
        lines.append(line)
    if not lines:
        raise _invalid("the file holds a header and no measurement", line=1, code="empty_file")
    return lines


def store_manual(session: Session, lines: list[ManualLine]) -> ManualReceipt:
    """Store each line, replacing the record of the same tree and day (a file sent twice changes nothing)."""
    created = replaced = 0
    for line in lines:
        record = session.scalars(
            select(ManualMeasurement).where(
                ManualMeasurement.orchard == line.orchard,
                ManualMeasurement.row == line.row,
                ManualMeasurement.tree == line.tree,
                ManualMeasurement.measured_on == line.measured_on,
            )
        ).one_or_none()
        if record is None:
            record = ManualMeasurement(
                orchard=line.orchard, row=line.row, tree=line.tree, measured_on=line.measured_on
            )
            session.add(record)
            created += 1
        else:
            replaced += 1
        record.height_m, record.width_m, record.thickness_m = line.height_m, line.width_m, line.thickness_m
        record.updated_at = utc_now()
    return ManualReceipt(lines=len(lines), created=created, replaced=replaced)


def _line(record: dict[str, str], number: int) -> ManualLine:
    names = {}
    for column in NAME_COLUMNS:
        name = (record[column] or "").strip()
        if not name or len(name) > _MAX_NAME or _CONTROL.search(name):
            raise _invalid(
                f"line {number}, column {column}: {name!r} is not a name (1 to {_MAX_NAME} characters, "
                "no control characters)",
                line=number,
                column=column,
            )
        names[column] = name
    day = (record["date"] or "").strip()
    try:
        measured_on = date.fromisoformat(day)
    except ValueError as error:
        raise _invalid(
            f"line {number}, column date: {day!r} is not a date as YYYY-MM-DD", line=number, column="date"
        ) from error
    metrics = {column: _metric(record[column], number, column) for column in METRIC_COLUMNS}
    if all(value is None for value in metrics.values()):
        raise _invalid(
            f"line {number} holds none of {', '.join(METRIC_COLUMNS)}", line=number, column="height_m"
        )
    return ManualLine(
        orchard=names["orchard"],
        row=names["row"],
        tree=names["tree"],
        measured_on=measured_on,
        height_m=metrics["height_m"],
        width_m=metrics["width_m"],
        thickness_m=metrics["thickness_m"],
    )


def _metric(cell: str | None, number: int, column: str) -> float | None:
    text = (cell or "").strip()
    if not text:
        return None
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not 0.0 < value <= _MAX_METRIC_M:
        raise _invalid(
            f"line {number}, column {column}: {text!r} is not a length in metres (more than 0, at most "
            f"{_MAX_METRIC_M:g})",
            line=number,
            column=column,
        )
    return value


def _invalid(detail: str, *, code: str = "bad_manual_csv", **where: object) -> InvalidContent:
    return InvalidContent(detail, code=code, file="manual measurements CSV", **where)
