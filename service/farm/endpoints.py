"""HTTP routes of the farm management system's view: orchards, rows, trees, measurements, CSV, clouds."""

from __future__ import annotations

import hashlib
from collections.abc import Iterator
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Path, Query, Request, Response
from fastapi.responses import FileResponse, HTMLResponse, StreamingResponse

from canopy_core import __version__
from canopy_core.cloud_io import read_cloud
from service.captures.service import get_capture
from service.conventions import ItemId, SinceQuery, strong_etag, unchanged
from service.deps import ContextDep, ReadKey
from service.errors import BadRequest, Conflict, InvalidContent, NotFound, ServiceError
from service.farm.history import TreeHistory, history_csv, history_png, tree_history
from service.farm.las import las_bytes
from service.farm.schemas import MeasurementSummary, OrchardOut, OrchardSummary, RowOut, Summary, TreeOut
from service.farm.service import (
    get_measurement,
    get_orchard,
    get_row,
    get_tree,
    list_orchards,
    list_rows,
    list_tree_measurements,
    list_trees,
    measurement_document,
    measurements_csv,
    measurements_csv_etag,
)
from service.farm.summaries import orchard_summary, row_figure_png, row_summary, summary_csv
from service.models import Measurement as MeasurementRecord
from service.pagination import CursorQuery, LimitQuery, Page
from service.problems import problem_responses
from service.reports.page import report_html

__all__ = ["router"]

router = APIRouter(prefix="/v1", tags=["farm"])
_LISTS = problem_responses(BadRequest, NotFound)
_PNG: dict[int | str, dict[str, Any]] = {200: {"content": {"image/png": {}}, "description": "A PNG figure"}}
_SUMMARY_CSV = problem_responses(
    NotFound, also={200: {"content": {"text/csv": {}}, "description": "One line per scope and metric"}}
)


NameQuery = Annotated[str | None, Query(description="Only the one of this exact name")]


@router.get("/orchards", response_model=Page[OrchardOut], responses=_LISTS)
def orchards(
    context: ContextDep,
    _key: ReadKey,
    name: NameQuery = None,
    cursor: CursorQuery = None,
    limit: LimitQuery = 100,
) -> Page[OrchardOut]:
    """Every orchard, in the order first seen."""
    with context.database.reading() as session:
        return list_orchards(session, name=name, cursor=cursor, limit=limit)


@router.get("/orchards/{orchard_id}", response_model=OrchardOut, responses=problem_responses(NotFound))
def orchard(orchard_id: ItemId, context: ContextDep, _key: ReadKey) -> OrchardOut:
    """An orchard."""
    with context.database.reading() as session:
        return get_orchard(session, orchard_id)


@router.get("/orchards/{orchard_id}/rows", response_model=Page[RowOut], responses=_LISTS)
def rows(
    orchard_id: ItemId,
    context: ContextDep,
    _key: ReadKey,
    name: NameQuery = None,
    cursor: CursorQuery = None,
    limit: LimitQuery = 100,
) -> Page[RowOut]:
    """The rows of an orchard."""
    with context.database.reading() as session:
        return list_rows(session, orchard_id, name=name, cursor=cursor, limit=limit)


@router.get("/rows/{row_id}", response_model=RowOut, responses=problem_responses(NotFound))
def row(row_id: ItemId, context: ContextDep, _key: ReadKey) -> RowOut:
    """A row."""
    with context.database.reading() as session:
        return get_row(session, row_id)


@router.get("/rows/{row_id}/trees", response_model=Page[TreeOut], responses=_LISTS)
def trees(
    row_id: ItemId,
    context: ContextDep,
    _key: ReadKey,
    name: NameQuery = None,
    cursor: CursorQuery = None,
    limit: LimitQuery = 100,
) -> Page[TreeOut]:
    """The trees of a row, each with its latest measurement."""
    with context.database.reading() as session:
        return list_trees(session, row_id, name=name, cursor=cursor, limit=limit)


@router.get("/trees/{tree_id}", response_model=TreeOut, responses=problem_responses(NotFound))
def tree(tree_id: ItemId, context: ContextDep, _key: ReadKey) -> TreeOut:
    """A tree with its latest measurement."""
    with context.database.reading() as session:
        return get_tree(session, tree_id)


@router.get("/trees/{tree_id}/measurements", response_model=Page[MeasurementSummary], responses=_LISTS)
def tree_measurements(
    tree_id: ItemId, context: ContextDep, _key: ReadKey, cursor: CursorQuery = None, limit: LimitQuery = 100
) -> Page[MeasurementSummary]:
    """A tree's measurements, newest first."""
    with context.database.reading() as session:
        return list_tree_measurements(session, tree_id, cursor=cursor, limit=limit)


@router.get("/trees/{tree_id}/history", response_model=TreeHistory, responses=problem_responses(NotFound))
def history(tree_id: ItemId, context: ContextDep, _key: ReadKey) -> TreeHistory:
    """The tree's growth: its measurements' merged H, W and D, oldest capture first."""
    with context.database.reading() as session:
        return tree_history(session, tree_id)


@router.get("/trees/{tree_id}/history.csv", response_class=Response, responses=_SUMMARY_CSV)
def history_as_csv(tree_id: ItemId, request: Request, context: ContextDep, _key: ReadKey) -> Response:
    """The tree's growth as CSV."""
    with context.database.reading() as session:
        text = history_csv(tree_history(session, tree_id))
    return _csv_answer(request, text, f"tree-{tree_id}-history.csv")


@router.get(
    "/trees/{tree_id}/history.png", response_class=Response, responses=problem_responses(NotFound, also=_PNG)
)
def history_as_png(tree_id: ItemId, request: Request, context: ContextDep, _key: ReadKey) -> Response:
    """The tree's H, W and D against the capture date."""
    with context.database.reading() as session:
        found = tree_history(session, tree_id)
    etag = strong_etag(hashlib.sha256(f"{__version__}|{found.model_dump_json()}".encode()).hexdigest())
    not_modified = unchanged(request, etag)
    if not_modified is not None:
        return not_modified
    return Response(history_png(found), media_type="image/png", headers={"ETag": etag})


@router.get(
    "/measurements.csv",
    response_class=StreamingResponse,
    responses=problem_responses(
        BadRequest, also={200: {"content": {"text/csv": {}}, "description": "One line per measurement"}}
    ),
)
def measurements_export(
    context: ContextDep,
    _key: ReadKey,
    request: Request,
    orchard: Annotated[str | None, Query(description="Orchard name")] = None,
    row: Annotated[str | None, Query(description="Row name")] = None,
    since: SinceQuery = None,
) -> Response:
    """Measurements as CSV (metres), for a row, an orchard or everything; ``since`` is the capture time."""
    with context.database.reading() as session:
        etag = measurements_csv_etag(session, orchard=orchard, row=row, since=since)
    not_modified = unchanged(request, etag)
    if not_modified is not None:
        return not_modified

    def lines() -> Iterator[str]:
        with context.database.reading() as session:
            yield from measurements_csv(session, orchard=orchard, row=row, since=since)

    return StreamingResponse(
        lines(),
        media_type="text/csv; charset=utf-8",
        headers={
            "Content-Disposition": 'attachment; filename="measurements.csv"',
            "ETag": etag,
            "Cache-Control": "no-cache",
        },
    )


@router.get("/measurements/{measurement_id}", responses=problem_responses(NotFound))
def measurement(measurement_id: ItemId, context: ContextDep, _key: ReadKey) -> dict[str, Any]:
    """A measurement: merged metrics on top, ``modes`` per view and merged, ``registration``, ``config``."""
    with context.database.reading() as session:
        return measurement_document(session, get_measurement(session, measurement_id))


@router.get(
    "/measurements/{measurement_id}/cloud.ply",
    response_class=FileResponse,
    responses=problem_responses(
        NotFound,
        also={200: {"content": {"application/octet-stream": {}}, "description": "Binary PLY, metres"}},
    ),
)
def cloud(measurement_id: ItemId, request: Request, context: ContextDep, _key: ReadKey) -> Response:
    """The fused cloud of the measured views in the world frame (z up, ground at the trunk z = 0)."""
    with context.database.reading() as session:
        record = get_measurement(session, measurement_id)
    etag = strong_etag(record.cloud_sha256)
    not_modified = unchanged(request, etag)
    if not_modified is not None:
        return not_modified
    filename = f"measurement-{measurement_id}.ply"
    path = context.store.file_path(record.cloud_sha256)
    if path is not None:
        return FileResponse(
            path, media_type="application/octet-stream", filename=filename, headers={"ETag": etag}
        )
    try:
        ply = context.store.read(record.cloud_sha256)
    except FileNotFoundError:
        raise ServiceError(
            f"the fused cloud of measurement {measurement_id} is missing from the blob store"
        ) from None
    return Response(
        ply,
        media_type="application/octet-stream",
        headers={"ETag": etag, "Content-Disposition": f'attachment; filename="{filename}"'},
    )


@router.get(
    "/measurements/{measurement_id}/figures/{name}.png",
    response_class=Response,
    responses=problem_responses(NotFound, Conflict, also=_PNG),
)
def figure(
    measurement_id: ItemId,
    name: Annotated[str, Path(max_length=100, pattern=r"^[a-z0-9-]+$")],
    request: Request,
    context: ContextDep,
    _key: ReadKey,
) -> Response:
    """One of the figures the worker drew with the measurement (their names are in its ``figures``):
    ``report``, ``elevation``, ``top``, ``density``, ``modes``, ``balls-views-1``, ..."""
    with context.database.reading() as session:
        record = get_measurement(session, measurement_id)
    return _figure(request, context, record, name)


@router.get(
    "/measurements/{measurement_id}/report.png",
    response_class=Response,
    responses=problem_responses(NotFound, Conflict, also=_PNG),
)
def report_png(measurement_id: ItemId, request: Request, context: ContextDep, _key: ReadKey) -> Response:
    """The measurement's figures in one: side elevation, top view, height density, per view and merged."""
    with context.database.reading() as session:
        record = get_measurement(session, measurement_id)
    return _figure(request, context, record, "report")


@router.get(
    "/measurements/{measurement_id}/report",
    response_class=HTMLResponse,
    responses=problem_responses(
        NotFound, also={200: {"content": {"text/html": {}}, "description": "A page"}}
    ),
)
def report(measurement_id: ItemId, request: Request, context: ContextDep, _key: ReadKey) -> Response:
    """The measurement's report page: its numbers, registration diagnostics, figures and a 3D viewer of the
    fused cloud with where H, W and D were read."""
    with context.database.reading() as session:
        record = get_measurement(session, measurement_id)
        document = measurement_document(session, record)
        growth = tree_history(session, record.tree_id)
    figure_digests = sorted((record.figures or {}).items())
    known = f"{__version__}|{record.cloud_sha256}|{figure_digests}|{growth.model_dump_json()}"
    etag = strong_etag(hashlib.sha256(known.encode()).hexdigest())
    not_modified = unchanged(request, etag)
    if not_modified is not None:
        return not_modified
    try:
        cloud = read_cloud(context.store.read(record.cloud_sha256))
        figures = {name: context.store.read(digest) for name, digest in (record.figures or {}).items()}
    except FileNotFoundError as missing:
        raise ServiceError(
            f"a file of measurement {measurement_id} is missing from the blob store"
        ) from missing
    if len(growth.measurements) > 1:
        figures["growth"] = history_png(growth)
    return HTMLResponse(report_html(document, figures, cloud, growth), headers={"ETag": etag})


def _figure(request: Request, context: ContextDep, record: MeasurementRecord, name: str) -> Response:
    if record.figures is None:
        raise Conflict(
            f"measurement {record.id} was made before the worker drew figures; measure its capture again",
            code="measurement_without_figures",
        )
    digest = record.figures.get(name)
    if digest is None:
        raise NotFound(
            f"measurement {record.id} has no figure {name!r}; it has {', '.join(sorted(record.figures))}",
            code="unknown_figure",
        )
    etag = strong_etag(digest)
    not_modified = unchanged(request, etag)
    if not_modified is not None:
        return not_modified
    try:
        png = context.store.read(digest)
    except FileNotFoundError as missing:
        raise ServiceError(
            f"figure {name!r} of measurement {record.id} is missing from the blob store"
        ) from missing
    return Response(png, media_type="image/png", headers={"ETag": etag})


_LAS_TYPES = {"las": "application/vnd.las", "laz": "application/vnd.laszip"}


@router.get(
    "/measurements/{measurement_id}/cloud.{kind}",
    response_class=Response,
    responses=problem_responses(
        NotFound,
        Conflict,
        InvalidContent,
        also={
            200: {
                "content": {media: {} for media in _LAS_TYPES.values()},
                "description": "LAS 1.4 or LAZ, metres, RGB and ASPRS classes",
            }
        },
    ),
)
def cloud_las(
    measurement_id: ItemId,
    kind: Literal["las", "laz"],
    request: Request,
    context: ContextDep,
    _key: ReadKey,
    view: Annotated[
        str | None, Query(max_length=200, description="Only the points this view saw, e.g. views/1")
    ] = None,
) -> Response:
    """The fused cloud as LAS 1.4 (``cloud.las``) or LAZ (``cloud.laz``), each point classed ground (2),
    tree (5), calibration ball (64) or other (1); with ``view``, that view's points alone."""
    with context.database.reading() as session:
        record = get_measurement(session, measurement_id)
        views = list(get_capture(session, record.capture_id).manifest["views"])
    if view is not None and view not in views:
        raise InvalidContent(
            f"measurement {measurement_id} has no view {view!r}; its views are {', '.join(views)}",
            code="unknown_view",
            field="view",
        )
    etag = strong_etag(hashlib.sha256(f"{record.cloud_sha256}|{kind}|{view}".encode()).hexdigest())
    not_modified = unchanged(request, etag)
    if not_modified is not None:
        return not_modified
    try:
        cloud = read_cloud(context.store.read(record.cloud_sha256))
    except FileNotFoundError as missing:
        raise ServiceError(
            f"the fused cloud of measurement {measurement_id} is missing from the blob store"
        ) from missing
    if view is not None:
        if cloud.views is None:
            raise Conflict(
                f"measurement {measurement_id} was made before clouds recorded which view saw each point; "
                "measure its capture again for clouds per view",
                code="cloud_without_views",
                field="view",
            )
        cloud = cloud.only(cloud.views == views.index(view))
    suffix = "" if view is None else "-" + view.replace("/", "-")
    return Response(
        las_bytes(cloud, compressed=kind == "laz"),
        media_type=_LAS_TYPES[kind],
        headers={
            "ETag": etag,
            "Content-Disposition": f'attachment; filename="measurement-{measurement_id}{suffix}.{kind}"',
        },
    )


@router.get("/rows/{row_id}/summary", response_model=Summary, responses=problem_responses(NotFound))
def row_summary_json(row_id: ItemId, context: ContextDep, _key: ReadKey) -> Summary:
    """Per metric (H, W, D, crown volume, projected area), count, mean, median, min, max and standard
    deviation over the latest measurement of each tree of the row; the trees beyond 2 standard deviations."""
    with context.database.reading() as session:
        return row_summary(session, row_id)


@router.get(
    "/rows/{row_id}/summary.png", response_class=Response, responses=problem_responses(NotFound, also=_PNG)
)
def row_summary_png(row_id: ItemId, context: ContextDep, _key: ReadKey) -> Response:
    """Each tree's latest H and W along the row, the row's means, the trees beyond 2 standard deviations."""
    with context.database.reading() as session:
        return Response(row_figure_png(session, row_id), media_type="image/png")


@router.get(
    "/orchards/{orchard_id}/summary", response_model=OrchardSummary, responses=problem_responses(NotFound)
)
def orchard_summary_json(orchard_id: ItemId, context: ContextDep, _key: ReadKey) -> OrchardSummary:
    """The row summary's figures over the whole orchard, then for each of its rows."""
    with context.database.reading() as session:
        return orchard_summary(session, orchard_id)


@router.get("/rows/{row_id}/summary.csv", response_class=Response, responses=_SUMMARY_CSV)
def row_summary_csv(row_id: ItemId, request: Request, context: ContextDep, _key: ReadKey) -> Response:
    """The row's summary as CSV."""
    with context.database.reading() as session:
        return _csv_answer(request, summary_csv(row_summary(session, row_id)), f"row-{row_id}-summary.csv")


@router.get("/orchards/{orchard_id}/summary.csv", response_class=Response, responses=_SUMMARY_CSV)
def orchard_summary_csv(orchard_id: ItemId, request: Request, context: ContextDep, _key: ReadKey) -> Response:
    """The orchard's summary and its rows' as CSV."""
    with context.database.reading() as session:
        text = summary_csv(orchard_summary(session, orchard_id))
    return _csv_answer(request, text, f"orchard-{orchard_id}-summary.csv")


def _csv_answer(request: Request, text: str, filename: str) -> Response:
    """A CSV body with its ETag (304 when the client has it)."""
    etag = strong_etag(hashlib.sha256(text.encode()).hexdigest())
    not_modified = unchanged(request, etag)
    if not_modified is not None:
        return not_modified
    return Response(
        text,
        media_type="text/csv; charset=utf-8",
        headers={"ETag": etag, "Content-Disposition": f'attachment; filename="{filename}"'},
    )
