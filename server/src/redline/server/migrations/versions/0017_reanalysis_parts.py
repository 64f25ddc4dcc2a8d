"""A re-analysis split by series across workers: its plan and progress, and each part's verdicts
staged until they are stored in revision order

Revision ID: 0017
Revises: 0016
Create Date: 2026-11-24 20:40:00
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0017"
down_revision = "0016"
branch_labels = None
depends_on = None


def upgrade() -> None:
    for column in (
        sa.Column("run", sa.Integer(), nullable=False, server_default="0"),
        sa.Column("parts", sa.Integer(), nullable=False, server_default="1"),
        sa.Column("revisions", sa.JSON(), nullable=False, server_default="[]"),
        sa.Column("parts_done", sa.JSON(), nullable=False, server_default="[]"),
        sa.Column("stored", sa.Integer(), nullable=False, server_default="0"),
        sa.Column("from_database", sa.Boolean(), nullable=False, server_default="false"),
    ):
        op.add_column("reanalysis", column)
    op.create_table(
        "staged_detection",
        sa.Column("id", sa.Integer(), primary_key=True),
        sa.Column(
            "component_id",
            sa.Integer(),
            sa.ForeignKey("component.id", ondelete="CASCADE"),
            nullable=False,
        ),
        sa.Column("run", sa.Integer(), nullable=False),
        sa.Column("part", sa.Integer(), nullable=False),
        sa.Column("series_id", sa.Integer(), nullable=False),
        sa.Column("revision_id", sa.Integer(), nullable=False),
        sa.Column("baseline_revision_id", sa.Integer(), nullable=True),
        sa.Column("baseline_revisions", sa.Integer(), nullable=False),
        sa.Column("method", sa.String(50), nullable=False),
        sa.Column("verdict", sa.String(20), nullable=False),
        sa.Column("reason", sa.Text(), nullable=False),
        sa.Column("score", sa.Float(), nullable=False),
        sa.Column("p_value", sa.Float(), nullable=True),
        sa.Column("effect", sa.Float(), nullable=True),
        sa.Column("direction", sa.String(10), nullable=False),
        sa.Column("flagged", sa.Boolean(), nullable=False),
        sa.Column("confirmation", sa.String(20), nullable=False),
        sa.Column("confirmation_reason", sa.Text(), nullable=False),
        sa.Column("created", sa.DateTime(timezone=True), nullable=False),
    )
    op.create_index(
        "ix_staged_detection_revision", "staged_detection", ["component_id", "run", "revision_id"]
    )
    op.create_table(
        "staged_revision",
        sa.Column(
            "component_id",
            sa.Integer(),
            sa.ForeignKey("component.id", ondelete="CASCADE"),
            primary_key=True,
        ),
        sa.Column("run", sa.Integer(), primary_key=True),
        sa.Column("revision_id", sa.Integer(), primary_key=True),
        sa.Column("part", sa.Integer(), primary_key=True),
        sa.Column("executions", sa.Text(), nullable=False),
    )


def downgrade() -> None:
    op.drop_table("staged_revision")
    op.drop_index("ix_staged_detection_revision", table_name="staged_detection")
    op.drop_table("staged_detection")
    for name in ("from_database", "stored", "parts_done", "revisions", "parts", "run"):
        op.drop_column("reanalysis", name)
