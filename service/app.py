"""The FastAPI application: routers of each domain, problem+json errors, the API's conventions, and its
OpenAPI docs at /docs (Swagger UI) and /redoc, served from assets installed with the service, so they work
in a field office without internet."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

from fastapi import Depends, FastAPI
from fastapi.concurrency import run_in_threadpool
from fastapi.openapi.utils import get_openapi
from fastapi.staticfiles import StaticFiles
from fastapi_offline import FastAPIOffline

from canopy_core import __version__
from canopy_core.capture import CaptureManifest
from service import dashboard, health
from service.admission import Admission
from service.app_files import STATIC_DIR
from service.captures import endpoints as captures
from service.context import Context
from service.conventions import ConditionalGet, reject_unknown_query
from service.farm import endpoints as farm
from service.jobs import endpoints as jobs
from service.keys import endpoints as keys
from service.keys import session_endpoints as sessions
from service.metrics import RequestTimer, ServiceMetrics
from service.problems import Problem, component_schemas, install_problem_handlers
from service.settings import load_settings
from service.validation import endpoints as validation

__all__ = ["create_app"]

log = logging.getLogger("canopy.service")


@asynccontextmanager
async def _lifespan(app: FastAPI) -> AsyncIterator[None]:
    """While the API runs: remove the temporary files of uploads that ended unfinished, at start-up and
    every quarter of ``stale_upload_s`` after (see :meth:`BlobStore.remove_stale_incoming`); at shutdown,
    those of the uploads the shutdown cancelled (:meth:`BlobStore.discard_arriving`)."""
    context: Context = app.state.context
    older_than_s = context.settings.stale_upload_s

    async def sweep() -> None:
        while True:
            removed = await run_in_threadpool(context.store.remove_stale_incoming, older_than_s=older_than_s)
            if removed:
                log.warning("removed %d temporary file(s) of unfinished uploads", removed)
            await asyncio.sleep(older_than_s / 4)

    sweeping = asyncio.create_task(sweep())
    try:
        yield
    finally:
        sweeping.cancel()
        discarded = context.store.discard_arriving()
        if discarded:
            log.warning(
                "discarded %d upload(s) cancelled by the shutdown; their clients send them again", discarded
            )


def create_app(context: Context | None = None) -> FastAPI:
    """The API over ``context`` (default: built from the ``CANOPY_*`` environment)."""
    app = FastAPIOffline(
        lifespan=_lifespan,
        dependencies=[Depends(reject_unknown_query)],
        title="Canopy",
        version=__version__,
        summary="Measures fruit-tree canopies (height, width, crown thickness) from RGB-D captures.",
        description="All lengths are metres. Every /v1 route and /readyz need `Authorization: Bearer <key>`. "
        "The whole contract (scopes, errors, ETags, idempotency, paging) is docs/api.md in the repository.",
    )
    app.state.context = context = context or Context.from_settings(load_settings())
    app.state.admission = Admission(context.settings)
    app.state.metrics = metrics = ServiceMetrics(context.database)
    install_problem_handlers(app)
    app.add_middleware(ConditionalGet)
    app.add_middleware(RequestTimer, metrics=metrics)  # outermost: the whole answer is timed
    for module in (health, captures, jobs, farm, keys, sessions, validation, dashboard):
        app.include_router(module.router)
    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")
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
