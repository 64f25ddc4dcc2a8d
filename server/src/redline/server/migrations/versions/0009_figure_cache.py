"""figure_cache: trend charts rendered per component and view, valid for one data version

Revision ID: 0009
Revises: 0008
Create Date: 2026-11-23 08:20:00
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0009"
down_revision = "0008"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "figure_cache",
        sa.Column("id", sa.Integer(), primary_key=True),
        sa.Column("component_id", sa.Integer(), sa.ForeignKey("component.id"), nullable=False),
        sa.Column("view", sa.Text(), nullable=False),
        sa.Column("version", sa.Text(), nullable=False),
        sa.Column("figures", sa.Text(), nullable=False),
        sa.Column("earlier", sa.Text(), nullable=True),
        sa.Column("created", sa.DateTime(timezone=True), nullable=False),
        sa.UniqueConstraint("component_id", "view"),
    )
    op.create_index("ix_figure_cache_component_id", "figure_cache", ["component_id"])


def downgrade() -> None:
    op.drop_index("ix_figure_cache_component_id", "figure_cache")
    op.drop_table("figure_cache")
