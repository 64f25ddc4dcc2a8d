"""job.cases: the test cases a job runs (a confirmation run: those with a suspected change)

Revision ID: 0011
Revises: 0010
Create Date: 2026-11-23 08:50:00
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0011"
down_revision = "0010"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.add_column("job", sa.Column("cases", sa.JSON(), nullable=False, server_default="[]"))
    op.alter_column("job", "cases", server_default=None)


def downgrade() -> None:
    op.drop_column("job", "cases")
