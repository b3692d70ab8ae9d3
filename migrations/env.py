"""Alembic environment: migrates the connection the caller passes, or the database the settings name."""

from __future__ import annotations

from alembic import context
from sqlalchemy import Connection

from service.database import Database
from service.migrate import migration_connection
from service.models import Base
from service.settings import load_settings


def _migrate(connection: Connection) -> None:
    context.configure(
        connection=connection,
        target_metadata=Base.metadata,
        # SQLite alters tables by copying them; batch mode does that for every ALTER.
        render_as_batch=connection.dialect.name == "sqlite",
        compare_type=True,
    )
    with context.begin_transaction():
        context.run_migrations()


connection = context.config.attributes.get("connection")
if connection is not None:
    _migrate(connection)
else:
    # Run by the `alembic` command (alembic.ini, for writing migrations): migrated as `canopy db upgrade`
    # does, so that no table copy cascades its references away.
    database = Database(context.config.get_main_option("sqlalchemy.url") or load_settings().sqlalchemy_url)
    with migration_connection(database) as own_connection:
        _migrate(own_connection)
    database.dispose()
