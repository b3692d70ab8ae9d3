"""Creating, listing, revoking and checking API keys.

A key reads ``canopy_<prefix>_<secret>``: the prefix (8 hex digits) names the key in lists and logs, the
secret is 256 random bits. Only the SHA-256 of the whole key is stored; a fast hash suffices because the
key is random, not a password someone chose.
"""

from __future__ import annotations

import hashlib
import re
import secrets
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import timedelta

from sqlalchemy import select
from sqlalchemy.orm import Session

from service.errors import Conflict, Unauthorized
from service.models import ApiKey, utc_now, utc_text

__all__ = [
    "SCOPES",
    "NewKey",
    "authenticate",
    "create_key",
    "grants",
    "list_keys",
    "parse_lifetime",
    "revoke_key",
    "usable",
]

SCOPES = ("capture", "read", "admin")
"""``capture``: create captures, upload files, start jobs. ``read``: every GET. ``admin``: everything."""


_LIFETIME_UNITS = {"d": "days", "h": "hours", "m": "minutes"}


@dataclass(frozen=True)
class NewKey:
    """A key just created: the record and the key itself, which is shown this once and never again."""

    record: ApiKey
    key: str


def _digest(key: str) -> str:
    return hashlib.sha256(key.encode()).hexdigest()


def create_key(
    session: Session, *, name: str, scopes: Sequence[str], expires_in: timedelta | None = None
) -> NewKey:
    """Create a key with the given scopes (each one of :data:`SCOPES`), refused after ``expires_in``
    (never, when None)."""
    unknown = sorted(set(scopes) - set(SCOPES))
    if unknown or not scopes:
        raise ValueError(f"scopes must be among {', '.join(SCOPES)}; got {', '.join(scopes) or 'none'}")
    if expires_in is not None and expires_in <= timedelta(0):
        raise ValueError(f"a key must live a while: expires_in {expires_in} is not after now")
    prefix = secrets.token_hex(4)
    key = f"canopy_{prefix}_{secrets.token_urlsafe(32)}"
    record = ApiKey(
        name=name,
        prefix=prefix,
        key_sha256=_digest(key),
        scopes=" ".join(sorted(set(scopes), key=SCOPES.index)),
        expires_at=None if expires_in is None else utc_now() + expires_in,
    )
    session.add(record)
    session.flush()
    return NewKey(record=record, key=key)


def list_keys(session: Session) -> list[ApiKey]:
    """Every key, revoked ones included, oldest first."""
    return list(session.scalars(select(ApiKey).order_by(ApiKey.id)))


def revoke_key(session: Session, *, prefix: str) -> ApiKey | None:
    """Revoke the key with this prefix; None when there is none. Revoking twice keeps the first time.

    The last live admin key is not revoked (a 409 problem): without one nobody could make or revoke keys
    over the API, and every user would wait for someone to run ``canopy keys create`` on the host.
    """
    record = session.scalar(select(ApiKey).where(ApiKey.prefix == prefix))
    if record is None or record.revoked_at is not None:
        return record
    if "admin" in record.scopes.split():
        live_admins = session.scalars(select(ApiKey).where(ApiKey.revoked_at.is_(None))).all()
        if sum("admin" in key.scopes.split() for key in live_admins) == 1:
            raise Conflict(
                f"key {prefix} is the last admin key; create another admin key before revoking it",
                code="last_admin_key",
                field="prefix",
            )
    record.revoked_at = utc_now()
    return record


def authenticate(session: Session, key: str) -> ApiKey:
    """The key record matching ``key``; a 401 problem saying why when it is unknown, revoked or expired."""
    record = session.scalar(select(ApiKey).where(ApiKey.key_sha256 == _digest(key)))
    if record is None:
        raise Unauthorized("the API key is unknown")
    return usable(record)


def usable(record: ApiKey) -> ApiKey:
    """``record`` itself while it works; a 401 problem saying why when it is revoked or expired."""
    if record.revoked_at is not None:
        raise Unauthorized(f"API key {record.prefix} was revoked at {utc_text(record.revoked_at)}")
    if record.expires_at is not None and record.expires_at <= utc_now():
        raise Unauthorized(
            f"API key {record.prefix} expired at {utc_text(record.expires_at)}; ask an admin for a new one"
        )
    return record


def parse_lifetime(text: str) -> timedelta:
    """A key's lifetime as written on the command line: a number and a unit, ``90d``, ``12h``, ``30m``."""
    match = re.fullmatch(r"\s*(\d+)\s*([dhm])\s*", text)
    if match is None or int(match.group(1)) == 0:
        raise ValueError(f"{text!r} is not a lifetime such as 90d, 12h or 30m (days, hours, minutes)")
    return timedelta(**{_LIFETIME_UNITS[match.group(2)]: int(match.group(1))})


def grants(record: ApiKey, scope: str) -> bool:
    """True when the key may act in ``scope``; ``admin`` may do everything."""
    held = record.scopes.split()
    return scope in held or "admin" in held
