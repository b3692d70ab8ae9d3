"""Starting measurement jobs and reading their state."""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime
from typing import Any

from sqlalchemy import Select, select
from sqlalchemy.orm import Session

from canopy_core.errors import ConfigError
from canopy_core.measure import config_for
from service.captures.service import capture_manifest, missing_files
from service.errors import Conflict, NotFound
from service.jobs.schemas import JobError, JobOut
from service.models import Capture, CaptureFile, Job, Measurement, Orchard, Row, Tree
from service.pagination import Page, keyset, page_of

__all__ = ["create_job", "get_job", "job_out", "list_jobs"]


def create_job(
    session: Session, capture: Capture, *, overrides: dict[str, Any] | None, idempotency_key: str | None
) -> tuple[Job, bool]:
    """Queue a measurement of a complete capture; ``(job, created)``.

    A request repeated with the same ``Idempotency-Key``, or while a job with the same settings is still
    queued or running, returns that job instead of starting another.
    """
    manifest = capture_manifest(capture)
    received = list(session.scalars(select(CaptureFile.path).where(CaptureFile.capture_id == capture.id)))
    missing = missing_files(manifest, received)
    if missing:
        raise Conflict(
            f"capture {capture.id} still misses {len(missing)} file(s): {', '.join(missing)}",
            code="files_missing",
            missing=missing,
        )
    try:
        config_for(manifest, overrides)
    except ConfigError as exc:
        exc.field = f"config.{exc.field}" if exc.field else "config"
        raise
    # Two requests for the same capture at once take turns here, so the second finds the first's job:
    # PostgreSQL locks the capture's row (SQLite lets one writer in at a time anyway).
    session.execute(select(Capture.id).where(Capture.id == capture.id).with_for_update())
    same = select(Job).where(Job.capture_id == capture.id)
    if idempotency_key is not None:
        earlier = session.scalar(same.where(Job.idempotency_key == idempotency_key))
    else:
        earlier = next(
            (
                job
                for job in session.scalars(same.where(Job.state.in_(("queued", "running"))))
                if (job.config_overrides or None) == (overrides or None)
            ),
            None,
        )
    if earlier is not None:
        return earlier, False
    job = Job(capture_id=capture.id, config_overrides=overrides or None, idempotency_key=idempotency_key)
    session.add(job)
    session.flush()
    return job, True


def get_job(session: Session, job_id: int) -> Job:
    """The job with this id, or a 404 problem."""
    job = session.get(Job, job_id)
    if job is None:
        raise NotFound(f"no job with id {job_id}", job_id=job_id)
    return job


def _jobs() -> Select[Job, int | None, str, str, str, int]:
    """Jobs with their measurement's id (if any), orchard, row and tree names, and tree id."""
    return (
        select(Job, Measurement.id, Orchard.name, Row.name, Tree.name, Tree.id)
        .join(Capture, Capture.id == Job.capture_id)
        .join(Tree, Tree.id == Capture.tree_id)
        .join(Row, Row.id == Tree.row_id)
        .join(Orchard, Orchard.id == Row.orchard_id)
        .outerjoin(Measurement, Measurement.job_id == Job.id)
    )


def job_out(session: Session, job: Job) -> JobOut:
    """The job as the API shows it."""
    return _out(*session.execute(_jobs().where(Job.id == job.id)).one())


def _out(job: Job, measurement_id: int | None, orchard: str, row: str, tree: str, tree_id: int) -> JobOut:
    return JobOut(
        id=job.id,
        capture_id=job.capture_id,
        orchard=orchard,
        row=row,
        tree=tree,
        tree_id=tree_id,
        state=job.state,
        stage=job.stage,
        progress=job.progress,
        attempts=job.attempts,
        created_at=job.created_at,
        started_at=job.started_at,
        finished_at=job.finished_at,
        error=JobError.model_validate(job.error) if job.error else None,
        measurement_id=measurement_id,
    )


def list_jobs(
    session: Session,
    *,
    states: Sequence[str] | None,
    capture_id: int | None,
    since: datetime | None,
    order: str,
    cursor: str | None,
    limit: int,
) -> Page[JobOut]:
    """Jobs ``newest`` or ``oldest`` first, optionally in some states, of one capture, or created since."""
    query = _jobs()
    if states:
        query = query.where(Job.state.in_(states))
    if capture_id is not None:
        query = query.where(Job.capture_id == capture_id)
    if since is not None:
        query = query.where(Job.created_at >= since)
    rows = session.execute(keyset(query, Job.id, cursor, limit, newest_first=order == "newest")).all()
    return page_of([_out(*row) for row in rows], [row[0].id for row in rows], limit)
