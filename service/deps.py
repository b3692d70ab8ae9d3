"""FastAPI dependencies: the shared context and API-key checks, as ``Annotated`` aliases for routes."""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from service.admission import Admission
from service.context import Context
from service.errors import Forbidden, Unauthorized
from service.keys.service import authenticate, grants
from service.keys.sessions import SESSION_COOKIE, session_key
from service.metrics import ServiceMetrics
from service.models import ApiKey

__all__ = [
    "AdminKey",
    "AdmissionDep",
    "AnyKey",
    "CaptureKey",
    "CaptureOrReadKey",
    "ContextDep",
    "MetricsDep",
    "ReadKey",
]


def get_context(request: Request) -> Context:
    """The context the app was built with."""
    context: Context = request.app.state.context
    return context


ContextDep = Annotated[Context, Depends(get_context)]


def get_admission(request: Request) -> Admission:
    """The API process's upload slots and image-check turns."""
    admission: Admission = request.app.state.admission
    return admission


AdmissionDep = Annotated[Admission, Depends(get_admission)]


def get_metrics(request: Request) -> ServiceMetrics:
    """The API process's Prometheus metrics."""
    metrics: ServiceMetrics = request.app.state.metrics
    return metrics


MetricsDep = Annotated[ServiceMetrics, Depends(get_metrics)]


_BEARER = HTTPBearer(
    auto_error=False,
    scheme_name="apiKey",
    description="An API key made by `canopy keys create` or POST /v1/keys: `Authorization: Bearer <key>`",
)
BearerDep = Annotated[HTTPAuthorizationCredentials | None, Depends(_BEARER)]
"""The bearer credentials of a request, None without any; declared in the OpenAPI document as its
security scheme, so that Swagger UI offers to send the key."""


_SESSION_METHODS = frozenset({"GET", "HEAD"})
"""What a browser session's cookie may do: read. Anything that changes data needs the key as a bearer, so a
cookie a browser sends by itself can never write (no cross-site request forgery to fear)."""


def _require(*scopes: str) -> Callable[[Request, Context, HTTPAuthorizationCredentials | None], ApiKey]:
    """A dependency that lets through keys holding any of ``scopes`` (or ``admin``): sent as a bearer, or,
    to read, by a browser session's cookie (:mod:`service.keys.sessions`)."""

    def check(request: Request, context: ContextDep, credentials: BearerDep) -> ApiKey:
        cookie = request.cookies.get(SESSION_COOKIE)
        if credentials is None and cookie and request.method in _SESSION_METHODS:
            with context.database.reading() as session:
                record = session_key(session, cookie)
        elif credentials is None or credentials.scheme.lower() != "bearer" or not credentials.credentials:
            raise Unauthorized(
                "send the API key as 'Authorization: Bearer <key>' (a browser session signs in reads only)"
                if cookie
                else "send the API key as 'Authorization: Bearer <key>'"
            )
        else:
            with context.database.reading() as session:
                record = authenticate(session, credentials.credentials.strip())
        if not any(grants(record, scope) for scope in scopes):
            needed = " or ".join(f"'{scope}'" for scope in scopes)
            raise Forbidden(
                f"this request needs the {needed} scope; key {record.prefix} has {record.scopes}",
                scope=scopes[0],
            )
        return record

    return check


ReadKey = Annotated[ApiKey, Depends(_require("read"))]
CaptureKey = Annotated[ApiKey, Depends(_require("capture"))]
AdminKey = Annotated[ApiKey, Depends(_require("admin"))]
CaptureOrReadKey = Annotated[ApiKey, Depends(_require("capture", "read"))]
"""For what an uploading client must see of its own work: which files a capture misses, its job's state."""
AnyKey = Annotated[ApiKey, Depends(_require("capture", "read", "admin"))]
"""Any valid key, whatever its scopes: for what a client asks before it starts (who am I, is it up)."""
