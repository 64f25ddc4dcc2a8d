"""Run-time faults told to the alert subscriptions: an alert may tell a runtime alarm, once per
subscription

Revision ID: 0014
Revises: 0013
Create Date: 2026-11-24 04:40:00
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0014"
down_revision = "0013"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.add_column(
        "alert",
        sa.Column(
            "runtime_alarm_id",
            sa.Integer(),
            sa.ForeignKey("runtime_alarm.id", ondelete="CASCADE"),
            nullable=True,
        ),
    )
    op.create_unique_constraint(
        "uq_alert_subscription_runtime_alarm", "alert", ["subscription_id", "runtime_alarm_id"]
    )


def downgrade() -> None:
    op.drop_constraint("uq_alert_subscription_runtime_alarm", "alert", type_="unique")
    op.drop_column("alert", "runtime_alarm_id")
