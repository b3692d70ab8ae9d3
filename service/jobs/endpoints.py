"""HTTP routes of jobs: start a measurement, poll it (with ETag), list jobs."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Header, Query, Response
from sqlalchemy.orm import Session

from service.captures.service import check_access, get_capture
from service.conventions import MAX_ID, ItemId, SinceQuery
from service.deps import CaptureKey, CaptureOrReadKey, ContextDep, ReadKey
from service.errors import BadRequest, Conflict, Forbidden, InvalidContent, NotFound
from service.jobs.schemas import JobOrder, JobOut, JobRequest, JobState
from service.jobs.service import create_job, get_job, job_out, list_jobs
from service.pagination import CursorQuery, LimitQuery, Page
from service.problems import problem_responses

__all__ = ["router"]

router = APIRouter(tags=["jobs"])


@router.post(
    "/v1/captures/{capture_id}/jobs",
    response_model=JobOut,
    status_code=202,
    responses=problem_responses(NotFound, Conflict, InvalidContent, Forbidden),
)
def start(
    capture_id: ItemId,
    response: Response,
    context: ContextDep,
    key: CaptureKey,
    request: JobRequest | None = None,
    idempotency_key: Annotated[
        str | None, Header(max_length=200, description="Repeat it to get the same job back")
    ] = None,
) -> JobOut:
    """Queue a measurement of a capture whose files have all arrived; 409 while some are missing."""

    def queue(session: Session) -> JobOut:
        capture = get_capture(session, capture_id)
        check_access(capture, key, writing=True)
        job, _created = create_job(
            session,
            capture,
            overrides=request.config if request else None,
            idempotency_key=idempotency_key,
        )
        return job_out(session, job)

    out = context.database.write(queue)
    response.headers["Location"] = f"/v1/jobs/{out.id}"
    return out


@router.get(
    "/v1/jobs/{job_id}",
    response_model=JobOut,
    responses=problem_responses(
        NotFound, Forbidden, also={304: {"description": "Unchanged since the ETag sent"}}
    ),
)
def read(job_id: ItemId, context: ContextDep, key: CaptureOrReadKey) -> JobOut:
    """A job's state, stage and progress (a capture key: of the captures it created); send If-None-Match
    with the last ETag to get 304 while unchanged."""
    with context.database.reading() as session:
        job = get_job(session, job_id)
        check_access(get_capture(session, job.capture_id), key, writing=False)
        return job_out(session, job)


@router.get("/v1/jobs", response_model=Page[JobOut], responses=problem_responses(BadRequest))
def index(
    context: ContextDep,
    _key: ReadKey,
    state: Annotated[
        list[JobState] | None,
        Query(description="Only jobs in these states (repeat: state=queued&state=running)"),
    ] = None,
    capture_id: Annotated[int | None, Query(ge=1, le=MAX_ID, description="Only jobs of this capture")] = None,
    since: SinceQuery = None,
    order: Annotated[JobOrder, Query(description="newest or oldest first")] = "newest",
    cursor: CursorQuery = None,
    limit: LimitQuery = 100,
) -> Page[JobOut]:
    """Jobs, newest first by default, each with its orchard, row and tree; ``since`` is the creation time."""
    with context.database.reading() as session:
        return list_jobs(
            session, states=state, capture_id=capture_id, since=since, order=order, cursor=cursor, limit=limit
        )
