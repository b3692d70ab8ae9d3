"""The FastAPI application: routers of each domain, problem+json errors, the API's conventions, and its
OpenAPI docs at /docs (Swagger UI) and /redoc, served from assets installed with the service, so they work
in a field office without internet."""

from __future__ import annotations

from fastapi import Depends, FastAPI
from fastapi_offline import FastAPIOffline

from canopy_core import __version__
from service import health
from service.captures import endpoints as captures
from service.context import Context
from service.conventions import ConditionalGet, reject_unknown_query
from service.farm import endpoints as farm
from service.jobs import endpoints as jobs
from service.keys import endpoints as keys
from service.problems import install_problem_handlers
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
    return app
