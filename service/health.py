"""Liveness and Prometheus metrics (answered without an API key) and readiness (any key)."""

from __future__ import annotations

from fastapi import APIRouter, Response
from sqlalchemy.exc import SQLAlchemyError

from service.deps import AnyKey, ContextDep, MetricsDep
from service.errors import NotReady
from service.metrics import CONTENT_TYPE
from service.storage import ObjectStoreUnavailable

__all__ = ["router"]

router = APIRouter(tags=["health"])


@router.get("/healthz")
def healthz() -> dict[str, str]:
    """The process is up."""
    return {"status": "ok"}


@router.get("/readyz")
def readyz(context: ContextDep, _key: AnyKey) -> dict[str, str]:
    """The database and the blob store answer; 503 problem+json naming the one that does not."""
    try:
        context.database.ping()
    except SQLAlchemyError as exc:
        raise NotReady(f"the database does not answer: {type(exc).__name__}") from exc
    try:
        context.store.ping()
    except (OSError, ObjectStoreUnavailable) as exc:
        raise NotReady(f"the blob store cannot take files: {exc}") from exc
    return {"status": "ready"}


@router.get("/metrics", response_class=Response, responses={200: {"content": {CONTENT_TYPE: {}}}})
def metrics(registry: MetricsDep) -> Response:
    """Prometheus metrics of this API process and of the job queue (no key: scrapers rarely carry one; it
    tells counts and timings, never names or data)."""
    return Response(registry.exposition(), media_type=CONTENT_TYPE)
