"""The dashboard at ``/``: one page (``static/dashboard.html`` and ``dashboard.js``) that signs a browser in
with an API key and follows jobs, orchards, rows and trees through the API."""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import FileResponse

from service.app_files import STATIC_DIR

__all__ = ["router"]

router = APIRouter(tags=["dashboard"])


@router.get("/", response_class=FileResponse, include_in_schema=False)
def dashboard() -> FileResponse:
    """The dashboard page; it asks for a key itself (nothing on it is data before the browser signs in)."""
    return FileResponse(
        STATIC_DIR / "dashboard.html", media_type="text/html", headers={"Cache-Control": "no-cache"}
    )
