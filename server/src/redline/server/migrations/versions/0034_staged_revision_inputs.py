"""staged_revision.inputs: a revision's `revision.inputs` when the re-analysis part began

Revision ID: 0034
Revises: 0033
Create Date: 2026-12-07 05:20:00

A part judges revisions in order, from its memory of the earlier ones, and its verdicts are
stored later, batch by batch. A run ingested meanwhile into an earlier revision counts up the
inputs of the revisions in its reach, but their own executions are unchanged, so the finishing
step stored their staged verdicts, judged from the old baseline, and marked them analysed (a
review). It now judges again from the database every revision whose inputs differ from those
its parts began with. Null: staged before this column; judged as before.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0034"
down_revision = "0033"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.add_column("staged_revision", sa.Column("inputs", sa.Integer(), nullable=True))


def downgrade() -> None:
    op.drop_column("staged_revision", "inputs")
