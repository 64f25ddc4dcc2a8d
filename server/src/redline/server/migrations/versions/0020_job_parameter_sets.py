"""A confirmation run names the parameter sets it runs again, not only the test cases

Revision ID: 0020
Revises: 0019
Create Date: 2026-11-27 15:50:00
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0020"
down_revision = "0019"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.add_column(
        "job", sa.Column("parameter_sets", sa.JSON(), nullable=False, server_default="{}")
    )
    op.alter_column("job", "parameter_sets", server_default=None)


def downgrade() -> None:
    op.drop_column("job", "parameter_sets")
