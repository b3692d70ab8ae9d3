"""Creating captures (idempotently, by tree and capture time) and reporting which files they hold."""

from __future__ import annotations

import json
from collections.abc import Collection

from sqlalchemy import delete, select
from sqlalchemy.orm import Session

from canopy_core.capture import (
    CaptureManifest,
    capture_time,
    expected_files,
    parse_manifest,
    stored_manifest,
)
from service.captures.schemas import CaptureOut
from service.errors import Conflict, Forbidden, NotFound
from service.keys.service import grants
from service.models import ApiKey, Capture, CaptureFile, Job, Orchard, Row, Tree

__all__ = [
    "capture_manifest",
    "capture_out",
    "check_access",
    "create_capture",
    "delete_capture",
    "get_capture",
    "missing_files",
]


def _tree(session: Session, manifest: CaptureManifest) -> Tree:
    orchard = session.scalar(select(Orchard).where(Orchard.name == manifest.orchard))
    if orchard is None:
        orchard = Orchard(name=manifest.orchard)
        session.add(orchard)
        session.flush()
    row = session.scalar(select(Row).where(Row.orchard_id == orchard.id, Row.name == manifest.row))
    if row is None:
        row = Row(orchard_id=orchard.id, name=manifest.row)
        session.add(row)
        session.flush()
    tree = session.scalar(select(Tree).where(Tree.row_id == row.id, Tree.name == manifest.tree))
    if tree is None:
        tree = Tree(row_id=row.id, name=manifest.tree)
        session.add(tree)
        session.flush()
    return tree


def create_capture(session: Session, body: bytes, *, key: ApiKey) -> tuple[Capture, bool]:
    """The capture ``body`` (capture.json's bytes) describes, and whether it was created now (by ``key``,
    which owns it then).

    The same orchard, row, tree and capture time name the same capture: sending it again returns the one
    stored, if ``key`` may write to it (see :func:`check_access`). A different capture.json for that tree
    and time is a conflict, never a second capture.
    """
    manifest = parse_manifest(body)
    captured_at = capture_time(manifest)
    document = json.loads(body)
    tree = _tree(session, manifest)
    existing = session.scalar(
        select(Capture).where(Capture.tree_id == tree.id, Capture.captured_at == captured_at)
    )
    if existing is not None:
        if existing.manifest != document:
            raise Conflict(
                f"tree {manifest.tree} of row {manifest.row} in {manifest.orchard} already has a capture at "
                f"{manifest.captured_at} (id {existing.id}) with a different capture.json",
                file="capture.json",
                capture_id=existing.id,
            )
        check_access(existing, key, writing=True)
        return existing, False
    capture = Capture(tree_id=tree.id, captured_at=captured_at, manifest=document, created_by_key_id=key.id)
    session.add(capture)
    session.flush()
    return capture, True


def delete_capture(session: Session, capture_id: int) -> None:
    """Delete a capture with its files' records, jobs and measurements; 409 while a job is queued or running.

    The files' bytes stay in the blob store: they may be shared with other captures (the store keeps
    identical bytes once), and removing unreferenced blobs safely is a sweep's job, not a request's.
    """
    get_capture(session, capture_id)
    active = session.scalar(
        select(Job.id).where(Job.capture_id == capture_id, Job.state.in_(("queued", "running"))).limit(1)
    )
    if active is not None:
        raise Conflict(
            f"capture {capture_id} has job {active} queued or running; delete it once the job has finished",
            code="job_active",
            job_id=active,
        )
    session.execute(delete(Capture).where(Capture.id == capture_id))  # the database cascades the rest


def get_capture(session: Session, capture_id: int) -> Capture:
    """The capture with this id, or a 404 problem."""
    capture = session.get(Capture, capture_id)
    if capture is None:
        raise NotFound(f"no capture with id {capture_id}", capture_id=capture_id)
    return capture


def check_access(capture: Capture, key: ApiKey, *, writing: bool) -> None:
    """A 403 problem unless ``key`` may write to (``writing``) or read the capture.

    A capture key writes only to the captures it created (files, jobs), and reads only those; reading
    others takes the read scope, writing them the admin scope. Captures made before keys owned them
    (``created_by_key_id`` None) are open to any capture key, as they were.
    """
    if capture.created_by_key_id in (None, key.id) or grants(key, "admin"):
        return
    if not writing and grants(key, "read"):
        return
    doing = "writes to" if writing else "reads"
    raise Forbidden(
        f"capture {capture.id} was created by another API key; key {key.prefix} {doing} only the captures "
        "it created: send it with the key that created it, or with an admin key",
        code="not_capture_owner",
        capture_id=capture.id,
    )


def capture_manifest(capture: Capture) -> CaptureManifest:
    """The stored manifest, parsed (it was validated when the capture was created)."""
    return stored_manifest(capture.manifest)


def _received(session: Session, capture_id: int) -> dict[str, str]:
    """Each received file's SHA-256 (hex), by path, in path order."""
    rows = session.execute(
        select(CaptureFile.path, CaptureFile.sha256)
        .where(CaptureFile.capture_id == capture_id)
        .order_by(CaptureFile.path)
    )
    return {path: sha256 for path, sha256 in rows}


def missing_files(manifest: CaptureManifest, received: Collection[str]) -> list[str]:
    """Files the capture still needs; a view's colour is missing only when neither PNG nor JPEG came."""
    return [path for path in expected_files(manifest, received) if path not in received]


def capture_out(session: Session, capture: Capture) -> CaptureOut:
    """The capture as the API shows it, with its files received and missing."""
    manifest = capture_manifest(capture)
    tree = session.get_one(Tree, capture.tree_id)
    received = _received(session, capture.id)
    return CaptureOut(
        id=capture.id,
        orchard=manifest.orchard,
        row=manifest.row,
        tree=manifest.tree,
        tree_id=tree.id,
        captured_at=capture.captured_at,
        views=manifest.views,
        files_expected=expected_files(manifest, received),
        files_received=list(received),
        files_sha256=received,
        files_missing=missing_files(manifest, received),
        created_at=capture.created_at,
    )
