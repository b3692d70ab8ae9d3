"""measurements taken by hand, to validate the service's against; each measurement's report figures

Revision ID: 0003
Revises: 0002
Create Date: 2026-11-25
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0003"
down_revision = "0002"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "manual_measurements",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("orchard", sa.String(length=200), nullable=False),
        sa.Column("row", sa.String(length=200), nullable=False),
        sa.Column("tree", sa.String(length=200), nullable=False),
        sa.Column("measured_on", sa.Date(), nullable=False),
        sa.Column("height_m", sa.Double(), nullable=True),
        sa.Column("width_m", sa.Double(), nullable=True),
        sa.Column("thickness_m", sa.Double(), nullable=True),
        sa.Column("updated_at", sa.DateTime(), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_manual_measurements")),
        sa.UniqueConstraint(
            "orchard",
            "row",
            "tree",
            "measured_on",
            name=op.f("uq_manual_measurements_orchard_row_tree_measured_on"),
        ),
        sqlite_autoincrement=True,
    )
    op.add_column("measurements", sa.Column("figures", sa.JSON(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("measurements", table_kwargs={"sqlite_autoincrement": True}) as batch:
        batch.drop_column("figures")
    op.drop_table("manual_measurements")
