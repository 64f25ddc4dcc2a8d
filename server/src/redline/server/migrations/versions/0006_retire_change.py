"""change: retired; KS's decided verdicts are read from detection (they were written twice)

Revision ID: 0006
Revises: 0005
Create Date: 2026-11-23 05:00:00
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0006"
down_revision = "0005"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.drop_table("change")


def downgrade() -> None:
    op.create_table(
        "change",
        sa.Column("id", sa.Integer(), primary_key=True),
        sa.Column(
            "series_id", sa.Integer(), sa.ForeignKey("series.id"), nullable=False, index=True
        ),
        sa.Column(
            "revision_id", sa.Integer(), sa.ForeignKey("revision.id"), nullable=False, index=True
        ),
        sa.Column(
            "baseline_revision_id", sa.Integer(), sa.ForeignKey("revision.id"), nullable=False
        ),
        sa.Column("method", sa.String(50), nullable=False),
        sa.Column("score", sa.Float(), nullable=False),
        sa.Column("p_value", sa.Float(), nullable=False),
        sa.Column("effect", sa.Float(), nullable=False),
        sa.Column("flagged", sa.Boolean(), nullable=False),
        sa.Column("created", sa.DateTime(timezone=True), nullable=False),
        sa.UniqueConstraint("series_id", "revision_id", "method"),
    )
