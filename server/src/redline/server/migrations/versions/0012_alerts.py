"""Alerts: subscriptions, the alerts and changes each was told about, the delivery outbox, and a
component's commit-status target

Revision ID: 0012
Revises: 0011
Create Date: 2026-11-23 12:40:00
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0012"
down_revision = "0011"
branch_labels = None
depends_on = None

NOW = sa.DateTime(timezone=True)


def upgrade() -> None:
    op.add_column(
        "component", sa.Column("commit_status", sa.JSON(), nullable=False, server_default="{}")
    )
    op.alter_column("component", "commit_status", server_default=None)
    op.create_table(
        "subscription",
        sa.Column("id", sa.Integer(), primary_key=True),
        sa.Column(
            "component_id",
            sa.Integer(),
            sa.ForeignKey("component.id", ondelete="CASCADE"),
            nullable=True,
        ),
        sa.Column("kind", sa.String(20), nullable=False),
        sa.Column("address", sa.Text(), nullable=False),
        sa.Column("url", sa.Text(), nullable=False),
        sa.Column("secret", sa.Text(), nullable=False),
        sa.Column("format", sa.String(20), nullable=False),
        sa.Column("counters", sa.JSON(), nullable=False),
        sa.Column("direction", sa.String(20), nullable=False),
        sa.Column("min_effect", sa.Float(), nullable=False),
        sa.Column("confirmed_only", sa.Boolean(), nullable=False),
        sa.Column("delivery", sa.String(20), nullable=False),
        sa.Column("digest_sent", NOW, nullable=True),
        sa.Column("created", NOW, nullable=False),
        sa.Column("updated", NOW, nullable=False),
    )
    op.create_index("ix_subscription_component_id", "subscription", ["component_id"])
    op.create_table(
        "delivery",
        sa.Column("id", sa.Integer(), primary_key=True),
        sa.Column("uid", sa.String(36), nullable=False, unique=True),
        sa.Column("key", sa.String(200), nullable=True, unique=True),
        sa.Column(
            "subscription_id",
            sa.Integer(),
            sa.ForeignKey("subscription.id", ondelete="CASCADE"),
            nullable=True,
        ),
        sa.Column(
            "component_id",
            sa.Integer(),
            sa.ForeignKey("component.id", ondelete="CASCADE"),
            nullable=True,
        ),
        sa.Column("kind", sa.String(20), nullable=False),
        sa.Column("event", sa.String(40), nullable=False),
        sa.Column("payload", sa.JSON(), nullable=False),
        sa.Column("state", sa.String(20), nullable=False),
        sa.Column("attempts", sa.Integer(), nullable=False),
        sa.Column("last_error", sa.Text(), nullable=False),
        sa.Column("next_try", NOW, nullable=False),
        sa.Column("lease_until", NOW, nullable=True),
        sa.Column("created", NOW, nullable=False),
        sa.Column("delivered", NOW, nullable=True),
    )
    op.create_index("ix_delivery_subscription_id", "delivery", ["subscription_id"])
    op.create_index("ix_delivery_component_id", "delivery", ["component_id"])
    op.create_index("ix_delivery_state", "delivery", ["state"])
    op.create_index(
        "ix_delivery_due",
        "delivery",
        ["next_try"],
        postgresql_where=sa.text("state IN ('pending', 'sending')"),
    )
    op.create_table(
        "alert",
        sa.Column("id", sa.Integer(), primary_key=True),
        sa.Column(
            "subscription_id",
            sa.Integer(),
            sa.ForeignKey("subscription.id", ondelete="CASCADE"),
            nullable=False,
        ),
        sa.Column(
            "regression_id",
            sa.Integer(),
            sa.ForeignKey("regression.id", ondelete="SET NULL"),
            nullable=True,
        ),
        sa.Column(
            "revision_id",
            sa.Integer(),
            sa.ForeignKey("revision.id", ondelete="SET NULL"),
            nullable=True,
        ),
        sa.Column("kind", sa.String(30), nullable=False),
        sa.Column("body", sa.JSON(), nullable=False),
        sa.Column(
            "delivery_id",
            sa.Integer(),
            sa.ForeignKey("delivery.id", ondelete="SET NULL"),
            nullable=True,
        ),
        sa.Column("created", NOW, nullable=False),
    )
    op.create_index("ix_alert_subscription_id", "alert", ["subscription_id"])
    op.create_index("ix_alert_regression_id", "alert", ["regression_id"])
    op.create_index("ix_alert_delivery_id", "alert", ["delivery_id"])
    op.create_table(
        "alerted_change",
        sa.Column(
            "subscription_id",
            sa.Integer(),
            sa.ForeignKey("subscription.id", ondelete="CASCADE"),
            primary_key=True,
        ),
        sa.Column("series_id", sa.Integer(), sa.ForeignKey("series.id"), primary_key=True),
        sa.Column("revision_id", sa.Integer(), sa.ForeignKey("revision.id"), primary_key=True),
        sa.Column(
            "alert_id",
            sa.Integer(),
            sa.ForeignKey("alert.id", ondelete="CASCADE"),
            nullable=False,
        ),
    )
    op.create_index("ix_alerted_change_alert_id", "alerted_change", ["alert_id"])


def downgrade() -> None:
    op.drop_table("alerted_change")
    op.drop_table("alert")
    op.drop_table("delivery")
    op.drop_table("subscription")
    op.drop_column("component", "commit_status")
