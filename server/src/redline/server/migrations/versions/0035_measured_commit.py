"""revision.measured_commit: the hash of the commit a revision's first uploaded run checked out

Revision ID: 0035
Revises: 0034
Create Date: 2026-12-07 19:30:00

An admin may report a revision by a branch or tag name. Its confirmation pairs, queued later,
checked that name out again and measured whatever commit the branch had moved to by then,
judged as the revision. The first run a host uploads now records the hash it checked out, and
every later run of the revision checks out that hash. Empty: measured before this column (or
not yet), its name is checked out as before.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0035"
down_revision = "0034"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.add_column(
        "revision",
        sa.Column("measured_commit", sa.String(64), nullable=False, server_default=""),
    )


def downgrade() -> None:
    op.drop_column("revision", "measured_commit")
