"""HTTP routes of API keys: create, list, revoke (admin scope); the key in use (any key)."""

from __future__ import annotations

from datetime import timedelta

from fastapi import APIRouter

from canopy_core import __version__
from service.deps import AdminKey, AnyKey, ContextDep
from service.errors import Conflict, NotFound
from service.keys.schemas import KeyCreate, KeyCreated, KeyCurrent, KeyOut
from service.keys.service import create_key, list_keys, revoke_key
from service.models import ApiKey
from service.problems import problem_responses

__all__ = ["key_out", "router"]

router = APIRouter(prefix="/v1/keys", tags=["keys"])


def key_out(record: ApiKey) -> KeyOut:
    """A key record as the API and the CLI show it."""
    return KeyOut(
        id=record.id,
        name=record.name,
        prefix=record.prefix,
        scopes=record.scopes.split(),
        created_at=record.created_at,
        revoked_at=record.revoked_at,
        expires_at=record.expires_at,
    )


@router.post("", response_model=KeyCreated, status_code=201)
def create(body: KeyCreate, context: ContextDep, _key: AdminKey) -> KeyCreated:
    """Create a key; the answer holds the key, shown this once."""
    with context.database.writing() as session:
        lifetime = None if body.expires_in_s is None else timedelta(seconds=body.expires_in_s)
        new = create_key(session, name=body.name, scopes=body.scopes, expires_in=lifetime)
        return KeyCreated(**key_out(new.record).model_dump(), key=new.key)


@router.get("", response_model=list[KeyOut])
def index(context: ContextDep, _key: AdminKey) -> list[KeyOut]:
    """Every key, revoked ones included."""
    with context.database.reading() as session:
        return [key_out(record) for record in list_keys(session)]


@router.get("/current", response_model=KeyCurrent)
def current(key: AnyKey) -> KeyCurrent:
    """The key this request was sent with (never the key itself) and the service's version."""
    return KeyCurrent(version=__version__, key=key_out(key))


@router.delete("/{prefix}", response_model=KeyOut, responses=problem_responses(NotFound, Conflict))
def revoke(prefix: str, context: ContextDep, _key: AdminKey) -> KeyOut:
    """Revoke a key by its prefix; it stops working at once."""
    with context.database.writing() as session:
        record = revoke_key(session, prefix=prefix)
        if record is None:
            raise NotFound(f"no API key with prefix {prefix!r}", field="prefix")
        return key_out(record)
