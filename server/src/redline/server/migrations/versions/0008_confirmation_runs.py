"""job.pair, job.confirms_revision_id, job.pinned_host_id: confirmation runs, a flagged revision
and its baseline run again in interleaved pairs on one host

Revision ID: 0008
Revises: 0007
Create Date: 2026-11-23 06:50:00
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0008"
down_revision = "0007"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.add_column("job", sa.Column("pair", sa.Integer(), nullable=False, server_default="0"))
    op.alter_column("job", "pair", server_default=None)
    op.add_column(
        "job",
        sa.Column(
            "confirms_revision_id", sa.Integer(), sa.ForeignKey("revision.id"), nullable=True
        ),
    )
    op.create_index("ix_job_confirms_revision_id", "job", ["confirms_revision_id"])
    op.add_column(
        "job", sa.Column("pinned_host_id", sa.Integer(), sa.ForeignKey("host.id"), nullable=True)
    )


def downgrade() -> None:
    op.drop_column("job", "pinned_host_id")
    op.drop_index("ix_job_confirms_revision_id", "job")
    op.drop_column("job", "confirms_revision_id")
    op.drop_column("job", "pair")
