"""Reading a request body whole, refusing it (413) beyond a limit before it fills memory."""

from __future__ import annotations

from fastapi import Request

from service.problems import BadRequest, PayloadTooLarge

__all__ = ["read_body"]


async def read_body(request: Request, *, limit_bytes: int, what: str) -> bytes:
    """The request body, at most ``limit_bytes`` long; ``what`` names it in the error."""
    declared = request.headers.get("content-length")
    if declared is not None:
        if not declared.isdigit():
            raise BadRequest(f"Content-Length {declared!r} is not a number", field="Content-Length")
        if int(declared) > limit_bytes:
            raise PayloadTooLarge(
                f"{what} is {int(declared)} bytes; the limit is {limit_bytes} bytes",
                file=what,
                limit_bytes=limit_bytes,
            )
    chunks, size = [], 0
    async for chunk in request.stream():
        size += len(chunk)
        if size > limit_bytes:
            raise PayloadTooLarge(
                f"{what} is over the limit of {limit_bytes} bytes", file=what, limit_bytes=limit_bytes
            )
        chunks.append(chunk)
    return b"".join(chunks)
