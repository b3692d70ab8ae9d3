"""RFC 9457 problem details: the one error base of the API, its subclasses, and the handlers that render
every error (ours, the measurement core's, FastAPI's validation and Starlette's routing) as
``application/problem+json`` naming the field, file or view at fault.
"""

from __future__ import annotations

import logging
from typing import Any, ClassVar

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel, ConfigDict, Field
from sqlalchemy.exc import OperationalError
from starlette.exceptions import HTTPException as StarletteHTTPException

from canopy_core.errors import CanopyError
from service.storage import OutOfSpace

__all__ = [
    "COMPONENT_REF",
    "PROBLEM_JSON",
    "ApiError",
    "BadRequest",
    "Conflict",
    "Forbidden",
    "InsufficientStorage",
    "InvalidContent",
    "NotFound",
    "PayloadTooLarge",
    "Problem",
    "RequestTimeout",
    "ServiceBusy",
    "TooManyRequests",
    "Unauthorized",
    "component_schemas",
    "install_problem_handlers",
    "problem_responses",
]

PROBLEM_JSON = "application/problem+json"

log = logging.getLogger("canopy.service")


class ApiError(Exception):
    """An error answered as problem+json with ``status``; ``code`` is the stable, machine-readable kind.

    Locations (``field``, ``file``, ``view``) and any other keyword arguments become members of the
    problem object, so clients never parse ``detail``.
    """

    status: ClassVar[int] = 500
    title: ClassVar[str] = "Internal error"
    code: ClassVar[str] = "internal_error"

    def __init__(self, detail: str, *, code: str | None = None, **members: Any) -> None:
        super().__init__(detail)
        self.detail = detail
        self.instance_code = code or self.code
        self.members = {key: value for key, value in members.items() if value is not None}
        self.headers: dict[str, str] = {}


class BadRequest(ApiError):
    status, title, code = 400, "Bad request", "bad_request"


class Unauthorized(ApiError):
    status, title, code = 401, "Missing or invalid API key", "unauthorized"

    def __init__(self, detail: str) -> None:
        super().__init__(detail)
        self.headers = {"WWW-Authenticate": 'Bearer realm="canopy"'}


class Forbidden(ApiError):
    status, title, code = 403, "API key lacks the scope", "forbidden"


class NotFound(ApiError):
    status, title, code = 404, "Not found", "not_found"


class RequestTimeout(ApiError):
    status, title, code = 408, "Request timeout", "body_timeout"

    def __init__(self, detail: str, **members: Any) -> None:
        super().__init__(detail, **members)
        # The rest of the body may still come: close rather than read it as the next request.
        self.headers = {"Connection": "close"}


class Conflict(ApiError):
    status, title, code = 409, "Conflict", "conflict"


class PayloadTooLarge(ApiError):
    status, title, code = 413, "Body too large", "body_too_large"


class InvalidContent(ApiError):
    status, title, code = 422, "Invalid content", "invalid_content"


class _ComeBackLater(ApiError):
    """An error the same request may not meet later: it says when to try again (``Retry-After``)."""

    def __init__(self, detail: str, *, retry_after_s: int, code: str | None = None, **members: Any) -> None:
        super().__init__(detail, code=code, **members)
        self.headers = {"Retry-After": str(retry_after_s)}


class TooManyRequests(_ComeBackLater):
    status, title, code = 429, "Too many requests", "too_many_uploads"


class ServiceBusy(_ComeBackLater):
    status, title, code = 503, "Service busy", "service_busy"


class InsufficientStorage(_ComeBackLater):
    status, title, code = 507, "Insufficient storage", "out_of_space"


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
    *errors: type[ApiError], also: dict[int | str, dict[str, Any]] | None = None
) -> dict[int | str, dict[str, Any]]:
    """OpenAPI ``responses=`` entries for the errors a route can answer with, plus ``also``."""
    responses: dict[int | str, dict[str, Any]] = {**(also or {})}
    for error in errors:
        responses[error.status] = {
            "description": error.title,
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


def _api_error(_request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, ApiError)
    return problem(
        exc.status, exc.title, exc.detail, code=exc.instance_code, headers=exc.headers, **exc.members
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
        full = OutOfSpace.measured(store.root, store.min_free_bytes, reason="the database could not grow")
        return _out_of_space(request, full)
    log.warning("database unavailable: %s", exc)
    return problem(
        503,
        "Database unavailable",
        "the database is busy or unreachable; try again shortly",
        code="database_unavailable",
        headers={"Retry-After": "2"},
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
    return _api_error(request, refusal)


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
    app.add_exception_handler(Exception, _unexpected)
    app.add_exception_handler(ApiError, _api_error)
    app.add_exception_handler(CanopyError, _canopy_error)
    app.add_exception_handler(RequestValidationError, _validation_error)
    app.add_exception_handler(StarletteHTTPException, _http_error)
