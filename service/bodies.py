"""Reading request bodies within their limits: small JSON documents whole, files streamed to disk.

A body is refused (413) beyond its limit before it fills memory or disk: from its Content-Length when it
declares one, else as soon as more has arrived than the limit. A body that stops arriving (a laptop gone
out of Wi-Fi range mid-upload leaves its connection open for minutes) is given up after ``idle_timeout_s``
without a byte (408), so it does not hold its upload slot.
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator

from fastapi import Request

from service.errors import BadRequest, PayloadTooLarge, RequestTimeout
from service.storage import IncomingBlob

__all__ = ["declared_length", "read_body", "receive_body"]


def declared_length(request: Request, *, limit_bytes: int, what: str) -> int | None:
    """The body's Content-Length, None when it declares none; 400 when it is not a number, 413 when it is
    over ``limit_bytes`` (``what`` names the body in the error)."""
    declared = request.headers.get("content-length")
    if declared is None:
        return None
    if not declared.isdigit():
        raise BadRequest(f"Content-Length {declared!r} is not a number", field="Content-Length")
    if int(declared) > limit_bytes:
        raise _too_large(what, limit_bytes, int(declared))
    return int(declared)


async def _chunks(request: Request, *, idle_timeout_s: float, what: str) -> AsyncIterator[bytes]:
    """The body's chunks as they arrive; 408 when none comes for ``idle_timeout_s``."""
    stream = request.stream()
    while True:
        try:
            chunk = await asyncio.wait_for(anext(stream), timeout=idle_timeout_s)
        except StopAsyncIteration:
            return
        except TimeoutError:
            raise RequestTimeout(
                f"{what}: no byte of the body arrived for {idle_timeout_s:g} s; the upload was given up, "
                "send it again",
                file=what,
            ) from None
        yield chunk


async def read_body(request: Request, *, limit_bytes: int, idle_timeout_s: float, what: str) -> bytes:
    """The whole body, at most ``limit_bytes`` long: for JSON documents, which are parsed whole."""
    declared_length(request, limit_bytes=limit_bytes, what=what)
    chunks, size = [], 0
    async for chunk in _chunks(request, idle_timeout_s=idle_timeout_s, what=what):
        size += len(chunk)
        if size > limit_bytes:
            raise _too_large(what, limit_bytes)
        chunks.append(chunk)
    return b"".join(chunks)


async def receive_body(
    request: Request, into: IncomingBlob, *, limit_bytes: int, idle_timeout_s: float, what: str
) -> None:
    """Stream the body into ``into`` as it arrives (hashing it on the way), at most ``limit_bytes``: only
    one network chunk of it is ever in memory."""
    declared_length(request, limit_bytes=limit_bytes, what=what)
    async for chunk in _chunks(request, idle_timeout_s=idle_timeout_s, what=what):
        if into.size_bytes + len(chunk) > limit_bytes:
            raise _too_large(what, limit_bytes)
        into.write(chunk)


def _too_large(what: str, limit_bytes: int, size_bytes: int | None = None) -> PayloadTooLarge:
    detail = (
        f"{what} is over the limit of {limit_bytes} bytes"
        if size_bytes is None
        else f"{what} is {size_bytes} bytes; the limit is {limit_bytes} bytes"
    )
    return PayloadTooLarge(detail, file=what, limit_bytes=limit_bytes)
