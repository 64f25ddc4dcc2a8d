"""revision.inputs: how many times what its verdicts are judged from has changed

Revision ID: 0033
Revises: 0032
Create Date: 2026-12-07 05:00:00

Ingestion cleared `analyzed_at` without the revision's detection lock, and a detection already
under way then wrote its start time over the cleared mark: the verdict read "done" without the
results ingested meanwhile (a review of the CI gate). Ingestion now also counts up `inputs`,
and detection marks a revision analysed only when `inputs` is still what it read before judging
(`redline.server.services.analysed`): no clock is compared, so workers whose clocks disagree
cannot leave a verdict pending, nor mark a stale one done.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0033"
down_revision = "0032"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.add_column(
        "revision", sa.Column("inputs", sa.Integer(), nullable=False, server_default=sa.text("0"))
    )


def downgrade() -> None:
    op.drop_column("revision", "inputs")
