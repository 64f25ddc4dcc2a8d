"""A confirmation pair queued again after a busy host waits before it runs

Revision ID: 0027
Revises: 0026
Create Date: 2026-12-02 01:00:00

When the host was busy in a confirmation pair's runs of a suspected change (their phases are
left out), the pairs are run once more, no sooner than ``job.not_before``, when the work that
loaded the host may have ended (`redline.worker.quiet_pairs`). Jobs queued before have none.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0027"
down_revision = "0026"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.add_column("job", sa.Column("not_before", sa.DateTime(timezone=True), nullable=True))


def downgrade() -> None:
    op.drop_column("job", "not_before")
