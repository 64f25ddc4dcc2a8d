"""Resource-usage models trained from recordings, and the run-time alarms `redline watch` reports

Revision ID: 0013
Revises: 0012
Create Date: 2026-11-23 13:15:00
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0013"
down_revision = "0012"
branch_labels = None
depends_on = None

NOW = sa.DateTime(timezone=True)


def upgrade() -> None:
    op.create_table(
        "resource_model",
        sa.Column("id", sa.Integer(), primary_key=True),
        sa.Column(
            "component_id",
            sa.Integer(),
            sa.ForeignKey("component.id", ondelete="CASCADE"),
            nullable=False,
        ),
        sa.Column("state", sa.String(20), nullable=False),
        sa.Column("error", sa.Text(), nullable=False),
        sa.Column("request", sa.JSON(), nullable=False),
        sa.Column("process", sa.String(200), nullable=False),
        sa.Column("metrics", sa.JSON(), nullable=False),
        sa.Column("provenance", sa.JSON(), nullable=False),
        sa.Column("plot", sa.JSON(), nullable=False),
        sa.Column("path", sa.Text(), nullable=False),
        sa.Column("created", NOW, nullable=False),
        sa.Column("finished", NOW, nullable=True),
    )
    op.create_index("ix_resource_model_component_id", "resource_model", ["component_id"])
    op.create_table(
        "runtime_alarm",
        sa.Column("id", sa.Integer(), primary_key=True),
        sa.Column(
            "component_id",
            sa.Integer(),
            sa.ForeignKey("component.id", ondelete="CASCADE"),
            nullable=False,
        ),
        sa.Column(
            "model_id",
            sa.Integer(),
            sa.ForeignKey("resource_model.id", ondelete="SET NULL"),
            nullable=True,
        ),
        sa.Column("host", sa.String(200), nullable=False),
        sa.Column("process", sa.String(200), nullable=False),
        sa.Column("target", sa.String(50), nullable=False),
        sa.Column("started", sa.Boolean(), nullable=False),
        sa.Column("residual", sa.Float(), nullable=False),
        sa.Column("threshold", sa.Float(), nullable=False),
        sa.Column("step", sa.Integer(), nullable=False),
        sa.Column("at", NOW, nullable=False),
    )
    op.create_index("ix_runtime_alarm_component_id", "runtime_alarm", ["component_id"])


def downgrade() -> None:
    op.drop_table("runtime_alarm")
    op.drop_table("resource_model")
