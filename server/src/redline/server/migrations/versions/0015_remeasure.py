"""A fresh run of an execution the host was busy in: a job may re-measure another

Revision ID: 0015
Revises: 0014
Create Date: 2026-11-24 17:10:00
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0015"
down_revision = "0014"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.add_column(
        "job",
        sa.Column(
            "remeasures_job_id",
            sa.Integer(),
            sa.ForeignKey("job.id", ondelete="SET NULL"),
            nullable=True,
        ),
    )


def downgrade() -> None:
    op.drop_column("job", "remeasures_job_id")
