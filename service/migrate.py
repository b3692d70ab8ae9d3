"""Bringing a database to the newest schema with the Alembic migrations in ``migrations/``."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from alembic import command
from alembic.config import Config
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory
from sqlalchemy import Connection, text

import migrations
from service.database import Database

__all__ = ["current_revision", "is_current", "migration_connection", "upgrade"]

_MIGRATION_LOCK = 0x63616E6F7079
"""The PostgreSQL advisory lock key migrations hold (the bytes of "canopy")."""

_SQLITE_MIGRATION_WAIT_MS = 600_000
"""How long an upgrade on SQLite waits for another process's, milliseconds: the whole of it, a large
database's table copies included, where a write transaction's usual wait is seconds (PostgreSQL's advisory
lock waits as long as it takes)."""


def _config() -> Config:
    config = Config()
    config.set_main_option("script_location", str(Path(migrations.__file__).parent))
    return config


@contextmanager
def migration_connection(database: Database) -> Iterator[Connection]:
    """A connection to migrate ``database`` on, in one transaction that the block's migrations share.

    From reading the version the database is at to its last migration, the block is one transaction:
    Alembic, finding a transaction open, commits none of its own. So processes started together (APIs,
    several `canopy db upgrade`) take turns on it, on SQLite's write lock (``BEGIN IMMEDIATE``, waited for
    up to :data:`_SQLITE_MIGRATION_WAIT_MS`) or PostgreSQL's advisory lock, and the later ones find the
    database current; with a transaction per migration, one could read the version between another's
    migrations and apply one of them again. A migration that fails leaves the schema as it was.

    On SQLite, foreign keys are off while migrating: Alembic alters a table there by copying it and
    dropping the original, which with foreign keys on would cascade-delete every row that refers to it.
    They are checked before the commit instead, and a broken reference rolls the whole upgrade back.
    """
    with database.write_engine.connect() as connection:
        driver = connection.connection.driver_connection if database.is_sqlite else None
        if driver is not None:
            # Outside any transaction (the driver starts none on its own), where SQLite honours them.
            (usual_wait_ms,) = driver.execute("PRAGMA busy_timeout").fetchone()
            driver.execute("PRAGMA foreign_keys=OFF")
            driver.execute(f"PRAGMA busy_timeout={_SQLITE_MIGRATION_WAIT_MS}")
        try:
            with connection.begin():
                if driver is None:
                    # Released at the transaction's commit or rollback, also when a migration fails.
                    connection.execute(text("SELECT pg_advisory_xact_lock(:key)"), {"key": _MIGRATION_LOCK})
                yield connection
                if driver is not None:
                    broken = connection.exec_driver_sql("PRAGMA foreign_key_check").fetchall()
                    if broken:
                        raise RuntimeError(
                            f"the migration left rows whose references are broken: {broken[:5]}"
                        )
        finally:
            if driver is not None:  # the connection goes back to the pool as it came
                driver.execute("PRAGMA foreign_keys=ON")
                driver.execute(f"PRAGMA busy_timeout={usual_wait_ms}")


def upgrade(database: Database) -> None:
    """Apply every migration the database lacks (nothing when it is current), all in one transaction that
    processes upgrading at once take turns on (see :func:`migration_connection`)."""
    config = _config()
    with migration_connection(database) as connection:
        config.attributes["connection"] = connection
        command.upgrade(config, "head")


def current_revision(database: Database) -> str | None:
    """The migration the database is at (None: an empty database)."""
    with database.read_engine.connect() as connection:
        return MigrationContext.configure(connection).get_current_revision()


def is_current(database: Database) -> bool:
    """True when the database is at the newest migration."""
    return current_revision(database) == ScriptDirectory.from_config(_config()).get_current_head()
