"""The system of record: orchards, rows, trees, captures, their files, jobs, measurements, API keys and the
measurements a crew took by hand.

Dialect-neutral SQLAlchemy 2 models (SQLite and PostgreSQL). Relationships load nothing implicitly
(``lazy="raise"``): every query is written where it runs. Constraint names follow one convention so that
Alembic can alter tables on SQLite.
"""

from __future__ import annotations

from datetime import UTC, date, datetime
from typing import Any, ClassVar

from pydantic import TypeAdapter
from sqlalchemy import JSON, DateTime, Float, ForeignKey, Index, Integer, MetaData, String, UniqueConstraint
from sqlalchemy.engine import Dialect
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column, relationship
from sqlalchemy.types import TypeDecorator

__all__ = [
    "JOB_STATES",
    "ApiKey",
    "Base",
    "BrowserSession",
    "Capture",
    "CaptureFile",
    "Job",
    "ManualMeasurement",
    "Measurement",
    "Orchard",
    "Row",
    "StoredBlob",
    "Tree",
    "utc_now",
    "utc_text",
]

JOB_STATES = ("queued", "running", "succeeded", "failed")

NAMING_CONVENTION = {
    "ix": "ix_%(column_0_label)s",
    "uq": "uq_%(table_name)s_%(column_0_N_name)s",
    "ck": "ck_%(table_name)s_%(constraint_name)s",
    "fk": "fk_%(table_name)s_%(column_0_name)s_%(referred_table_name)s",
    "pk": "pk_%(table_name)s",
}


_GROWING_IDS = {"sqlite_autoincrement": True}


def utc_now() -> datetime:
    """The current time, timezone-aware in UTC."""
    return datetime.now(UTC)


_TIMES = TypeAdapter(datetime)


def utc_text(moment: datetime) -> str:
    """``moment`` as RFC 3339 in UTC ending in ``Z``: how every answer of the API writes a time."""
    return str(_TIMES.dump_python(moment.astimezone(UTC), mode="json"))


class UtcDateTime(TypeDecorator[datetime]):
    """A point in time stored as naive UTC (SQLite has no time zones) and read back as aware UTC."""

    impl = DateTime
    cache_ok = True

    def process_bind_param(self, value: datetime | None, dialect: Dialect) -> datetime | None:
        if value is None:
            return None
        if value.tzinfo is None:
            raise ValueError("naive datetime: give every stored time a time zone")
        return value.astimezone(UTC).replace(tzinfo=None)

    def process_result_value(self, value: datetime | None, dialect: Dialect) -> datetime | None:
        return None if value is None else value.replace(tzinfo=UTC)


class Base(DeclarativeBase):
    """Every table's ids only grow: SQLite's AUTOINCREMENT never hands a deleted row's id to a new one,
    so an id a client kept (in a receipt, a link) can never name something else."""

    metadata = MetaData(naming_convention=NAMING_CONVENTION)
    type_annotation_map: ClassVar[dict[Any, Any]] = {datetime: UtcDateTime, dict[str, Any]: JSON}


class Orchard(Base):
    __tablename__ = "orchards"
    __table_args__ = (_GROWING_IDS,)

    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(String(200), unique=True)
    created_at: Mapped[datetime] = mapped_column(default=utc_now)


class Row(Base):
    __tablename__ = "rows"
    __table_args__ = (UniqueConstraint("orchard_id", "name"), _GROWING_IDS)

    id: Mapped[int] = mapped_column(primary_key=True)
    orchard_id: Mapped[int] = mapped_column(ForeignKey("orchards.id", ondelete="CASCADE"))
    name: Mapped[str] = mapped_column(String(200))
    created_at: Mapped[datetime] = mapped_column(default=utc_now)

    orchard: Mapped[Orchard] = relationship(lazy="raise")


class Tree(Base):
    __tablename__ = "trees"
    __table_args__ = (UniqueConstraint("row_id", "name"), _GROWING_IDS)

    id: Mapped[int] = mapped_column(primary_key=True)
    row_id: Mapped[int] = mapped_column(ForeignKey("rows.id", ondelete="CASCADE"))
    name: Mapped[str] = mapped_column(String(200))
    created_at: Mapped[datetime] = mapped_column(default=utc_now)

    row: Mapped[Row] = relationship(lazy="raise")


class Capture(Base):
    """One tree captured once: the manifest as uploaded; unique per tree and capture time."""

    __tablename__ = "captures"
    __table_args__ = (UniqueConstraint("tree_id", "captured_at"), _GROWING_IDS)

    id: Mapped[int] = mapped_column(primary_key=True)
    tree_id: Mapped[int] = mapped_column(ForeignKey("trees.id", ondelete="CASCADE"))
    captured_at: Mapped[datetime]
    manifest: Mapped[dict[str, Any]]
    created_at: Mapped[datetime] = mapped_column(default=utc_now)
    created_by_key_id: Mapped[int | None] = mapped_column(ForeignKey("api_keys.id"))
    """The key that created it: a capture key writes only to captures it created. None for captures made
    before keys owned them, which any capture key may still write to."""

    tree: Mapped[Tree] = relationship(lazy="raise")


class CaptureFile(Base):
    """One acknowledged file of a capture; its bytes are the blob named by ``sha256``."""

    __tablename__ = "capture_files"
    __table_args__ = (UniqueConstraint("capture_id", "path"), _GROWING_IDS)

    id: Mapped[int] = mapped_column(primary_key=True)
    capture_id: Mapped[int] = mapped_column(ForeignKey("captures.id", ondelete="CASCADE"))
    path: Mapped[str] = mapped_column(String(300))
    sha256: Mapped[str] = mapped_column(String(64))
    size_bytes: Mapped[int]
    image_width: Mapped[int | None]
    image_height: Mapped[int | None]
    created_at: Mapped[datetime] = mapped_column(default=utc_now)


class Job(Base):
    """A measurement of a capture: queued, then leased by one worker at a time, then finished.

    ``lease_owner`` and ``lease_expires_at`` are set while a worker runs it; a lease that runs out makes the
    job claimable again. ``error`` holds the last failure (code, message and view/file/field when known).
    """

    __tablename__ = "jobs"
    __table_args__ = (
        UniqueConstraint("capture_id", "idempotency_key"),
        Index("ix_jobs_state_lease", "state", "lease_expires_at"),
        _GROWING_IDS,
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    capture_id: Mapped[int] = mapped_column(ForeignKey("captures.id", ondelete="CASCADE"), index=True)
    state: Mapped[str] = mapped_column(String(16), default="queued")
    stage: Mapped[str | None] = mapped_column(String(32))
    progress: Mapped[float] = mapped_column(Float, default=0.0)
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    config_overrides: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    idempotency_key: Mapped[str | None] = mapped_column(String(200))
    lease_owner: Mapped[str | None] = mapped_column(String(200))
    lease_expires_at: Mapped[datetime | None]
    error: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    created_at: Mapped[datetime] = mapped_column(default=utc_now)
    started_at: Mapped[datetime | None]
    finished_at: Mapped[datetime | None]


class Measurement(Base):
    """A job's result: the headline metrics as columns for queries, the whole document as JSON."""

    __tablename__ = "measurements"
    __table_args__ = (_GROWING_IDS,)

    id: Mapped[int] = mapped_column(primary_key=True)
    job_id: Mapped[int] = mapped_column(ForeignKey("jobs.id", ondelete="CASCADE"), unique=True)
    capture_id: Mapped[int] = mapped_column(ForeignKey("captures.id", ondelete="CASCADE"), index=True)
    tree_id: Mapped[int] = mapped_column(ForeignKey("trees.id", ondelete="CASCADE"), index=True)
    height_m: Mapped[float]
    width_m: Mapped[float]
    thickness_m: Mapped[float]
    result: Mapped[dict[str, Any]]
    cloud_sha256: Mapped[str] = mapped_column(String(64))
    cloud_points: Mapped[int]
    figures: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    """The report's PNG figures in the blob store, name to SHA-256; None for measurements made before the
    worker drew them."""
    created_at: Mapped[datetime] = mapped_column(default=utc_now)


class ApiKey(Base):
    """An API key, stored only as the SHA-256 of the whole key; ``prefix`` identifies it in lists and logs."""

    __tablename__ = "api_keys"
    __table_args__ = (_GROWING_IDS,)

    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(String(200))
    prefix: Mapped[str] = mapped_column(String(32), unique=True)
    key_sha256: Mapped[str] = mapped_column(String(64), unique=True)
    scopes: Mapped[str] = mapped_column(String(100))
    created_at: Mapped[datetime] = mapped_column(default=utc_now)
    revoked_at: Mapped[datetime | None]
    expires_at: Mapped[datetime | None]
    """After this instant the key is refused; None: it does not expire."""


class ManualMeasurement(Base):
    """A tree's height, width and crown thickness measured by hand on one day, to judge the measurements by
    (the paper's Table 1). Named by orchard, row and tree rather than linked: a crew may enter its tape
    and pole readings before the tree is ever captured. One record per tree and day; a metric not taken
    is None."""

    __tablename__ = "manual_measurements"
    __table_args__ = (UniqueConstraint("orchard", "row", "tree", "measured_on"), _GROWING_IDS)

    id: Mapped[int] = mapped_column(primary_key=True)
    orchard: Mapped[str] = mapped_column(String(200))
    row: Mapped[str] = mapped_column(String(200))
    tree: Mapped[str] = mapped_column(String(200))
    measured_on: Mapped[date]
    height_m: Mapped[float | None]
    width_m: Mapped[float | None]
    thickness_m: Mapped[float | None]
    updated_at: Mapped[datetime] = mapped_column(default=utc_now)


class BrowserSession(Base):
    """A browser signed in with an API key: the dashboard's and report pages' cookie, stored only as the
    SHA-256 of its token. It grants what its key grants, for reading, until it expires or the key stops
    working (revoked, expired, deleted)."""

    __tablename__ = "browser_sessions"
    __table_args__ = (_GROWING_IDS,)

    id: Mapped[int] = mapped_column(primary_key=True)
    token_sha256: Mapped[str] = mapped_column(String(64), unique=True)
    key_id: Mapped[int] = mapped_column(ForeignKey("api_keys.id", ondelete="CASCADE"), index=True)
    created_at: Mapped[datetime] = mapped_column(default=utc_now)
    expires_at: Mapped[datetime]


class StoredBlob(Base):
    """A blob in the object store, as the processes that store it and the garbage collector agree on it.

    An object store has no rename to set a blob aside with, so the row does it: whoever stores a blob
    renews ``committed_at`` (by the database's clock) before it writes the object and the record that
    names it; the collector sets ``claimed_at`` before it deletes the object and drops the row after. A
    writer that finds the blob claimed waits for the claim to end (see ``service/blob_registry.py``). Only
    the object store uses this table; the folder store's files carry their own times.
    """

    __tablename__ = "stored_blobs"

    sha256: Mapped[str] = mapped_column(String(64), primary_key=True)
    size_bytes: Mapped[int]
    committed_at: Mapped[datetime]
    claimed_at: Mapped[datetime | None]
