"""What the keys endpoints take and answer."""

from __future__ import annotations

from datetime import datetime
from typing import Literal

from pydantic import BaseModel, Field

__all__ = ["KeyCreate", "KeyCreated", "KeyCurrent", "KeyOut", "SessionOut"]

Scope = Literal["capture", "read", "admin"]


class KeyCreate(BaseModel):
    """A key to create: a name for people, and its scopes."""

    name: str = Field(min_length=1, max_length=200)
    scopes: list[Scope] = Field(min_length=1)
    expires_in_s: int | None = Field(
        None, gt=0, le=100 * 366 * 86400, description="Seconds until the key is refused; none: never."
    )


class KeyOut(BaseModel):
    """A key as listed: never the key itself, which only its creator saw once."""

    id: int
    name: str
    prefix: str
    scopes: list[str]
    created_at: datetime
    revoked_at: datetime | None
    expires_at: datetime | None


class KeyCreated(KeyOut):
    """A key just created, with the key: store it now, it cannot be shown again."""

    key: str


class KeyCurrent(BaseModel):
    """The key a request was sent with, and the service that took it: what a client checks before it
    starts (that the address is a Canopy service, and that its key may do what it is about to do)."""

    service: Literal["canopy"] = "canopy"
    version: str
    key: KeyOut


class SessionOut(BaseModel):
    """A browser signed in: the key it reads with (never the key itself) and when the session ends."""

    key: KeyOut
    expires_at: datetime
