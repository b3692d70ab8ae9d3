"""The FastAPI application: routers of each domain, problem+json errors, the API's conventions, and its
OpenAPI docs at /docs (Swagger UI) and /redoc, served from assets installed with the service, so they work
in a field office without internet."""

from __future__ import annotations

from typing import Any

from fastapi import Depends, FastAPI
from fastapi.openapi.utils import get_openapi
from fastapi_offline import FastAPIOffline

from canopy_core import __version__
from canopy_core.capture import CaptureManifest
from service import health
from service.captures import endpoints as captures
from service.context import Context
from service.conventions import ConditionalGet, reject_unknown_query
from service.farm import endpoints as farm
from service.jobs import endpoints as jobs
from service.keys import endpoints as keys
from service.problems import Problem, component_schemas, install_problem_handlers
from service.settings import Settings

__all__ = ["create_app"]


def create_app(context: Context | None = None) -> FastAPI:
    """The API over ``context`` (default: built from the ``CANOPY_*`` environment)."""
    app = FastAPIOffline(
        dependencies=[Depends(reject_unknown_query)],
        title="Canopy",
        version=__version__,
        summary="Measures fruit-tree canopies (height, width, crown thickness) from RGB-D captures.",
        description="All lengths are metres. Every /v1 route and /readyz need `Authorization: Bearer <key>`. "
        "The whole contract (scopes, errors, ETags, idempotency, paging) is docs/api.md in the repository.",
    )
    app.state.context = context or Context.from_settings(Settings())
    install_problem_handlers(app)
    app.add_middleware(ConditionalGet)
    for module in (health, captures, jobs, farm, keys):
        app.include_router(module.router)
    app.openapi = lambda: _openapi(app)  # type: ignore[method-assign]
    return app


def _openapi(app: FastAPI) -> dict[str, Any]:
    """The OpenAPI document FastAPI builds, with the schemas routes name by reference and FastAPI does not
    collect itself: problem details, and capture.json (a raw body, read before it is parsed)."""
    if app.openapi_schema is None:
        document = get_openapi(
            title=app.title,
            version=app.version,
            summary=app.summary,
            description=app.description,
            routes=app.routes,
        )
        schemas = document.setdefault("components", {}).setdefault("schemas", {})
        schemas.update(component_schemas(Problem, CaptureManifest))
        app.openapi_schema = document
    return app.openapi_schema
