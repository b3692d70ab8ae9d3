"""captures remember the key that created them; keys may expire

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-25
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import sqlalchemy as sa
from alembic import op
from alembic.operations import BatchOperations

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None


@contextmanager
def _altered(table: str) -> Iterator[BatchOperations]:
    """Alter ``table``; on SQLite, where that copies the table, keep AUTOINCREMENT and the highest id ever
    given (ids are never reused, not even those of deleted rows)."""
    sqlite = op.get_bind().dialect.name == "sqlite"
    highest = (
        op.get_bind().scalar(sa.text("SELECT seq FROM sqlite_sequence WHERE name = :table"), {"table": table})
        if sqlite
        else None
    )
    with op.batch_alter_table(table, table_kwargs={"sqlite_autoincrement": True}) as batch:
        yield batch
    if highest is not None:
        op.get_bind().execute(
            sa.text("UPDATE sqlite_sequence SET seq = max(seq, :highest) WHERE name = :table"),
            {"highest": highest, "table": table},
        )


def upgrade() -> None:
    with _altered("captures") as batch:
        batch.add_column(sa.Column("created_by_key_id", sa.Integer(), nullable=True))
        batch.create_foreign_key(
            op.f("fk_captures_created_by_key_id_api_keys"), "api_keys", ["created_by_key_id"], ["id"]
        )
    with _altered("api_keys") as batch:
        batch.add_column(sa.Column("expires_at", sa.DateTime(), nullable=True))


def downgrade() -> None:
    with _altered("api_keys") as batch:
        batch.drop_column("expires_at")
    with _altered("captures") as batch:
        batch.drop_constraint(op.f("fk_captures_created_by_key_id_api_keys"), type_="foreignkey")
        batch.drop_column("created_by_key_id")
