"""The job queue as workers see it: claim with a lease, renew it, finish only while holding it.

Every operation is one short write transaction. A claim takes the oldest queued job, or a running job
whose lease ran out (its worker died), in one atomic step: ``BEGIN IMMEDIATE`` on SQLite,
``FOR UPDATE SKIP LOCKED`` on PostgreSQL, so two workers never hold the same job. Renewing, completing and
failing check that the worker still holds the lease, so a job is never both finished and retried, and its
measurement is stored once.

Leases are timed by the database's clock, not each worker's: on PostgreSQL workers on many machines
compare the leases they write against one clock, so one whose clock runs fast cannot take a job whose
lease has not run out. (SQLite's workers share a machine, and its clock.)
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any

from sqlalchemy import and_, or_, select
from sqlalchemy.orm import Session

from service.database import database_now
from service.models import Capture, Job, Measurement

__all__ = ["Lease", "claim", "complete", "fail", "release", "renew"]


@dataclass(frozen=True)
class Lease:
    """A worker's hold on a job for one attempt."""

    job_id: int
    capture_id: int
    owner: str
    attempt: int
    overrides: dict[str, Any] | None


def _lost_error(attempts: int) -> dict[str, Any]:
    return {
        "code": "worker_lost",
        "message": f"the worker running this job stopped answering on each of its {attempts} attempts "
        "(killed, out of memory, or the machine stopped); it is not retried again",
    }


def claim(session: Session, *, owner: str, lease_s: float, max_attempts: int) -> Lease | None:
    """Lease the next job to ``owner``, or None when no job is ready.

    A running job whose lease ran out after ``max_attempts`` attempts is marked failed instead of being
    run again: whatever kills its workers would kill the next one too.
    """
    while True:
        now = database_now(session)
        job = session.scalar(
            select(Job)
            .where(
                or_(
                    Job.state == "queued",
                    and_(Job.state == "running", Job.lease_expires_at < now),
                )
            )
            .order_by(Job.id)
            .limit(1)
            .with_for_update(skip_locked=True)
        )
        if job is None:
            return None
        if job.state == "running" and job.attempts >= max_attempts:
            _finish(job, state="failed", error=_lost_error(job.attempts), now=now)
            session.flush()
            continue
        job.state = "running"
        job.stage = "queued"
        job.progress = 0.0
        job.attempts += 1
        job.lease_owner = owner
        job.lease_expires_at = now + timedelta(seconds=lease_s)
        job.started_at = job.started_at or now
        session.flush()
        return Lease(
            job_id=job.id,
            capture_id=job.capture_id,
            owner=owner,
            attempt=job.attempts,
            overrides=job.config_overrides,
        )


def _held(session: Session, lease: Lease) -> Job | None:
    job = session.get(Job, lease.job_id, with_for_update=True)
    if (
        job is None
        or job.state != "running"
        or job.lease_owner != lease.owner
        or job.attempts != lease.attempt
    ):
        return None
    return job


def renew(
    session: Session, lease: Lease, *, lease_s: float, stage: str | None = None, progress: float | None = None
) -> bool:
    """Extend the lease (and record the stage and progress); False when the lease was lost."""
    job = _held(session, lease)
    if job is None:
        return False
    job.lease_expires_at = database_now(session) + timedelta(seconds=lease_s)
    if stage is not None:
        job.stage = stage
    if progress is not None:
        job.progress = progress
    return True


def _finish(job: Job, *, state: str, error: dict[str, Any] | None, now: datetime) -> None:
    job.state = state
    job.error = error
    job.finished_at = now
    job.lease_owner = None
    job.lease_expires_at = None


def complete(
    session: Session,
    lease: Lease,
    *,
    result: dict[str, Any],
    cloud_sha256: str,
    cloud_points: int,
    figures: dict[str, str] | None = None,
) -> int | None:
    """Store the measurement (with its figures' blobs, name to SHA-256) and mark the job succeeded; the
    measurement's id, or None (lease lost)."""
    job = _held(session, lease)
    if job is None:
        return None
    tree_id = session.scalar(select(Capture.tree_id).where(Capture.id == job.capture_id))
    assert tree_id is not None  # a job's capture cannot be deleted while the job exists (foreign key)
    measurement = Measurement(
        job_id=job.id,
        capture_id=job.capture_id,
        tree_id=tree_id,
        height_m=result["height_m"],
        width_m=result["width_m"],
        thickness_m=result["thickness_m"],
        result=result,
        cloud_sha256=cloud_sha256,
        cloud_points=cloud_points,
        figures=figures,
    )
    session.add(measurement)
    job.stage, job.progress = "done", 1.0
    _finish(job, state="succeeded", error=None, now=database_now(session))
    session.flush()
    return measurement.id


def fail(session: Session, lease: Lease, *, error: dict[str, Any], retry: bool, max_attempts: int) -> bool:
    """Record a failed attempt: queued again when ``retry`` and attempts remain, else failed for good.

    Returns False when the lease was lost (another worker owns the job now; nothing is changed).
    """
    job = _held(session, lease)
    if job is None:
        return False
    if retry and job.attempts < max_attempts:
        job.state, job.error, job.stage, job.progress = "queued", error, None, 0.0
        job.lease_owner = job.lease_expires_at = None
    else:
        _finish(job, state="failed", error=error, now=database_now(session))
    return True


def release(session: Session, lease: Lease) -> bool:
    """Give the job back to the queue without counting the attempt (the worker is shutting down)."""
    job = _held(session, lease)
    if job is None:
        return False
    job.state, job.stage, job.progress = "queued", None, 0.0
    job.attempts -= 1
    job.lease_owner = job.lease_expires_at = None
    return True
