"""HTTP routes of captures: create one, look at it, upload its files."""

from __future__ import annotations

from functools import partial
from typing import Annotated, Any

from fastapi import APIRouter, Header, Request, Response
from fastapi.concurrency import run_in_threadpool
from sqlalchemy.orm import Session

from service.bodies import declared_length, read_body, receive_body
from service.captures.schemas import CaptureOut, FileOut
from service.captures.service import (
    capture_manifest,
    capture_out,
    check_access,
    create_capture,
    delete_capture,
    get_capture,
)
from service.captures.uploads import (
    FileFacts,
    check_against_stored,
    check_content,
    check_path,
    parse_content_digest,
    record_file,
)
from service.conventions import ItemId
from service.deps import AdminKey, AdmissionDep, CaptureKey, CaptureOrReadKey, ContextDep, MetricsDep
from service.errors import (
    BadRequest,
    Conflict,
    Forbidden,
    InsufficientStorage,
    InvalidContent,
    NotFound,
    PayloadTooLarge,
    RequestTimeout,
    ServiceBusy,
    TooManyRequests,
)
from service.models import CaptureFile
from service.problems import COMPONENT_REF, problem_responses

__all__ = ["router"]

router = APIRouter(prefix="/v1/captures", tags=["captures"])

_MANIFEST_BODY: dict[str, Any] = {
    "requestBody": {
        "required": True,
        "content": {"application/json": {"schema": {"$ref": COMPONENT_REF.format(model="CaptureManifest")}}},
    }
}
_FILE_BODY: dict[str, Any] = {
    "requestBody": {
        "required": True,
        "content": {"application/octet-stream": {"schema": {"type": "string", "format": "binary"}}},
    }
}


@router.post(
    "",
    response_model=CaptureOut,
    status_code=201,
    openapi_extra=_MANIFEST_BODY,
    responses=problem_responses(
        Conflict,
        InvalidContent,
        PayloadTooLarge,
        InsufficientStorage,
        Forbidden,
        also={200: {"description": "The capture existed already"}},
    ),
)
async def create(request: Request, response: Response, context: ContextDep, key: CaptureKey) -> CaptureOut:
    """Create a capture from capture.json's content, or return the one with the same tree and time."""
    body = await read_body(
        request,
        limit_bytes=context.settings.max_json_bytes,
        idle_timeout_s=context.settings.upload_idle_timeout_s,
        what="capture.json",
    )
    context.store.check_space()

    def create_in_database(session: Session) -> tuple[CaptureOut, bool]:
        capture, created = create_capture(session, body, key=key)
        return capture_out(session, capture), created

    out, created = await run_in_threadpool(context.database.write, create_in_database)
    response.status_code = 201 if created else 200
    response.headers["Location"] = f"/v1/captures/{out.id}"
    return out


@router.get("/{capture_id}", response_model=CaptureOut, responses=problem_responses(NotFound, Forbidden))
def read(capture_id: ItemId, context: ContextDep, key: CaptureOrReadKey) -> CaptureOut:
    """A capture and which of its files have been received (a capture key: of the captures it created)."""
    with context.database.reading() as session:
        capture = get_capture(session, capture_id)
        check_access(capture, key, writing=False)
        return capture_out(session, capture)


@router.delete(
    "/{capture_id}", status_code=204, response_class=Response, responses=problem_responses(NotFound, Conflict)
)
def remove(capture_id: ItemId, context: ContextDep, _key: AdminKey) -> Response:
    """Delete a capture, its files, jobs and measurements (admin scope); 409 while its job runs."""
    context.database.write(lambda session: delete_capture(session, capture_id))
    return Response(status_code=204)


@router.put(
    "/{capture_id}/files/{path:path}",
    response_model=FileOut,
    status_code=201,
    openapi_extra=_FILE_BODY,
    responses=problem_responses(
        BadRequest,
        NotFound,
        Conflict,
        PayloadTooLarge,
        InvalidContent,
        RequestTimeout,
        TooManyRequests,
        ServiceBusy,
        InsufficientStorage,
        Forbidden,
        also={200: {"description": "The same bytes were stored already"}},
    ),
)
async def put_file(
    capture_id: ItemId,
    path: str,
    request: Request,
    response: Response,
    context: ContextDep,
    admission: AdmissionDep,
    metrics: MetricsDep,
    key: CaptureKey,
    content_digest: Annotated[str | None, Header(description="sha-256=:<base64>: (RFC 9530)")] = None,
) -> FileOut:
    """Store one file of the capture, verified against its SHA-256; re-sending the same bytes is harmless.

    The body streams to a temporary file beside the blobs while it is hashed, and is checked from there:
    memory holds one network chunk of it, and an image's pixels only while it is checked (a few at once).
    """
    settings = context.settings

    def locate() -> str:
        with context.database.reading() as session:
            capture = get_capture(session, capture_id)
            check_access(capture, key, writing=True)
            return check_path(capture_manifest(capture), path)

    def compare(session: Session, sha256: str, facts: FileFacts | None) -> CaptureFile | None:
        return check_against_stored(
            context, session, capture_id, path=path, view=view, sha256=sha256, facts=facts
        )

    def compare_now(sha256: str, facts: FileFacts | None) -> CaptureFile | None:
        with context.database.reading() as session:
            return compare(session, sha256, facts)

    def persist(session: Session) -> tuple[CaptureFile, bool]:
        repeated = compare(session, sha256, facts)
        if repeated is not None:
            return repeated, False
        record = record_file(
            session, capture_id, path=path, sha256=sha256, size_bytes=incoming.size_bytes, facts=facts
        )
        return record, True

    view = await run_in_threadpool(locate)
    declared = parse_content_digest(content_digest)
    # A conflict is told before the body is read: no point in taking megabytes that will be refused.
    await run_in_threadpool(compare_now, declared, None)
    limit = settings.max_json_bytes if path.endswith(".json") else settings.max_upload_bytes
    context.store.check_space(declared_length(request, limit_bytes=limit, what=path) or 0)
    with admission.upload(key.id, file=path), context.store.receive() as incoming:
        await receive_body(
            request, incoming, limit_bytes=limit, idle_timeout_s=settings.upload_idle_timeout_s, what=path
        )
        await run_in_threadpool(incoming.finish)
        sha256 = incoming.sha256
        if sha256 != declared:
            raise BadRequest(
                f"the body's SHA-256 ({sha256}) is not the one Content-Digest declares ({declared}); "
                "the file was damaged on the way: send it again",
                code="digest_mismatch",
                file=path,
                field="Content-Digest",
            )
        repeated = await run_in_threadpool(compare_now, sha256, None)
        if repeated is None:
            facts = await admission.check_image(
                partial(
                    check_content, incoming.path, path=path, view=view, max_pixels=settings.max_image_pixels
                )
            )
            repeated = await run_in_threadpool(compare_now, sha256, facts)
        if repeated is not None:
            response.status_code = 200
            return FileOut.model_validate(repeated, from_attributes=True)
        await run_in_threadpool(incoming.commit)
        metrics.upload_bytes.inc(incoming.size_bytes)
    record, created = await run_in_threadpool(context.database.write, persist)
    response.status_code = 201 if created else 200
    return FileOut.model_validate(record, from_attributes=True)
