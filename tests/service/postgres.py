"""The PostgreSQL the scale path's tests run on: a schema of its own per test, in the server
``CANOPY_TEST_POSTGRES_URL`` names (default: the local one on 127.0.0.1:5432, database ``test``).

`./dev.sh test` installs and starts Debian's PostgreSQL when nothing answers there and sets the URL; when
none can be had, these tests are skipped, each saying why.
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Iterator
from contextlib import contextmanager

import pytest
from sqlalchemy import create_engine, text
from sqlalchemy.exc import OperationalError

POSTGRES_URL = os.environ.get("CANOPY_TEST_POSTGRES_URL", "postgresql+psycopg://postgres@127.0.0.1:5432/test")

BACKENDS = ["sqlite", "postgresql"]
"""The databases the queue, worker and end-to-end tests run on: the embedded default and the scale path."""


@contextmanager
def postgres_schema() -> Iterator[str]:
    """The URL of a new, empty schema in the test server (dropped afterwards): every connection made with
    the URL sees that schema alone, so tests running at once never meet."""
    schema = f"canopy_{uuid.uuid4().hex[:12]}"
    admin = create_engine(POSTGRES_URL)
    try:
        with admin.begin() as connection:
            connection.execute(text(f'CREATE SCHEMA "{schema}"'))
    except OperationalError as exc:
        admin.dispose()
        pytest.skip(f"SKIPPED LOUDLY: no PostgreSQL at {POSTGRES_URL} for the scale path's tests: {exc}")
    try:
        yield f"{POSTGRES_URL}?options=-csearch_path%3D{schema}"
    finally:
        with admin.begin() as connection:
            connection.execute(text(f'DROP SCHEMA "{schema}" CASCADE'))
        admin.dispose()


@contextmanager
def database_url(backend: str) -> Iterator[str | None]:
    """The database URL a service under test runs on: None for its own SQLite file, or a PostgreSQL
    schema of its own."""
    if backend == "sqlite":
        yield None
        return
    with postgres_schema() as url:
        yield url
