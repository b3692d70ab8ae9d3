"""RFC 9457 problem details: the status each of the service's errors (``service/errors.py``) is answered
with, and the handlers that render every error (ours, the measurement core's, FastAPI's validation and
Starlette's routing) as ``application/problem+json`` naming the field, file or view at fault.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel, ConfigDict, Field
from sqlalchemy.exc import OperationalError
from starlette.exceptions import HTTPException as StarletteHTTPException

from canopy_core.errors import CanopyError
from service.errors import (
    BadRequest,
    ComeBackLater,
    Conflict,
    Forbidden,
    InsufficientStorage,
    InvalidContent,
    NotFound,
    NotReady,
    PayloadTooLarge,
    RequestTimeout,
    ServiceBusy,
    ServiceError,
    TooManyRequests,
    Unauthorized,
)
from service.storage import ObjectStoreUnavailable, OutOfSpace

__all__ = [
    "COMPONENT_REF",
    "HTTP_KINDS",
    "PROBLEM_JSON",
    "HttpKind",
    "Problem",
    "component_schemas",
    "http_kind",
    "install_problem_handlers",
    "problem_responses",
]

PROBLEM_JSON = "application/problem+json"

log = logging.getLogger("canopy.service")


@dataclass(frozen=True)
class HttpKind:
    """How one kind of :class:`ServiceError` is answered: its status and the problem's title."""

    status: int
    title: str


HTTP_KINDS: dict[type[ServiceError], HttpKind] = {
    BadRequest: HttpKind(400, "Bad request"),
    Unauthorized: HttpKind(401, "Missing or invalid API key"),
    Forbidden: HttpKind(403, "API key lacks the scope"),
    NotFound: HttpKind(404, "Not found"),
    RequestTimeout: HttpKind(408, "Request timeout"),
    Conflict: HttpKind(409, "Conflict"),
    PayloadTooLarge: HttpKind(413, "Body too large"),
    InvalidContent: HttpKind(422, "Invalid content"),
    TooManyRequests: HttpKind(429, "Too many requests"),
    ServiceBusy: HttpKind(503, "Service busy"),
    NotReady: HttpKind(503, "Not ready"),
    InsufficientStorage: HttpKind(507, "Insufficient storage"),
    ServiceError: HttpKind(500, "Internal error"),
}
"""Every kind of the service's errors, with its answer; a subclass not listed answers as its nearest base."""


def http_kind(error: type[ServiceError]) -> HttpKind:
    """How errors of class ``error`` are answered: as the nearest class in its hierarchy that is listed."""
    return next(HTTP_KINDS[cls] for cls in error.__mro__ if cls in HTTP_KINDS)


def _headers(error: ServiceError) -> dict[str, str]:
    """The headers an error's answer carries: the challenge of a 401, when to try again, and closing a
    connection whose request body may still be arriving (rather than reading it as the next request)."""
    if isinstance(error, Unauthorized):
        return {"WWW-Authenticate": 'Bearer realm="canopy"'}
    if isinstance(error, ComeBackLater):
        return {"Retry-After": str(error.retry_after_s)}
    if isinstance(error, RequestTimeout):
        return {"Connection": "close"}
    return {}


class Problem(BaseModel):
    """An error, as RFC 9457 problem details: every 4xx and 5xx answer of the API."""

    model_config = ConfigDict(extra="allow")

    type: str = Field(description="/problems/<code>, relative")
    title: str = Field(description="The kind of error, for people")
    status: int = Field(description="The HTTP status")
    detail: str = Field(description="What was wrong, naming the file, view or field")
    code: str = Field(description="The stable, machine-readable kind (docs/api.md lists them)")
    field: str | None = Field(None, description="The field, parameter or setting at fault")
    file: str | None = Field(None, description="The capture's file at fault")
    view: str | None = Field(None, description="The capture's view at fault")


COMPONENT_REF = "#/components/schemas/{model}"
"""Where the OpenAPI document keeps a named schema; models given to :func:`component_schemas` refer there."""


def component_schemas(*models: type[BaseModel]) -> dict[str, Any]:
    """OpenAPI component schemas of ``models`` and of every model they nest, by name."""
    schemas: dict[str, Any] = {}
    for model in models:
        schema = model.model_json_schema(ref_template=COMPONENT_REF)
        schemas.update(schema.pop("$defs", {}))
        schemas[model.__name__] = schema
    return schemas


def problem_responses(
    *errors: type[ServiceError], also: dict[int | str, dict[str, Any]] | None = None
) -> dict[int | str, dict[str, Any]]:
    """OpenAPI ``responses=`` entries for the errors a route can answer with, plus ``also``."""
    responses: dict[int | str, dict[str, Any]] = {**(also or {})}
    for error in errors:
        kind = http_kind(error)
        responses[kind.status] = {
            "description": kind.title,
            "content": {PROBLEM_JSON: {"schema": {"$ref": COMPONENT_REF.format(model=Problem.__name__)}}},
        }
    return responses


def problem(
    status: int, title: str, detail: str, *, code: str, headers: dict[str, str] | None = None, **members: Any
) -> JSONResponse:
    """A problem+json response; ``type`` is a relative URI per problem code, documented in docs/api.md."""
    body = {"type": f"/problems/{code}", "title": title, "status": status, "detail": detail, "code": code}
    body.update(members)
    return JSONResponse(body, status_code=status, media_type=PROBLEM_JSON, headers=headers)


def _service_error(_request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, ServiceError)
    kind = http_kind(type(exc))
    return problem(
        kind.status, kind.title, exc.detail, code=exc.instance_code, headers=_headers(exc), **exc.members
    )


def _canopy_error(_request: Request, exc: Exception) -> JSONResponse:
    # The core's errors that reach a request are about the content sent (capture.json, camera.json,
    # an image, the settings): the client must change what it sends.
    assert isinstance(exc, CanopyError)
    members: dict[str, Any] = {
        key: value for key, value in exc.to_dict().items() if key not in {"code", "message"}
    }
    return problem(422, "Invalid content", exc.message, code=exc.code, **members)


def _validation_error(_request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, RequestValidationError)
    problems = []
    for error in exc.errors():
        location = [str(part) for part in error["loc"]]
        where = location[0] if location else "body"
        problems.append({"field": ".".join(location[1:]) or where, "where": where, "message": error["msg"]})
    detail = "; ".join(f"{item['field']}: {item['message']}" for item in problems)
    first = problems[0]
    return problem(
        422,
        "Invalid request",
        detail,
        code="invalid_request",
        field=first["field"],
        where=first["where"],
        errors=problems,
    )


def _http_error(_request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, StarletteHTTPException)
    return problem(
        exc.status_code,
        str(exc.detail),
        str(exc.detail),
        code="not_found" if exc.status_code == 404 else "http_error",
        headers=dict(exc.headers or {}),
    )


def _database_unavailable(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, OperationalError)
    if "database or disk is full" in str(exc.orig):  # SQLite's words for ENOSPC
        store = request.app.state.context.store
        full = OutOfSpace.measured(
            store.spool_dir, store.min_free_bytes, reason="the database could not grow"
        )
        return _out_of_space(request, full)
    log.warning("database unavailable: %s", exc)
    return problem(
        503,
        "Database unavailable",
        "the database is busy or unreachable; try again shortly",
        code="database_unavailable",
        headers={"Retry-After": "2"},
    )


def _object_store_unavailable(_request: Request, exc: Exception) -> JSONResponse:
    log.warning("object store unavailable: %s", exc)
    return problem(
        503,
        "Object store unavailable",
        "the object store holding the files did not answer or refused the request; nothing was stored: "
        "try again shortly",
        code="object_store_unavailable",
        headers={"Retry-After": "5"},
    )


OUT_OF_SPACE_RETRY_S = 60
"""When to try again after a full disk: an operator has to free space, which takes minutes, not seconds."""


def _out_of_space(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, OutOfSpace)
    log.warning("refused a write: %s", exc)
    refusal = InsufficientStorage(
        f"the server's data disk is full ({exc.free_bytes} bytes free, {exc.floor_bytes} kept free); "
        "nothing was stored: try again once space is freed",
        retry_after_s=OUT_OF_SPACE_RETRY_S,
        free_bytes=exc.free_bytes,
        min_free_bytes=exc.floor_bytes,
    )
    return _service_error(request, refusal)


def _unexpected(_request: Request, exc: Exception) -> JSONResponse:
    log.error("unexpected error", exc_info=exc)
    # The connection may hold the rest of a request the server gave up on: close it rather than read
    # that as the next request, and say so, so a client does not reuse it and meet a reset.
    return problem(
        500,
        "Internal error",
        "an unexpected error occurred; it is logged",
        code="internal_error",
        headers={"Connection": "close"},
    )


def install_problem_handlers(app: FastAPI) -> None:
    """Render every error the app can raise as problem+json."""
    app.add_exception_handler(OperationalError, _database_unavailable)
    app.add_exception_handler(OutOfSpace, _out_of_space)
    app.add_exception_handler(ObjectStoreUnavailable, _object_store_unavailable)
    app.add_exception_handler(Exception, _unexpected)
    app.add_exception_handler(ServiceError, _service_error)
    app.add_exception_handler(CanopyError, _canopy_error)
    app.add_exception_handler(RequestValidationError, _validation_error)
    app.add_exception_handler(StarletteHTTPException, _http_error)
