"""detection.confirmation and regression.confirmation: a flagged change is suspected until the
later revisions say whether it held (its regression confirmed) or was a spike (not confirmed)

Revision ID: 0007
Revises: 0006
Create Date: 2026-11-23 06:10:00
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0007"
down_revision = "0006"
branch_labels = None
depends_on = None


def upgrade() -> None:
    for table, default in (("detection", ""), ("regression", "suspected")):
        op.add_column(
            table,
            sa.Column("confirmation", sa.String(20), nullable=False, server_default=default),
        )
        op.add_column(
            table,
            sa.Column("confirmation_reason", sa.Text(), nullable=False, server_default=""),
        )
        op.alter_column(table, "confirmation", server_default=None)
        op.alter_column(table, "confirmation_reason", server_default=None)
    op.create_index("ix_regression_confirmation", "regression", ["confirmation"])
    op.create_index(
        "ix_detection_suspected",
        "detection",
        ["series_id"],
        postgresql_where=sa.text("confirmation = 'suspected'"),
    )
    # regressions found before: confirmed as they were (they were alarms already), and their
    # detections held, so nothing already reported goes quiet
    op.execute("UPDATE regression SET confirmation = 'confirmed'")
    op.execute(
        "UPDATE detection SET confirmation = 'held', confirmation_reason = "
        "'found before confirmation by history existed' WHERE regression_id IS NOT NULL"
    )


def downgrade() -> None:
    op.drop_index("ix_detection_suspected", "detection")
    op.drop_index("ix_regression_confirmation", "regression")
    for table in ("regression", "detection"):
        op.drop_column(table, "confirmation_reason")
        op.drop_column(table, "confirmation")
