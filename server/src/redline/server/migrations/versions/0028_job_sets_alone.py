"""A confirmation run may run its flagged parameter sets alone

Revision ID: 0028
Revises: 0027
Create Date: 2026-12-05 22:30:00

A confirmation run of a change in what a component does per unit of work (CPU, a round trip)
runs the flagged parameter sets only (``job.sets_alone``); one of a change in what it holds
(memory, threads, files) runs the suite as far as the last of them, as every confirmation run
did before (`redline.worker.quiet_pairs.flagged_scope`). Jobs queued before run as far as.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0028"
down_revision = "0027"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.add_column(
        "job",
        sa.Column("sets_alone", sa.Boolean(), nullable=False, server_default=sa.false()),
    )


def downgrade() -> None:
    op.drop_column("job", "sets_alone")
