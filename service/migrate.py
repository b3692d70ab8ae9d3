"""Bringing a database to the newest schema with the Alembic migrations in ``migrations/``."""

from __future__ import annotations

from pathlib import Path

from alembic import command
from alembic.config import Config
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory
from sqlalchemy import text

import migrations
from service.database import Database

__all__ = ["current_revision", "is_current", "upgrade"]

_MIGRATION_LOCK = 0x63616E6F7079
"""The PostgreSQL advisory lock key migrations hold (the bytes of "canopy")."""


def _config() -> Config:
    config = Config()
    config.set_main_option("script_location", str(Path(migrations.__file__).parent))
    return config


def upgrade(database: Database) -> None:
    """Apply every migration the database lacks (nothing when it is current).

    The whole upgrade is one transaction, from reading the version the database is at to its last
    migration: Alembic, finding a transaction open, commits none of its own. So processes started together
    (an API and its workers, several `canopy db upgrade`) take turns on it, on SQLite's write lock
    (``BEGIN IMMEDIATE``) or PostgreSQL's advisory lock, and the later ones find the database current;
    with a transaction per migration, one could read the version between another's migrations and apply
    them again. A migration that fails leaves the schema as it was.

    On SQLite, foreign keys are off while migrating: Alembic alters a table there by copying it and
    dropping the original, which with foreign keys on would cascade-delete every row that refers to it.
    They are checked afterwards instead.
    """
    config = _config()
    with database.write_engine.connect() as connection:
        if database.is_sqlite:
            # Outside any transaction (the driver starts none on its own), where SQLite honours it.
            connection.connection.driver_connection.execute("PRAGMA foreign_keys=OFF")  # type: ignore[union-attr]
        with connection.begin():
            if not database.is_sqlite:
                # Released at the transaction's commit or rollback, also when a migration fails.
                connection.execute(text("SELECT pg_advisory_xact_lock(:key)"), {"key": _MIGRATION_LOCK})
            config.attributes["connection"] = connection
            command.upgrade(config, "head")
        if database.is_sqlite:
            broken = connection.exec_driver_sql("PRAGMA foreign_key_check").fetchall()
            connection.rollback()
            connection.connection.driver_connection.execute("PRAGMA foreign_keys=ON")  # type: ignore[union-attr]
            if broken:
                raise RuntimeError(f"the migration left rows whose references are broken: {broken[:5]}")


def current_revision(database: Database) -> str | None:
    """The migration the database is at (None: an empty database)."""
    with database.read_engine.connect() as connection:
        return MigrationContext.configure(connection).get_current_revision()


def is_current(database: Database) -> bool:
    """True when the database is at the newest migration."""
    return current_revision(database) == ScriptDirectory.from_config(_config()).get_current_head()
