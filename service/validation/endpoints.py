"""HTTP routes of the validation against manual measurements: the CSV in, Table 1 out (JSON, CSV, PNG)."""

from __future__ import annotations

import hashlib
from typing import Annotated

from fastapi import APIRouter, Depends, Query, Request, Response
from starlette.concurrency import run_in_threadpool

from service.bodies import read_body
from service.conventions import strong_etag, unchanged
from service.deps import CaptureKey, ContextDep, ReadKey
from service.errors import InvalidContent, PayloadTooLarge, RequestTimeout
from service.problems import problem_responses
from service.validation.figure import scatter_png
from service.validation.manual import MANUAL_COLUMNS, read_manual_csv, store_manual
from service.validation.schemas import ManualReceipt, Validation
from service.validation.service import validation, validation_csv

__all__ = ["router"]

router = APIRouter(prefix="/v1", tags=["validation"])

_CSV_BODY = {
    "requestBody": {
        "required": True,
        "content": {"text/csv": {"schema": {"type": "string", "example": ",".join(MANUAL_COLUMNS)}}},
    }
}
OrchardQuery = Annotated[str | None, Query(max_length=200, description="Only this orchard's trees")]
RowQuery = Annotated[str | None, Query(max_length=200, description="Only this row's trees")]
WindowQuery = Annotated[
    float | None,
    Query(gt=0, le=3650, description="Pair within this many days (default: the service's setting)"),
]


@router.post(
    "/validation/manual",
    response_model=ManualReceipt,
    openapi_extra=_CSV_BODY,
    responses=problem_responses(InvalidContent, PayloadTooLarge, RequestTimeout),
)
async def upload_manual(request: Request, context: ContextDep, _key: CaptureKey) -> ManualReceipt:
    """Store manual measurements from CSV (``orchard,row,tree,date,height_m,width_m,thickness_m``, metres,
    empty where not measured); a tree and day sent again replaces its record. All lines or none."""
    body = await read_body(
        request,
        limit_bytes=context.settings.max_csv_bytes,
        idle_timeout_s=context.settings.upload_idle_timeout_s,
        what="manual measurements CSV",
    )
    lines = read_manual_csv(body)
    return await run_in_threadpool(context.database.write, lambda session: store_manual(session, lines))


def _paired(
    context: ContextDep,
    _key: ReadKey,
    orchard: OrchardQuery = None,
    row: RowQuery = None,
    window_days: WindowQuery = None,
) -> Validation:
    """The validation the request's filters ask for (every GET route of this module answers it)."""
    with context.database.reading() as session:
        return validation(
            session,
            window_days=window_days or context.settings.validation_window_days,
            orchard=orchard,
            row=row,
        )


PairedDep = Annotated[Validation, Depends(_paired)]


@router.get("/validation", response_model=Validation)
def validation_json(result: PairedDep) -> Validation:
    """Each manual measurement paired with the tree's measurement nearest in time (or why none), and the
    paper's Table 1 over the pairs: n, R², RMSE and ARE of H, W and D per view mode and merged."""
    return result


_CSV_ANSWER = problem_responses(
    also={200: {"content": {"text/csv": {}}, "description": "Table 1, one line per mode and metric"}}
)
_PNG_ANSWER = problem_responses(
    also={200: {"content": {"image/png": {}}, "description": "Calculated against manual, 1:1 line"}}
)


@router.get("/validation.csv", response_class=Response, responses=_CSV_ANSWER)
def validation_table_csv(request: Request, result: PairedDep) -> Response:
    """Table 1 as CSV."""
    return _answer(request, validation_csv(result).encode(), "text/csv; charset=utf-8", "validation.csv")


@router.get("/validation.png", response_class=Response, responses=_PNG_ANSWER)
def validation_scatter(request: Request, result: PairedDep) -> Response:
    """Calculated against manual H, W and D, per view mode, with the 1:1 line."""
    etag = strong_etag(hashlib.sha256(result.model_dump_json().encode()).hexdigest())
    not_modified = unchanged(request, etag)
    if not_modified is not None:
        return not_modified
    return Response(scatter_png(result), media_type="image/png", headers={"ETag": etag})


def _answer(request: Request, body: bytes, media_type: str, filename: str) -> Response:
    etag = strong_etag(hashlib.sha256(body).hexdigest())
    not_modified = unchanged(request, etag)
    if not_modified is not None:
        return not_modified
    return Response(
        body,
        media_type=media_type,
        headers={"ETag": etag, "Content-Disposition": f'attachment; filename="{filename}"'},
    )
