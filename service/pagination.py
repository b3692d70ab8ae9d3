"""Cursor pagination of every list: ``{"items": [...], "next_cursor": "..." | null}``.

A cursor is opaque to clients: the base64 of the last item's id, so a page is stable while rows are added.
"""

from __future__ import annotations

import base64
import binascii
from typing import Annotated, Generic, TypeVar

from fastapi import Query
from pydantic import BaseModel
from sqlalchemy import Select
from sqlalchemy.orm import InstrumentedAttribute

from service.conventions import MAX_ID
from service.errors import BadRequest

__all__ = ["CursorQuery", "LimitQuery", "Page", "decode_cursor", "encode_cursor", "keyset", "page_of"]

CursorQuery = Annotated[str | None, Query(description="next_cursor of the previous page")]
LimitQuery = Annotated[int, Query(ge=1, le=1000, description="Items per page")]


Item = TypeVar("Item")
SelectT = TypeVar("SelectT", bound=Select)


class Page(BaseModel, Generic[Item]):
    """One page of a list; pass ``next_cursor`` as ``cursor=`` for the next (null on the last page)."""

    items: list[Item]
    next_cursor: str | None


def encode_cursor(last_id: int) -> str:
    """The cursor that continues after the item with ``last_id``."""
    return base64.urlsafe_b64encode(f"id:{last_id}".encode()).decode().rstrip("=")


def decode_cursor(cursor: str | None) -> int | None:
    """The id a cursor continues after; None for the first page; a 400 problem for a cursor not ours."""
    if cursor is None:
        return None
    try:
        text = base64.urlsafe_b64decode(cursor + "=" * (-len(cursor) % 4)).decode()
        kind, _, value = text.partition(":")
        if kind != "id" or not value.isdigit() or int(value) > MAX_ID:
            raise ValueError(text)
        return int(value)
    except (ValueError, binascii.Error, UnicodeDecodeError) as exc:
        raise BadRequest(
            "cursor is not one this service gave out; pass next_cursor unchanged",
            code="invalid_cursor",
            field="cursor",
        ) from exc


def keyset(
    query: SelectT,
    key: InstrumentedAttribute[int],
    cursor: str | None,
    limit: int,
    *,
    newest_first: bool = False,
) -> SelectT:
    """``query`` ordered by ``key``, continued after ``cursor``, with one row more than ``limit`` (to tell
    whether another page follows)."""
    position = decode_cursor(cursor)
    if position is not None:
        query = query.where(key < position if newest_first else key > position)
    return query.order_by(key.desc() if newest_first else key).limit(limit + 1)


def page_of(items: list[Item], ids: list[int], limit: int) -> Page[Item]:
    """A page from up to ``limit + 1`` fetched items (the extra one only tells that more follow)."""
    more = len(items) > limit
    return Page[Item](items=items[:limit], next_cursor=encode_cursor(ids[limit - 1]) if more else None)
