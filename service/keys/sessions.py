"""Browser sessions: a key entered once in the dashboard becomes an HttpOnly cookie holding a random token,
stored only as its SHA-256, that grants what the key grants, for reading, until it expires or the key
stops working."""

from __future__ import annotations

import hashlib
import secrets
from datetime import datetime, timedelta

from sqlalchemy import delete, select
from sqlalchemy.orm import Session

from service.errors import Unauthorized
from service.keys.service import usable
from service.models import ApiKey, BrowserSession, utc_now

__all__ = ["SESSION_COOKIE", "close_session", "open_session", "session_key"]

SESSION_COOKIE = "canopy_session"


def open_session(session: Session, key: ApiKey, *, ttl: timedelta) -> tuple[str, datetime]:
    """A new session of ``key``: its token (for the cookie, never stored) and when it expires. Expired
    sessions are removed on the way."""
    now = utc_now()
    session.execute(delete(BrowserSession).where(BrowserSession.expires_at <= now))
    token = secrets.token_urlsafe(32)
    expires_at = now + ttl
    session.add(BrowserSession(token_sha256=_digest(token), key_id=key.id, expires_at=expires_at))
    return token, expires_at


def session_key(session: Session, token: str) -> ApiKey:
    """The key a session cookie stands for; a 401 problem when the session is unknown or expired, or its
    key revoked or expired."""
    found = session.execute(
        select(BrowserSession, ApiKey)
        .join(ApiKey, ApiKey.id == BrowserSession.key_id)
        .where(BrowserSession.token_sha256 == _digest(token))
    ).one_or_none()
    if found is None:
        raise Unauthorized("the browser session is unknown or signed out; sign in again with an API key")
    browser, key = found
    if browser.expires_at <= utc_now():
        raise Unauthorized("the browser session has expired; sign in again with an API key")
    return usable(key)


def close_session(session: Session, token: str) -> None:
    """Forget a session (signing out); nothing happens for an unknown token."""
    session.execute(delete(BrowserSession).where(BrowserSession.token_sha256 == _digest(token)))


def _digest(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()
