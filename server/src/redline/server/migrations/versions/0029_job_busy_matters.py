"""A confirmation run may say that a busy host does not spoil it

Revision ID: 0029
Revises: 0028
Create Date: 2026-12-06 02:40:00

A confirmation run of changes in what a component holds only (memory, threads, files:
`redline.detect.counters.is_held`) is judged even in a phase the host was busy in, so the agent
need not run it again at once when it was (``job.busy_matters`` false); in `bench_verdicts` a
leak's four first confirmation runs were each run three times as busy, 60 s a run against 20 s.
Every other job, those queued before included, keeps the agent's own retries.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0029"
down_revision = "0028"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.add_column(
        "job",
        sa.Column("busy_matters", sa.Boolean(), nullable=False, server_default=sa.true()),
    )


def downgrade() -> None:
    op.drop_column("job", "busy_matters")
