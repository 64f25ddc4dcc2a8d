"""detection: per-component configuration, every method's verdict, regressions with triage
history, re-analysis progress

Revision ID: 0004
Revises: 0003
Create Date: 2026-11-22 03:15:00
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0004"
down_revision = "0003"
branch_labels = None
depends_on = None


def _now() -> sa.Column:
    return sa.Column("created", sa.DateTime(timezone=True), nullable=False)


def upgrade() -> None:
    op.create_table(
        "detection_config",
        sa.Column("component_id", sa.Integer(), sa.ForeignKey("component.id"), primary_key=True),
        sa.Column("config", sa.JSON(), nullable=False),
        sa.Column("updated", sa.DateTime(timezone=True), nullable=False),
    )
    op.create_table(
        "regression",
        sa.Column("id", sa.Integer(), primary_key=True),
        sa.Column(
            "component_id", sa.Integer(), sa.ForeignKey("component.id"), nullable=False, index=True
        ),
        sa.Column("good_revision_id", sa.Integer(), sa.ForeignKey("revision.id"), nullable=False),
        sa.Column("bad_revision_id", sa.Integer(), sa.ForeignKey("revision.id"), nullable=False),
        sa.Column("good_key", sa.String(1000, collation="C"), nullable=False),
        sa.Column("bad_key", sa.String(1000, collation="C"), nullable=False),
        sa.Column("state", sa.String(20), nullable=False, index=True),
        _now(),
        sa.Column("updated", sa.DateTime(timezone=True), nullable=False),
    )
    op.create_table(
        "regression_event",
        sa.Column("id", sa.Integer(), primary_key=True),
        sa.Column(
            "regression_id",
            sa.Integer(),
            sa.ForeignKey("regression.id", ondelete="CASCADE"),
            nullable=False,
            index=True,
        ),
        sa.Column("at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("who", sa.String(200), nullable=False),
        sa.Column("from_state", sa.String(20), nullable=False),
        sa.Column("to_state", sa.String(20), nullable=False),
        sa.Column("comment", sa.Text(), nullable=False),
    )
    op.create_table(
        "detection",
        sa.Column("id", sa.Integer(), primary_key=True),
        sa.Column(
            "series_id", sa.Integer(), sa.ForeignKey("series.id"), nullable=False, index=True
        ),
        sa.Column(
            "revision_id", sa.Integer(), sa.ForeignKey("revision.id"), nullable=False, index=True
        ),
        sa.Column(
            "baseline_revision_id", sa.Integer(), sa.ForeignKey("revision.id"), nullable=True
        ),
        sa.Column("baseline_revisions", sa.Integer(), nullable=False),
        sa.Column("method", sa.String(50), nullable=False),
        sa.Column("verdict", sa.String(20), nullable=False),
        sa.Column("reason", sa.Text(), nullable=False),
        sa.Column("score", sa.Float(), nullable=False),
        sa.Column("p_value", sa.Float(), nullable=True),
        sa.Column("effect", sa.Float(), nullable=True),
        sa.Column("direction", sa.String(10), nullable=False),
        sa.Column("flagged", sa.Boolean(), nullable=False),
        sa.Column(
            "regression_id",
            sa.Integer(),
            sa.ForeignKey("regression.id", ondelete="SET NULL"),
            nullable=True,
            index=True,
        ),
        _now(),
        sa.UniqueConstraint("series_id", "revision_id", "method"),
    )
    op.create_table(
        "reanalysis",
        sa.Column("component_id", sa.Integer(), sa.ForeignKey("component.id"), primary_key=True),
        sa.Column("state", sa.String(20), nullable=False),
        sa.Column("total", sa.Integer(), nullable=False),
        sa.Column("done", sa.Integer(), nullable=False),
        sa.Column("error", sa.Text(), nullable=False),
        sa.Column("requested", sa.DateTime(timezone=True), nullable=False),
        sa.Column("started", sa.DateTime(timezone=True), nullable=True),
        sa.Column("finished", sa.DateTime(timezone=True), nullable=True),
    )


def downgrade() -> None:
    op.drop_table("reanalysis")
    op.drop_table("detection")
    op.drop_table("regression_event")
    op.drop_table("regression")
    op.drop_table("detection_config")
