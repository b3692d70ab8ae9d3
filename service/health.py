"""Liveness (the one route that answers without an API key) and readiness (a key with read scope)."""

from __future__ import annotations

from fastapi import APIRouter
from sqlalchemy.exc import SQLAlchemyError

from service.deps import AnyKey, ContextDep
from service.problems import ApiError

__all__ = ["router"]

router = APIRouter(tags=["health"])


class NotReady(ApiError):
    status, title, code = 503, "Not ready", "not_ready"


@router.get("/healthz")
def healthz() -> dict[str, str]:
    """The process is up."""
    return {"status": "ok"}


@router.get("/readyz")
def readyz(context: ContextDep, _key: AnyKey) -> dict[str, str]:
    """The database answers; 503 problem+json when it does not."""
    try:
        context.database.ping()
    except SQLAlchemyError as exc:
        raise NotReady(f"the database does not answer: {type(exc).__name__}") from exc
    return {"status": "ready"}
