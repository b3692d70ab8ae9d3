"""Conventions every route follows: ids are positive 64-bit integers, unknown query parameters are refused,
and every GET that answers a body carries an ETag and answers ``If-None-Match`` with 304.

A dashboard polls lists every few seconds and a farm system re-reads a row's CSV each night: with an ETag
they get 304 and no body while nothing changed. A misspelt filter (``?stat=failed``) that was silently
ignored would answer every job as if it were the filtered list, so it is refused naming the parameter.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterator
from datetime import UTC, datetime
from typing import Annotated

from fastapi import Path, Query, Request, Response
from fastapi.dependencies.models import Dependant
from fastapi.routing import APIRoute
from pydantic import AfterValidator, AwareDatetime
from starlette.datastructures import MutableHeaders
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.errors import BadRequest

__all__ = [
    "MAX_ID",
    "ConditionalGet",
    "ItemId",
    "SinceQuery",
    "reject_unknown_query",
    "strong_etag",
    "unchanged",
]

MAX_ID = 2**63 - 1
"""The largest id: the databases' 64-bit signed integer. A larger one names nothing, and must be refused
before it reaches the database, whose driver cannot even send it."""

ItemId = Annotated[int, Path(ge=1, le=MAX_ID, description="The item's id, as the service gave it out")]


def strong_etag(digest_hex: str) -> str:
    """The ETag header value for content known by its hex digest."""
    return f'"{digest_hex}"'


def unchanged(request: Request, etag: str) -> Response | None:
    """A 304 for a request whose If-None-Match names ``etag``, else None: a route whose body is large or
    streamed (a cloud, the CSV) asks this before it reads or queries anything for the body."""
    if_none_match = request.headers.get("if-none-match")
    if if_none_match is None or not _matches(if_none_match, etag):
        return None
    return Response(status_code=304, headers={"ETag": etag, "Cache-Control": "no-cache"})


def _utc(moment: datetime) -> datetime:
    try:
        return moment.astimezone(UTC)
    except OverflowError as exc:
        raise ValueError("the time is out of range once in UTC") from exc


SinceQuery = Annotated[
    AwareDatetime | None,
    AfterValidator(lambda moment: None if moment is None else _utc(moment)),
    Query(description="At or after this time (RFC 3339 with a time zone)"),
]


def _query_names(dependant: Dependant) -> Iterator[str]:
    """The query parameter names a route takes, its dependencies' included."""
    for param in dependant.query_params:
        yield param.alias
    for dependency in dependant.dependencies:
        yield from _query_names(dependency)


def reject_unknown_query(request: Request) -> None:
    """A 400 problem naming every query parameter the route does not take (an app-wide dependency)."""
    route = request.scope.get("route")
    if not isinstance(route, APIRoute):
        return
    known = set(_query_names(route.dependant))
    unknown = sorted(set(request.query_params) - known)
    if unknown:
        takes = ", ".join(sorted(known)) or "none"
        raise BadRequest(
            f"unknown query parameter(s) {', '.join(unknown)}; {route.path} takes: {takes}",
            code="unknown_parameter",
            field=unknown[0],
            unknown=unknown,
        )


def _matches(if_none_match: str, etag: str) -> bool:
    """Whether an If-None-Match header names ``etag`` (or ``*``); weak tags compare by their value."""
    tags = {tag.strip().removeprefix("W/") for tag in if_none_match.split(",")}
    return "*" in tags or etag.removeprefix("W/") in tags


class ConditionalGet:
    """ASGI middleware: ETag and 304 for every successful GET.

    A response that brings its own ETag (a file known by its SHA-256, the CSV by its rows) keeps it; a
    JSON body without one gets the SHA-256 of its bytes. When the request's ``If-None-Match`` names the
    ETag, the answer is 304 with the ETag and no body. Other responses pass unchanged.
    """

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["method"] != "GET":
            await self.app(scope, receive, send)
            return
        if_none_match = next(
            (value.decode("latin-1") for name, value in scope["headers"] if name == b"if-none-match"), None
        )
        start: Message | None = None
        mode = "pass"
        chunks: list[bytes] = []

        async def conditional_send(message: Message) -> None:
            nonlocal start, mode
            if message["type"] == "http.response.start":
                headers = MutableHeaders(scope=message)
                if message["status"] != 200:
                    await send(message)
                elif "etag" in headers:
                    if if_none_match is not None and _matches(if_none_match, headers["etag"]):
                        mode = "unchanged"
                        await send(_not_modified(headers))
                    else:
                        await send(message)
                elif headers.get("content-type", "").startswith("application/json"):
                    mode, start = "buffer", message
                else:
                    await send(message)
                return
            if mode == "pass":
                await send(message)
            elif mode == "buffer":
                chunks.append(message.get("body", b""))
                if not message.get("more_body", False):
                    await _send_buffered(send, start, b"".join(chunks), if_none_match)
            elif not message.get("more_body", False):  # "unchanged": the 304 went out; the body is dropped
                await send({"type": "http.response.body", "body": b""})

        await self.app(scope, receive, conditional_send)


def _not_modified(headers: MutableHeaders) -> Message:
    """The start of a 304 answer carrying the validators of the response it replaces, and no body."""
    kept = [(name, value) for name, value in headers.raw if name in {b"etag", b"cache-control", b"vary"}]
    return {"type": "http.response.start", "status": 304, "headers": kept}


async def _send_buffered(send: Send, start: Message | None, body: bytes, if_none_match: str | None) -> None:
    """Send a buffered JSON body with its content's ETag, or 304 when the client holds it."""
    assert start is not None
    headers = MutableHeaders(scope=start)
    headers["etag"] = strong_etag(hashlib.sha256(body).hexdigest())
    headers.setdefault("cache-control", "no-cache")
    if if_none_match is not None and _matches(if_none_match, headers["etag"]):
        await send(_not_modified(headers))
        await send({"type": "http.response.body", "body": b""})
        return
    await send(start)
    await send({"type": "http.response.body", "body": body})
