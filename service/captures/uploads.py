"""Receiving one file of a capture: its path, its RFC 9530 digest, its content, and storing it once.

The content is checked with the measurement core's own rules (``parse_camera``, ``open_depth``,
``open_color``), on the file the body was streamed to, so a file the service accepts is a file the
measurement can read. Sizes are checked
against camera.json whichever arrives first. The bytes are made durable in the blob store (outside any
database lock) before the record that acknowledges them is committed; the checks against the capture's
other files run again in the write transaction.
"""

from __future__ import annotations

import base64
import binascii
import re
from dataclasses import dataclass
from pathlib import Path

from sqlalchemy import select
from sqlalchemy.orm import Session

from canopy_core.capture import CameraModel, CaptureManifest, color_file_names, parse_camera
from canopy_core.errors import CaptureError
from canopy_core.images import open_color, open_depth
from service.context import Context
from service.errors import BadRequest, Conflict, InvalidContent
from service.models import CaptureFile

__all__ = [
    "FileFacts",
    "check_against_stored",
    "check_content",
    "check_path",
    "parse_content_digest",
    "record_file",
]

_VIEW_FILES = ("camera.json", "depth.png", "color.png", "color.jpg")
_DIGEST_MEMBER = re.compile(r"\s*([A-Za-z0-9-]+)\s*=\s*:([A-Za-z0-9+/=]*):\s*")


@dataclass(frozen=True)
class FileFacts:
    """What a checked file's content says about it: image size, or the camera it describes."""

    image_width: int | None = None
    image_height: int | None = None
    camera: CameraModel | None = None


def check_path(manifest: CaptureManifest, path: str) -> str:
    """The view a file path belongs to; a 422 problem for a path outside the capture or not in it."""
    segments = path.split("/")
    if path.startswith("/") or "\\" in path or any(segment in {"..", "."} for segment in segments):
        raise InvalidContent(
            f"file path {path!r} points outside the capture; use a path such as views/1/depth.png",
            code="invalid_path",
            file=path,
        )
    view = "/".join(segments[:-1])
    # Split on "/" as written (no normalising): "views/1//depth.png" or a trailing "/" are other names.
    if len(segments) != 3 or view not in manifest.views or segments[-1] not in _VIEW_FILES:
        raise InvalidContent(
            f"file path {path!r} is not a file of this capture: its views are {', '.join(manifest.views)}, "
            f"each with {', '.join(_VIEW_FILES[:3])} (or color.jpg)",
            code="invalid_path",
            file=path,
        )
    return view


def parse_content_digest(header: str | None) -> str:
    """The SHA-256 hex digest a ``Content-Digest`` header (RFC 9530) declares; 400 if absent or unusable."""
    if not header:
        raise BadRequest(
            "send the file's SHA-256 as 'Content-Digest: sha-256=:<base64>:' (RFC 9530)",
            code="digest_missing",
            field="Content-Digest",
        )
    for member in header.split(","):
        match = _DIGEST_MEMBER.fullmatch(member)
        if match and match.group(1).lower() == "sha-256":
            try:
                raw = base64.b64decode(match.group(2), validate=True)
            except binascii.Error:
                raw = b""
            if len(raw) != 32:
                raise BadRequest(
                    "Content-Digest's sha-256 value is not the base64 of a 32-byte digest",
                    code="digest_invalid",
                    field="Content-Digest",
                )
            return raw.hex()
    raise BadRequest(
        f"Content-Digest {header!r} has no sha-256 member; only sha-256 is accepted",
        code="digest_invalid",
        field="Content-Digest",
    )


def check_content(received: Path, *, path: str, view: str, max_pixels: int) -> FileFacts:
    """Check a received file (``received``: where its body was written; ``path``: its name in the capture)
    by its kind on its own; sizes against camera.json come at storing."""
    name = path.rsplit("/", 1)[-1]
    if name == "camera.json":  # read whole: its size was limited to max_json_bytes
        return FileFacts(camera=parse_camera(received.read_bytes(), file=path, view=view))
    opener = open_depth if name == "depth.png" else open_color
    with opener(received, file=path, view=view, max_pixels=max_pixels) as image:
        return FileFacts(image_width=image.width, image_height=image.height)


def _stored_camera(context: Context, files: dict[str, CaptureFile], view: str) -> CameraModel | None:
    record = files.get(f"{view}/camera.json")
    if record is None:
        return None
    return parse_camera(context.store.read(record.sha256), file=record.path, view=view, stored=True)


def _check_sizes(
    context: Context, files: dict[str, CaptureFile], *, path: str, view: str, facts: FileFacts
) -> None:
    """Depth and colour sizes must agree with camera.json, whichever of them came first."""
    camera = facts.camera or _stored_camera(context, files, view)
    if camera is None:
        return
    images = (
        {path: (facts.image_width, facts.image_height)}
        if facts.camera is None
        else {
            record.path: (record.image_width, record.image_height)
            for record in files.values()
            if record.path.startswith(f"{view}/") and record.image_width is not None
        }
    )
    for image_path, (width, height) in images.items():
        is_depth = image_path.endswith("/depth.png")
        expected = camera.depth.size if is_depth else camera.color_size
        if (width, height) != expected:
            what = (
                "depth_intrinsics"
                if is_depth
                else ("depth_intrinsics" if camera.registered else "color_intrinsics")
            )
            raise CaptureError(
                f"{image_path} is {width}x{height} but {view}/camera.json {what} says "
                f"{expected[0]}x{expected[1]}",
                file=path,
                view=view,
                field=what if facts.camera is not None else None,
            )


def check_against_stored(
    context: Context,
    session: Session,
    capture_id: int,
    *,
    path: str,
    view: str,
    sha256: str,
    facts: FileFacts | None,
) -> CaptureFile | None:
    """Check a file against what the capture holds: the record of these same bytes at ``path`` if there is
    one (the upload is a harmless repeat), else None (it may be stored).

    Different bytes for a stored path, or a second colour image for a view, are a 409 conflict; with
    ``facts`` (the content was checked), sizes that disagree with camera.json are a 422.
    """
    files = {
        record.path: record
        for record in session.scalars(select(CaptureFile).where(CaptureFile.capture_id == capture_id))
    }
    existing = files.get(path)
    if existing is not None:
        if existing.sha256 != sha256:
            raise Conflict(
                f"{path} is already stored with other content (sha-256 {existing.sha256}); "
                "a stored file is never replaced",
                code="file_conflict",
                file=path,
                view=view,
            )
        return existing
    if path in color_file_names(view):
        other = next((name for name in color_file_names(view) if name != path and name in files), None)
        if other is not None:
            raise Conflict(
                f"{view} already has its colour image as {other}; send one of color.png or color.jpg",
                code="file_conflict",
                file=path,
                view=view,
            )
    if facts is not None:
        _check_sizes(context, files, path=path, view=view, facts=facts)
    return None


def record_file(
    session: Session, capture_id: int, *, path: str, sha256: str, size_bytes: int, facts: FileFacts
) -> CaptureFile:
    """Record a file whose bytes are already durable in the blob store."""
    record = CaptureFile(
        capture_id=capture_id,
        path=path,
        sha256=sha256,
        size_bytes=size_bytes,
        image_width=facts.image_width,
        image_height=facts.image_height,
    )
    session.add(record)
    session.flush()
    return record
