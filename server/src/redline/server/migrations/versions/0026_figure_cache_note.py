"""A cached trend view says what its page left out

Revision ID: 0026
Revises: 0025
Create Date: 2026-12-01 18:30:00

A view drawing more than `redline.server.services.trend_view.MAX_CHARTS` charts or
``MAX_SERIES`` series is cut to its first ones, and its page says so (``note``). The views
cached before were drawn whole, 30 MB for a trial's 20,000 series: they are dropped, to be
rendered again on their next request.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0026"
down_revision = "0025"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.execute("DELETE FROM figure_cache")
    op.add_column("figure_cache", sa.Column("note", sa.Text(), nullable=False, server_default=""))


def downgrade() -> None:
    op.drop_column("figure_cache", "note")
