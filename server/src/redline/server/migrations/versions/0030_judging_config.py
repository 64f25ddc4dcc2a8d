"""A verdict keeps the detection configuration it was judged by

Revision ID: 0030
Revises: 0029
Create Date: 2026-12-06 04:30:00

The "why flagged" page read the component's configuration as it is now, so after a save with
``"reanalyze": false`` it showed new thresholds beside verdicts judged by the old ones. Each
distinct configuration a component's verdicts were judged by is kept once (``judging_config``:
its fields and every method's parameters as it judged), and a detection points at its own.
Verdicts stored before have none (NULL): the page says it shows the current configuration.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0030"
down_revision = "0029"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "judging_config",
        sa.Column("id", sa.Integer(), primary_key=True),
        sa.Column(
            "component_id",
            sa.Integer(),
            sa.ForeignKey("component.id", ondelete="CASCADE"),
            nullable=False,
        ),
        sa.Column("digest", sa.String(64), nullable=False),
        sa.Column("config", sa.JSON(), nullable=False),
        sa.Column("params", sa.JSON(), nullable=False),
        sa.Column("created", sa.DateTime(timezone=True), nullable=False),
        sa.UniqueConstraint("component_id", "digest"),
    )
    op.add_column(
        "detection",
        sa.Column("config_id", sa.Integer(), sa.ForeignKey("judging_config.id"), nullable=True),
    )
    # a component's deletion removes its rows: each one's foreign key check looks here
    op.create_index("ix_detection_config_id", "detection", ["config_id"])


def downgrade() -> None:
    op.drop_index("ix_detection_config_id", table_name="detection")
    op.drop_column("detection", "config_id")
    op.drop_table("judging_config")
