"""What the captures endpoints answer."""

from __future__ import annotations

from datetime import datetime

from pydantic import BaseModel, Field

__all__ = ["CaptureOut", "FileOut"]


class CaptureOut(BaseModel):
    """A capture and how far its upload has come."""

    id: int
    orchard: str
    row: str
    tree: str
    tree_id: int
    captured_at: datetime
    views: list[str]
    files_expected: list[str] = Field(
        description="Every file the capture needs besides capture.json; a view's colour by the name it came "
        "under (color.png or color.jpg), as color.png until one came."
    )
    files_received: list[str]
    files_sha256: dict[str, str] = Field(
        description="Each received file's SHA-256 (lowercase hex), by path: a client compares its own file "
        "with it before skipping one as already sent."
    )
    files_missing: list[str]
    created_at: datetime


class FileOut(BaseModel):
    """One stored file of a capture."""

    capture_id: int
    path: str
    sha256: str
    size_bytes: int
    created_at: datetime
