"""A re-analysis keeps the detection configuration it was planned with

Revision ID: 0019
Revises: 0018
Create Date: 2026-11-24 23:40:00
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0019"
down_revision = "0018"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.add_column("reanalysis", sa.Column("config", sa.JSON(), nullable=True))


def downgrade() -> None:
    op.drop_column("reanalysis", "config")
