"""What a subscription was last told of each regression's confirmation

Revision ID: 0025
Revises: 0024
Create Date: 2026-11-29 12:00:00

Subscribers now hear how a regression they were sent settled (regression.confirmed,
.not_confirmed, .withdrawn; `redline.worker.follow_ups`), compared with what they were last told
of it. What was sent before this revision counts as told as the regression stands now: an
upgrade does not send a follow-up for every old regression that settled since its alert.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0025"
down_revision = "0024"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "regression_told",
        sa.Column(
            "subscription_id",
            sa.Integer(),
            sa.ForeignKey("subscription.id", ondelete="CASCADE"),
            primary_key=True,
        ),
        sa.Column(
            "regression_id",
            sa.Integer(),
            sa.ForeignKey("regression.id", ondelete="CASCADE"),
            primary_key=True,
        ),
        sa.Column("confirmation", sa.String(20), nullable=False),
    )
    op.create_index("ix_regression_told_regression_id", "regression_told", ["regression_id"])
    op.execute(
        "INSERT INTO regression_told (subscription_id, regression_id, confirmation) "
        "SELECT DISTINCT alert.subscription_id, alert.regression_id, regression.confirmation "
        "FROM alert JOIN regression ON regression.id = alert.regression_id "
        "WHERE alert.delivery_id IS NOT NULL"
    )


def downgrade() -> None:
    op.drop_index("ix_regression_told_regression_id", "regression_told")
    op.drop_table("regression_told")
