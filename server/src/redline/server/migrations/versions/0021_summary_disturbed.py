"""A summary says whether its phase was measured while the host was busy

Revision ID: 0021
Revises: 0020
Create Date: 2026-11-28 01:30:00

Summaries stored before it say False: which were disturbed is in their side tables only.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0021"
down_revision = "0020"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.add_column(
        "summary", sa.Column("disturbed", sa.Boolean(), nullable=False, server_default="false")
    )


def downgrade() -> None:
    op.drop_column("summary", "disturbed")
